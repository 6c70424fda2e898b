"""What one attack is: the log window, the stack under test, the search, where the outputs go."""

from __future__ import annotations

import dataclasses
import shlex
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from advsim_ros import graph
from advsim_ros.adapters.profile import ProcessProfile, StackProfile, profile_from_mapping
from advsim_ros.contract import topics
from advsim_ros.core.errors import UserError
from advsim_ros.core.search.registry import accept_algorithm, renamed_sections
from advsim_ros.core.types import ScenarioError
from advsim_ros.io.bag import BagConfig
from advsim_ros.ros.launcher import NodeSpec, python_module_command

PACKAGE_ROOT = Path(__file__).resolve().parents[1]
REPO_PARAMS = PACKAGE_ROOT.parents[2] / "params"
STACK_TOPIC_NAMES = tuple(spec.name for spec in topics.STACK_TOPICS)
REMAP_MODES = ("relay", "rename")


class AttackError(UserError, RuntimeError):
    """The attack could not run to the end; the message says why and where the logs are (a user error: the
    stack, the machine or the inputs; `advsim` prints it as one line)."""


def default_params_dir() -> Path:
    """params/ of the source tree, else the installed share/advsim_ros/params."""
    if REPO_PARAMS.is_dir():
        return REPO_PARAMS
    installed = Path(sys.prefix) / "share" / "advsim_ros" / "params"
    if installed.is_dir():
        return installed
    raise ScenarioError(f"no params folder found (looked in {REPO_PARAMS} and {installed})")


@dataclass(frozen=True)
class StackSpec:
    """The stack under test: a command started as its own process, with topic remappings."""

    name: str  # log-file name and how the summary refers to it
    command: tuple[str, ...]  # executable and arguments (the launcher appends --ros-args ...)
    remappings: Mapping[str, str] = field(default_factory=dict)  # contract topic -> the stack's topic
    remap_mode: str = "relay"  # "relay": stack_adapter bridges the names; "rename": -r STACK:=CONTRACT to the command
    params_files: tuple[Path, ...] = ()
    restart: bool = True  # start it again when it exits during the attack
    rename_node: bool = False  # reference stacks are single nodes; users' commands keep their names
    sim_time: bool = True  # append `-p use_sim_time:=true` (commands: only those whose argv has --ros-args)
    profile: StackProfile | None = None  # --stack-profile: its processes and adapters (then no remappings)
    also: tuple[tuple[str, ...], ...] = ()  # more processes of the stack (--stack repeated), beside the main one

    def __post_init__(self) -> None:
        unknown = sorted(set(self.remappings) - set(STACK_TOPIC_NAMES))
        if unknown:
            raise ScenarioError(
                f"remapping of {', '.join(unknown)}: not a topic of the contract "
                f"(one of {', '.join(STACK_TOPIC_NAMES)})"
            )
        for source, target in self.remappings.items():
            if not target.startswith("/") or " " in target:
                raise ScenarioError(f"remapping {source}:={target}: the target must be an absolute topic name")
        if self.remap_mode not in REMAP_MODES:
            raise ScenarioError(f"remap mode {self.remap_mode!r}: one of {', '.join(REMAP_MODES)}")

    def rename_rules(self) -> dict[str, str]:
        """Rules for the stack's command line: its own topic names renamed to the contract's."""
        if self.remap_mode != "rename":
            return {}
        return {stack: contract for contract, stack in self.remappings.items()}

    def relayed(self) -> dict[str, str]:
        """Contract topic -> the stack's name, for stack_adapter and the player (profiles, relay mode)."""
        if self.profile is not None:
            return self.profile.renamed()
        return dict(self.remappings) if self.remap_mode == "relay" else {}

    def adapter_profile(self) -> StackProfile | None:
        """The profile stack_adapter works from, when the graph needs one: a profile's, or --remap's in relay mode."""
        if self.profile is not None:
            return self.profile if self.profile.adapted() else None
        if not self.relayed():
            return None
        renamed = self.relayed()
        inputs: dict[str, Any] = {"topics": {}}
        outputs: dict[str, Any] = {}
        for contract, theirs in renamed.items():
            if contract == topics.LIDAR.name:
                inputs["lidar"] = {"topic": theirs}
            elif contract == topics.ODOM.name:
                inputs["pose"] = {"topic": theirs}
            elif contract == topics.PLAN.name:
                outputs["plan"] = {"topic": theirs}
            elif contract == topics.DETECTIONS.name:
                outputs["detections"] = {"topic": theirs}
            elif contract == topics.PREDICTIONS.name:
                outputs["predictions"] = {"topic": theirs}
            else:
                inputs["topics"][contract] = theirs
        mapping = {"name": self.name, "processes": [{"command": shlex.join(self.command)}], "inputs": inputs}
        return profile_from_mapping({**mapping, "outputs": outputs}, Path.cwd(), "--remap")

    def processes(self) -> tuple[NodeSpec, ...]:
        """The stack's processes as the launcher starts them (the first one is the stack's main process)."""
        if self.profile is not None:
            return tuple(_process_spec(self.profile, process) for process in self.profile.processes)
        main = NodeSpec(
            self.name,
            self.command,
            remappings=self.rename_rules(),
            params_files=self.params_files,
            parameters={"use_sim_time": True} if self.sim_time else {},
            rename_node=self.rename_node,
        )
        others = (
            NodeSpec(
                f"{self.name}{number}",
                command,
                remappings=self.rename_rules(),
                parameters={"use_sim_time": True} if takes_sim_time(command) else {},
                rename_node=False,
            )
            for number, command in enumerate(self.also, start=2)
        )
        return (main, *others)

    @staticmethod
    def from_profile(profile: StackProfile) -> StackSpec:
        """The stack a profile describes (``--stack-profile FILE``)."""
        first = profile.processes[0]
        return StackSpec(
            profile.name,
            first.argv,
            params_files=tuple(path for process in profile.processes for path in profile.params_paths(process)),
            restart=profile.restart,
            sim_time=profile.use_sim_time,
            profile=profile,
        )

    @staticmethod
    def reference(params_dir: Path | None = None) -> StackSpec:
        """The modular reference stack (ground removal, detector, tracker, prediction, planner)."""
        params = (params_dir or default_params_dir()) / "stack_modular.yaml"
        return StackSpec(
            "modular_stack",
            python_module_command("advsim_ros.stacks.modular.node"),
            params_files=(params,) if params.exists() else (),
        )

    @staticmethod
    def learned(params_dir: Path | None = None) -> StackSpec:
        """The imitation-learning reference stack (BEV raster -> planner)."""
        params = (params_dir or default_params_dir()) / "stack_learned.yaml"
        return StackSpec(
            "learned_stack",
            python_module_command("advsim_ros.stacks.learned.node"),
            params_files=(params,) if params.exists() else (),
        )

    @staticmethod
    def parse(text: str, remappings: Mapping[str, str] | None = None, params_dir: Path | None = None) -> StackSpec:
        """'reference', 'learned', or a command line to run as the stack."""
        if text in ("reference", "modular"):
            spec = StackSpec.reference(params_dir)
        elif text == "learned":
            spec = StackSpec.learned(params_dir)
        else:
            command = _command(text)
            # a user's command gets --ros-args of ours only for remappings (ros2 launch takes none), and sim time
            # only when its own argv hands --ros-args on to its node
            spec = StackSpec("stack", command, sim_time=takes_sim_time(command))
        return dataclasses.replace(spec, remappings=dict(remappings or {}))

    @staticmethod
    def parse_all(texts: Sequence[str], remappings: Mapping[str, str] | None = None) -> StackSpec:
        """--stack given once or more: the first the main process, each further one a command of the same stack."""
        if not texts:
            raise ScenarioError("--stack: no command")
        for text in texts[1:]:
            if text in ("reference", "modular", "learned"):
                raise ScenarioError(f"--stack {text}: only the first --stack may name a reference stack")
        spec = StackSpec.parse(texts[0], remappings)
        return dataclasses.replace(spec, also=tuple(_command(text) for text in texts[1:]))


def _command(text: str) -> tuple[str, ...]:
    try:
        command = tuple(shlex.split(text))
    except ValueError as error:
        raise ScenarioError(f"--stack {text!r}: {error}") from None
    if not command:
        raise ScenarioError("--stack: empty command")
    return command


def sets_sim_time(argv: Sequence[str]) -> bool:
    """Whether a command line sets use_sim_time itself (-p use_sim_time:=..., or a launch argument)."""
    return any(token.startswith("use_sim_time:=") for token in argv)


def takes_sim_time(argv: Sequence[str]) -> bool:
    """Whether -p use_sim_time:=true is appended: the argv hands --ros-args on and sets no use_sim_time itself."""
    return "--ros-args" in argv and not sets_sim_time(argv)


def _process_spec(profile: StackProfile, process: ProcessProfile) -> NodeSpec:
    """One process of a profile as the launcher starts it (--ros-args only for commands that take them)."""
    argv, cwd, env = process.argv, profile.cwd_path(process), process.environment
    if not process.ros_args:
        return NodeSpec(process.name, argv, rename_node=False, cwd=cwd, env=env)
    parameters: dict[str, str | int | float | bool] = dict(process.parameters)
    if profile.use_sim_time and not sets_sim_time(argv):
        parameters.setdefault("use_sim_time", True)
    return NodeSpec(
        process.name,
        argv,
        remappings=dict(process.remappings),
        params_files=profile.params_paths(process),
        parameters=parameters,
        rename_node=False,
        cwd=cwd,
        env=env,
    )


@dataclass(frozen=True)
class AttackOptions:
    """One attack: which log window, which stack, which search, where the outputs go."""

    bag: Path  # scenario bag (rosbag2 folder)
    out_dir: Path
    stack: StackSpec
    algorithm: str = "bo"
    queries: int = 75  # search queries (the original scenario and the re-runs of the best come on top)
    actors: int = 1  # actors perturbed at once
    seed: int = 0
    window_start_frame: int | None = None  # None: the curated window with the highest collision rate
    params_dir: Path | None = None  # None: the project's params/
    plan_timeout: float = 10.0  # longest wait for a plan per frame [s]
    connect_timeout: float = 120.0  # longest wait for the stack to subscribe to the LiDAR and publish plans [s]
    startup_timeout: float = 600.0  # longest wait for the first score (feasible sets, background model) [s]
    query_timeout: float = 300.0  # longest a single query may take before it is given up [s]
    reruns: int = 2  # evaluations of each best query after the search (reproducibility)
    rerun_top: int = 1  # how many of the best queries are re-run
    parameter_overrides: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)  # node -> {param: value}
    replay_only: bool = False  # `advsim replay`: score the bag's own scenario, no search, nothing moved
    replay_runs: int = 1  # `advsim replay`: how many times
    visual_report: bool = True  # draw bev.gif and report.html (seconds; campaigns may leave them to `advsim report`)
    loop: str = "open"  # open: the decision plan is scored (the paper); closed: the ego drives the stack's plans
    lanes: int = 1  # evaluation graphs run side by side, each with its own stack; never changes a score
    reactive_actors: bool = False  # closed loop: moving vehicles react to the ego (IDM along their paths)
    bag_config: BagConfig | None = None  # --bag-params: the bag's topics and frames (None: params/bag.yaml's)

    def __post_init__(self) -> None:
        # an algorithm under an old name ("rs"): one warning, then its name now, in --algo and in --param search.*
        object.__setattr__(self, "algorithm", accept_algorithm(self.algorithm))
        name = graph.SEARCH.name
        if name in self.parameter_overrides:
            search = renamed_sections(self.parameter_overrides[name], f"--param {name}")
            object.__setattr__(self, "parameter_overrides", {**self.parameter_overrides, name: search})
        if self.queries < 1 and not self.replay_only:
            raise ScenarioError(f"--queries: must be at least 1, got {self.queries}")
        if self.actors < 1:
            raise ScenarioError(f"--actors: must be at least 1, got {self.actors}")
        if self.reruns < 0 or self.rerun_top < 0 or self.replay_runs < 1:
            raise ScenarioError("--reruns and --rerun-top must be >= 0, --runs >= 1")
        if self.lanes < 1:
            raise ScenarioError(f"--lanes: must be at least 1, got {self.lanes}")
        if self.lanes > 1 and self.replay_only:
            raise ScenarioError("--lanes: only for attacks (a replay runs its runs one after another)")
        if self.loop not in ("open", "closed"):
            raise ScenarioError(f"--loop: open or closed, got {self.loop!r}")
        if self.reactive_actors and self.loop != "closed":
            raise ScenarioError("--reactive-actors: only with --loop closed (in open loop nothing drives)")
        profile = self.stack.profile
        if self.loop == "closed" and profile is not None and profile.timing.timer:
            # the stepped clock answers a sweep after the next one is due: the loop would run time backwards
            raise ScenarioError("--loop closed: not yet for stacks planning on their own timer (timing.mode timer)")
        for name in ("plan_timeout", "connect_timeout", "startup_timeout", "query_timeout"):
            if not getattr(self, name) > 0:
                raise ScenarioError(f"{name}: must be positive, got {getattr(self, name)}")

    @property
    def params(self) -> Path:
        return self.params_dir or default_params_dir()
