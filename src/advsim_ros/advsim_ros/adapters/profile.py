"""Stack profiles: how to start a user's stack and how to adapt it to the topic contract (docs/stacks.md).

A profile is a YAML file (schema below, every key optional except ``processes``). It says which
processes make the stack, the topics and message types the stack reads and answers under its own
names, the frame its plan is in, and whether it plans per sweep or on its own timer. Whatever
differs from the contract is bridged by the graph's stack_adapter node, so the stack's code stays
as it is. Loading validates everything and refuses a bad profile with one line naming the key.

    profile: 1
    name: my_stack
    use_sim_time: true
    processes:
      - {name: planner, command: "python3 planner.py", params_files: [planner.yaml], parameters: {rate: 10.0},
         cwd: planner, env: {PYTHONPATH: "${HOME}/libs"}}
    timing: {mode: timer, clock_step: 0.01, real_time_factor: 1.0, decision_delay: 0.1}
    inputs:
      lidar: {topic: /points_raw, frame_id: velodyne}
      pose: {type: navsatfix, topic: /fix, datum: {latitude: 49.01, longitude: 8.42, altitude: 110.0}}
      topics: {/tf: /tf}
    outputs:
      plan: {type: spatial_path, topic: /planner/path, frame_id: map, frame_origin: first_fix, headings: auto}
"""

from __future__ import annotations

import json
import math
import os
import shlex
import string
import sys
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import yaml

from advsim_ros.contract import topics
from advsim_ros.core.params import ParamsError, config_from_mapping
from advsim_ros.core.types import ScenarioError

SCHEMA_VERSION = 1
PLAN_TYPES = ("path", "spatial_path", "autoware_trajectory", "pose_array")
DETECTION_TYPES = ("actor_tracks", "autoware_detected_objects", "autoware_tracked_objects", "marker_array")
PREDICTION_TYPES = ("actor_tracks", "autoware_predicted_objects")
POSE_TYPES = ("odometry", "pose_stamped", "pose_with_covariance_stamped", "navsatfix")
TIMING_MODES = ("per_sweep", "timer")
PLAN_STAMPS = ("header", "arrival")
PLAN_HEADINGS = ("auto", "tangent")
FRAME_ORIGINS = ("world", "static", "first_fix", "datum", "tf")
RELIABILITIES = ("reliable", "best_effort")  # how the stack publishes an answer (the graph's own reads are reliable)
# Contract inputs a profile may give other names (LiDAR and pose have sections of their own)
RENAMEABLE_INPUTS = tuple(spec.name for spec in topics.STACK_INPUTS if spec not in (topics.LIDAR, topics.ODOM))


_CONTRACT_OBJECTS = {"detections": topics.DETECTIONS.name, "predictions": topics.PREDICTIONS.name}


class ProfileError(ScenarioError):
    """A stack profile that cannot be used; the message names the file and the key."""


def _topic_name(value: str, key: str) -> None:
    if not value.startswith("/") or any(c.isspace() for c in value) or value.endswith("/"):
        raise ScenarioError(f"{key}: {value!r} is not an absolute topic name")


def _reliability(value: str) -> None:
    if value not in RELIABILITIES:
        raise ScenarioError(
            f"reliability {value!r}: one of {', '.join(RELIABILITIES)} (the QoS the stack publishes with)"
        )


@dataclass(frozen=True)
class Datum:
    """A geodetic point (WGS 84): the origin of the world frame, x east and y north of it."""

    latitude: float  # [deg]
    longitude: float  # [deg]
    altitude: float = 0.0  # [m] above the ellipsoid

    def __post_init__(self) -> None:
        if not (-90.0 <= self.latitude <= 90.0 and -180.0 <= self.longitude <= 180.0):
            raise ScenarioError(f"latitude/longitude out of range: {self.latitude}, {self.longitude}")
        if not math.isfinite(self.altitude):
            raise ScenarioError("altitude: must be finite")


@dataclass(frozen=True)
class ProcessProfile:
    """One process of the stack."""

    command: str  # the command line (split like a shell would, not run through one)
    name: str = "stack"  # log-file name
    ros_args: bool = True  # the command passes --ros-args on to its nodes (false for scripts, ros2 launch)
    params_files: tuple[str, ...] = ()  # parameter files, relative to the profile's folder
    parameters: dict[str, Any] = field(default_factory=dict)  # -p NAME:=VALUE
    remappings: dict[str, str] = field(default_factory=dict)  # -r FROM:=TO, the stack's own rules
    cwd: str = ""  # working folder, relative to the profile's folder ("": where advsim runs)
    env: dict[str, str] = field(default_factory=dict)  # extra environment variables ($VAR expanded)

    def __post_init__(self) -> None:
        try:
            argv = shlex.split(self.command)
        except ValueError as error:
            raise ScenarioError(f"command {self.command!r}: {error}") from None
        if not argv:
            raise ScenarioError("command: empty")
        if not self.name or "/" in self.name or any(c.isspace() for c in self.name):
            raise ScenarioError(f"name {self.name!r}: one word, used as the log-file name")
        for key, value in self.parameters.items():
            if not isinstance(value, bool | int | float | str):
                raise ScenarioError(f"parameters.{key}: expected a number, a string or true/false, got {value!r}")
        if (self.params_files or self.parameters or self.remappings) and not self.ros_args:
            raise ScenarioError("params_files, parameters and remappings need ros_args: true")
        for variable in self.env:
            if not variable or "=" in variable or "\0" in variable or any(c.isspace() for c in variable):
                raise ScenarioError(f"env: {variable!r} is not an environment variable's name")

    @property
    def argv(self) -> tuple[str, ...]:
        """The command split like a shell would, $VAR and ${VAR} expanded ($ADVSIM_PYTHON: advsim's interpreter)."""
        return tuple(_expand(token) for token in shlex.split(self.command))

    @property
    def environment(self) -> dict[str, str]:
        """``env`` with $VAR and ${VAR} in its values expanded as in the command."""
        return {variable: _expand(value) for variable, value in self.env.items()}


def _expand(text: str) -> str:
    """$VAR and ${VAR} from advsim's environment ($ADVSIM_PYTHON: its interpreter); unknown ones stay as written."""
    return string.Template(text).safe_substitute({"ADVSIM_PYTHON": sys.executable, **os.environ})


@dataclass(frozen=True)
class TimingProfile:
    """Whether the stack plans once per sweep (stamped with it) or on a timer of its own."""

    mode: str = "per_sweep"  # per_sweep | timer
    clock_step: float = 0.01  # timer: /clock advances in steps of this between sweeps [s]
    real_time_factor: float = 1.0  # timer: simulated seconds per wall-clock second while stepping
    decision_delay: float = 0.1  # timer: the plan in force this long after the decision sweep is scored [s]
    max_plan_age: float = 0.5  # timer: older plans are not in force (they belong to an earlier query) [s]
    plan_stamp: str = "header"  # timer: when a plan was made: its header stamp, or its arrival on the sim clock
    answer_margin: float = 0.5  # timer: a stack making no plan after the decision time is answered this late [s]

    def __post_init__(self) -> None:
        if self.mode not in TIMING_MODES:
            raise ScenarioError(f"mode {self.mode!r}: one of {', '.join(TIMING_MODES)}")
        if self.plan_stamp not in PLAN_STAMPS:
            raise ScenarioError(f"plan_stamp {self.plan_stamp!r}: one of {', '.join(PLAN_STAMPS)}")
        for name in ("clock_step", "real_time_factor", "decision_delay", "max_plan_age", "answer_margin"):
            if not getattr(self, name) > 0.0:
                raise ScenarioError(f"{name}: must be positive, got {getattr(self, name)}")
        if self.decision_delay < self.clock_step:
            raise ScenarioError("decision_delay: must be at least one clock_step")

    @property
    def timer(self) -> bool:
        return self.mode == "timer"


@dataclass(frozen=True)
class LidarInput:
    topic: str = topics.LIDAR.name  # where the stack reads the sweeps
    frame_id: str = ""  # the stack's name for the sensor frame ("": the bag's)
    also: tuple[str, ...] = ()  # more topics the same sweep goes to (a stack with per-sensor and concatenated inputs)

    def __post_init__(self) -> None:
        for index, topic in enumerate((self.topic, *self.also)):
            _topic_name(topic, "topic" if index == 0 else f"also[{index - 1}]")
        if len({self.topic, *self.also}) != 1 + len(self.also) or topics.LIDAR.name in self.also:
            raise ScenarioError(f"also: the LiDAR topics must differ from each other and from {topics.LIDAR.name}")
        if self.frame_id and self.topic == topics.LIDAR.name:
            raise ScenarioError("frame_id: sweeps with the stack's frame name go to a topic of its own; give topic")


@dataclass(frozen=True)
class PoseInput:
    """How the stack learns where the ego is: the contract's odometry, or one of the other types."""

    type: str = "odometry"  # odometry | pose_stamped | pose_with_covariance_stamped | navsatfix
    topic: str = topics.ODOM.name
    frame_id: str = ""  # header frame of what is published ("": the world frame; navsatfix: "gnss")
    datum: Datum | None = None  # navsatfix: the geodetic point of the world frame's origin

    def __post_init__(self) -> None:
        if self.type not in POSE_TYPES:
            raise ScenarioError(f"type {self.type!r}: one of {', '.join(POSE_TYPES)}")
        _topic_name(self.topic, "topic")
        if self.type == "navsatfix" and self.datum is None:
            raise ScenarioError("navsatfix needs a datum: {latitude, longitude, altitude} of the world origin")


@dataclass(frozen=True)
class InputsProfile:
    lidar: LidarInput = field(default_factory=LidarInput)
    pose: PoseInput = field(default_factory=PoseInput)
    topics: dict[str, str] = field(default_factory=dict)  # other contract inputs -> the stack's names

    def __post_init__(self) -> None:
        for contract, theirs in self.topics.items():
            if contract not in RENAMEABLE_INPUTS:
                raise ScenarioError(f"topics: {contract} is not one of {', '.join(RENAMEABLE_INPUTS)}")
            _topic_name(theirs, f"topics.{contract}")


@dataclass(frozen=True)
class PlanOutput:
    """What the stack answers, and how it becomes the contract's plan (50 poses 0.1 s apart in world)."""

    type: str = "path"  # path (stamped poses) | spatial_path | autoware_trajectory | pose_array
    topic: str = topics.PLAN.name
    frame_id: str = ""  # the frame the stack plans in ("": the world frame)
    frame_origin: str = "world"  # world | static (origin_pose) | first_fix | datum (origin_datum) | tf (from /tf)
    origin_pose: tuple[float, float, float] = (0.0, 0.0, 0.0)  # static: x [m], y [m], yaw [rad] in world
    origin_datum: Datum | None = None  # datum: the frame is east-north-up at this point
    acceleration: float = 0.0  # untimed plans: driven from the ego's speed with this acceleration [m/s^2]
    max_speed: float = 15.0  # untimed plans: speed limit of that rule [m/s]
    horizon: float = 5.0  # the contract plan's length [s]
    step: float = 0.1  # the contract plan's pose spacing [s]
    reliability: str = "reliable"  # QoS the stack publishes with (best_effort: the adapter reads it so)
    headings: str = "auto"  # auto: from the path's tangent when every orientation is the identity; tangent: always

    def __post_init__(self) -> None:
        _reliability(self.reliability)
        if self.type not in PLAN_TYPES:
            raise ScenarioError(f"type {self.type!r}: one of {', '.join(PLAN_TYPES)}")
        if self.headings not in PLAN_HEADINGS:
            raise ScenarioError(f"headings {self.headings!r}: one of {', '.join(PLAN_HEADINGS)}")
        _topic_name(self.topic, "topic")
        if self.frame_origin not in FRAME_ORIGINS:
            raise ScenarioError(f"frame_origin {self.frame_origin!r}: one of {', '.join(FRAME_ORIGINS)}")
        if self.frame_origin == "datum" and self.origin_datum is None:
            raise ScenarioError("frame_origin datum needs origin_datum: {latitude, longitude, altitude}")
        if self.frame_origin != "world" and not self.frame_id:
            raise ScenarioError(f"frame_origin {self.frame_origin} needs the frame's name in frame_id")
        if not (self.max_speed > 0.0 and self.horizon > 0.0 and self.step > 0.0):
            raise ScenarioError("max_speed, horizon and step: must be positive")
        if not math.isfinite(self.acceleration):
            raise ScenarioError("acceleration: must be finite")

    @property
    def num_steps(self) -> int:
        return round(self.horizon / self.step)


@dataclass(frozen=True)
class ObjectsOutput:
    """Detections or predictions the stack publishes, for the scorer's AP and prediction L2 (optional).

    Boxes in the plan's frame (its ``frame_id``) are moved into the world with the plan's transform;
    any other header frame is taken as the world frame.
    """

    topic: str  # where the stack publishes them
    type: str = "actor_tracks"  # advsim_msgs/ActorTrackArray, or an Autoware / MarkerArray type (see *_TYPES)
    reliability: str = "reliable"  # QoS the stack publishes with (best_effort: the adapter reads it so)

    def __post_init__(self) -> None:
        _topic_name(self.topic, "topic")
        _reliability(self.reliability)


@dataclass(frozen=True)
class OutputsProfile:
    plan: PlanOutput = field(default_factory=PlanOutput)
    detections: ObjectsOutput = field(default_factory=lambda: ObjectsOutput(topics.DETECTIONS.name))
    predictions: ObjectsOutput = field(default_factory=lambda: ObjectsOutput(topics.PREDICTIONS.name))

    def __post_init__(self) -> None:
        if self.detections.type not in DETECTION_TYPES:
            raise ScenarioError(f"detections.type {self.detections.type!r}: one of {', '.join(DETECTION_TYPES)}")
        if self.predictions.type not in PREDICTION_TYPES:
            raise ScenarioError(f"predictions.type {self.predictions.type!r}: one of {', '.join(PREDICTION_TYPES)}")


@dataclass(frozen=True)
class StackProfile:
    """A whole profile (the module docstring shows the file)."""

    processes: tuple[ProcessProfile, ...]
    name: str = "stack"
    profile: int = SCHEMA_VERSION
    use_sim_time: bool = True  # pass -p use_sim_time:=true to every process that takes --ros-args
    restart: bool = True  # start a process again when it exits during the attack
    timing: TimingProfile = field(default_factory=TimingProfile)
    inputs: InputsProfile = field(default_factory=InputsProfile)
    outputs: OutputsProfile = field(default_factory=OutputsProfile)
    folder: str = ""  # where the profile file lies (relative params_files start there); set by the loader

    def __post_init__(self) -> None:
        if self.profile != SCHEMA_VERSION:
            raise ScenarioError(f"profile: this advsim_ros reads schema {SCHEMA_VERSION}, got {self.profile}")
        if not self.processes:
            raise ScenarioError("processes: at least one command that starts the stack")
        names = [process.name for process in self.processes]
        if len(set(names)) != len(names):
            raise ScenarioError(f"processes: names must differ (got {names}); give each a name")
        if self.outputs.plan.frame_origin == "first_fix" and self.inputs.pose.type != "navsatfix":
            raise ScenarioError("outputs.plan.frame_origin first_fix needs inputs.pose.type navsatfix")
        # the adapter publishes converted answers under the contract's name: the stack's must differ
        plan = self.outputs.plan
        if (self.plan_converted() or plan.reliability != "reliable") and plan.topic == topics.PLAN.name:
            raise ScenarioError(
                f"outputs.plan.topic: the adapter publishes this plan on {topics.PLAN.name}; name yours"
            )
        for key, output in (("detections", self.outputs.detections), ("predictions", self.outputs.predictions)):
            adapted = output.type != "actor_tracks" or output.reliability != "reliable"
            if adapted and output.topic == _CONTRACT_OBJECTS[key]:
                raise ScenarioError(
                    f"outputs.{key}.topic: the adapter publishes these on the contract's topic; name yours"
                )

    def plan_converted(self) -> bool:
        """Whether the plan is converted (type, frame, timing or headings), not just relayed."""
        plan = self.outputs.plan
        return plan.type != "path" or plan.frame_origin != "world" or self.timing.timer or plan.headings != "auto"

    def objects_converted(self, output: ObjectsOutput, contract: str) -> bool:
        """Whether detections or predictions are converted: another type, or restamped for a timer-driven
        stack (which publishes them under a name of its own; under the contract's they are not awaited)."""
        return output.type != "actor_tracks" or (self.timing.timer and output.topic != contract)

    def params_paths(self, process: ProcessProfile) -> tuple[Path, ...]:
        return tuple((Path(self.folder) / item).resolve() for item in process.params_files)

    def cwd_path(self, process: ProcessProfile) -> Path | None:
        """The process's working folder (relative ones start at the profile's folder); None: advsim's own."""
        return (Path(self.folder) / _expand(process.cwd)).resolve() if process.cwd else None

    def renamed(self) -> dict[str, str]:
        """Contract topic -> the stack's name, for every contract topic the stack calls otherwise."""
        names = {
            topics.LIDAR.name: self.inputs.lidar.topic,
            topics.ODOM.name: self.inputs.pose.topic,
            **self.inputs.topics,
            topics.PLAN.name: self.outputs.plan.topic,
            topics.DETECTIONS.name: self.outputs.detections.topic,
            topics.PREDICTIONS.name: self.outputs.predictions.topic,
        }
        return {contract: theirs for contract, theirs in names.items() if contract != theirs}

    def converts(self) -> bool:
        """Whether anything beyond renaming is needed (types, frames, timing): the adapter node's work."""
        return (
            self.plan_converted()
            or self.objects_converted(self.outputs.detections, topics.DETECTIONS.name)
            or self.objects_converted(self.outputs.predictions, topics.PREDICTIONS.name)
            or self.inputs.pose.type != "odometry"
            or bool(self.inputs.pose.frame_id)
            or bool(self.inputs.lidar.frame_id)
            or bool(self.inputs.lidar.also)
        )

    def adapted(self) -> bool:
        """Whether the graph needs its stack_adapter node for this stack."""
        return self.converts() or bool(self.renamed())

    def to_json(self) -> str:
        """The profile as JSON (the adapter node reads it back with ``load_profile``)."""
        return json.dumps(asdict(self), sort_keys=True)


def profile_from_mapping(mapping: Any, folder: Path, source: str) -> StackProfile:
    """A validated profile from parsed YAML/JSON; ProfileError names the source and the key."""
    if not isinstance(mapping, dict):
        raise ProfileError(f"{source}: expected a mapping (a stack profile), got {type(mapping).__name__}")
    values = {"folder": str(folder), **mapping}  # a profile written back as JSON keeps its folder
    try:
        return config_from_mapping(StackProfile, values, "profile")
    except ParamsError as error:
        raise ProfileError(f"{source}: {str(error).removeprefix('profile: ')}") from None
    except ScenarioError as error:
        raise ProfileError(f"{source}: {error}") from None


def load_profile(path: Path) -> StackProfile:
    """The profile in a YAML (or JSON) file; ProfileError with one line naming the problem."""
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as error:
        raise ProfileError(f"stack profile {path}: cannot read it ({error.strerror})") from None
    try:
        mapping = yaml.safe_load(text)
    except yaml.YAMLError as error:
        raise ProfileError(f"stack profile {path}: not valid YAML ({error})".replace("\n", " ")) from None
    profile = profile_from_mapping(mapping, path.resolve().parent, f"stack profile {path}")
    for process in profile.processes:
        for params_file in profile.params_paths(process):
            if not params_file.is_file():
                raise ProfileError(f"stack profile {path}: params file {params_file} of {process.name} does not exist")
        cwd = profile.cwd_path(process)
        if cwd is not None and not cwd.is_dir():
            raise ProfileError(f"stack profile {path}: cwd {cwd} of {process.name} is not a folder")
    return profile
