"""Messages of the attack graph on the wire: core types <-> CDR bytes through one rosbags typestore.

The nodes publish and subscribe raw CDR (rclpy's `publish(bytes)` and `raw=True` subscriptions),
so the message builders here are the same ones the bag writer uses, and a recorded message is
byte for byte what was on the topic. Nothing here imports rclpy.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Sequence
from typing import Any

import numpy as np
from rosbags.typesys.store import Typestore

from advsim_ros.core.feasibility import PerturbedTrajectory
from advsim_ros.core.types import ActorClass, ActorTrack, Perturbation, Plan, ScenarioError
from advsim_ros.io.bag import actor_states, header_msg, scenario_typestore, stamp_of, time_msg

PERTURBATION = "advsim_msgs/msg/Perturbation"
ACTOR_TRACK_ARRAY = "advsim_msgs/msg/ActorTrackArray"
ACTOR_SELECTION = "advsim_msgs/msg/ActorSelection"
QUERY_SCORE = "advsim_msgs/msg/QueryScore"
EPISODE = "advsim_msgs/msg/Episode"
PATH = "nav_msgs/msg/Path"
CLOCK = "rosgraph_msgs/msg/Clock"

# advsim_msgs/Episode phases
PHASE_START, PHASE_REPLAY, PHASE_DECISION, PHASE_DONE = 0, 1, 2, 3
OUTCOME_COMPLETE, OUTCOME_PLANS_MISSING, OUTCOME_STACK_LOST = 0, 1, 2

# advsim_msgs/QueryScore status values
STATUS_OK = 0
STATUS_STACK_TIMEOUT = 1
STATUS_STACK_ERROR = 2
STATUS_INFEASIBLE = 3
SCORE_METRICS = (
    "adversarial_loss",
    "imitation_loss",
    "collision_loss",
    "comfort_loss",
    "collision_3s",
    "collision_5s",
    "l2_human_3s",
    "l2_human_5s",
    "lateral_acceleration",
    "jerk",
)

_CDR_HEADER_BYTES = 4  # encapsulation kind and options precede the payload


class WireError(ScenarioError):
    """A message that cannot be turned into the core type it stands for; the text names the problem."""


class Wire:
    """Encode rosbags message objects to CDR bytes and back, with advsim_msgs registered."""

    def __init__(self) -> None:
        self.store: Typestore = scenario_typestore()

    def encode(self, message: Any) -> bytes:
        return bytes(self.store.serialize_cdr(message, message.__msgtype__))

    def decode(self, raw: bytes, type_name: str) -> Any:
        return self.store.deserialize_cdr(raw, type_name)

    def clock(self, stamp_ns: int) -> bytes:
        return self.encode(self.store.types[CLOCK](clock=time_msg(self.store, stamp_ns)))


def header_stamp_ns(raw: bytes) -> int:
    """Header stamp of a CDR message whose first field is std_msgs/Header, without decoding the rest."""
    little = raw[1] == 1  # encapsulation CDR_LE = 0x0001, CDR_BE = 0x0000
    sec, nanosec = struct.unpack_from("<iI" if little else ">iI", raw, _CDR_HEADER_BYTES)
    return sec * 1_000_000_000 + nanosec


def restamp(raw: bytes, stamp_ns: int) -> bytes:
    """A copy of a header-first CDR message with its header stamp replaced (the frame and payload unchanged)."""
    little = raw[1] == 1
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    patched = bytearray(raw)
    struct.pack_into("<iI" if little else ">iI", patched, _CDR_HEADER_BYTES, sec, nanosec)
    return bytes(patched)


# ----------------------------------------------------------------------------- perturbations


def perturbation_msg(wire: Wire, perturbation: Perturbation) -> Any:
    return wire.store.types[PERTURBATION](
        query_id=perturbation.query_id,
        scenario_id=perturbation.scenario_id,
        actor_ids=list(perturbation.actor_ids),
        delta=np.asarray(perturbation.delta, dtype=np.float64),
        algorithm=perturbation.algorithm,
    )


def perturbation_from_msg(message: Any) -> Perturbation:
    return Perturbation(
        query_id=int(message.query_id),
        scenario_id=str(message.scenario_id),
        actor_ids=tuple(str(actor_id) for actor_id in message.actor_ids),
        delta=np.asarray(message.delta, dtype=np.float64),
        algorithm=str(message.algorithm),
    )


# ----------------------------------------------------------------------------- tracks


def trajectory_track_msg(wire: Wire, trajectory: PerturbedTrajectory) -> Any:
    """An ActorTrack holding a perturbed trajectory with its own speed, curvature and acceleration."""
    types = wire.store.types
    states = [
        types["advsim_msgs/msg/ActorState"](
            stamp=time_msg(wire.store, stamp),
            x=float(trajectory.x[i]),
            y=float(trajectory.y[i]),
            z=float(trajectory.z[i]),
            yaw=float(math.remainder(float(trajectory.yaw[i]), math.tau)),
            velocity=float(trajectory.speed[i]),
            curvature=float(trajectory.curvature[i]),
            acceleration=float(trajectory.accel[i]),
        )
        for i, stamp in enumerate(trajectory.stamps_ns.tolist())
    ]
    length, width, height = (float(v) for v in trajectory.size)
    return types["advsim_msgs/msg/ActorTrack"](
        actor_id=trajectory.actor_id,
        actor_class=trajectory.actor_class.value,
        length=length,
        width=width,
        height=height,
        confidence=1.0,
        states=states,
    )


def logged_track_msg(wire: Wire, track: ActorTrack) -> Any:
    """An ActorTrack message of a logged track (speed, curvature, acceleration by finite differences)."""
    return wire.store.types["advsim_msgs/msg/ActorTrack"](
        actor_id=track.actor_id,
        actor_class=track.actor_class.value,
        length=track.length,
        width=track.width,
        height=track.height,
        confidence=1.0,
        states=actor_states(wire.store, track),
    )


def track_array_msg(wire: Wire, query_id: int, stamp_ns: int, frame_id: str, tracks: Sequence[Any]) -> Any:
    return wire.store.types[ACTOR_TRACK_ARRAY](
        header=header_msg(wire.store, stamp_ns, frame_id), query_id=int(query_id), tracks=list(tracks)
    )


def tracks_from_msg(message: Any) -> tuple[ActorTrack, ...]:
    """Each ActorTrack of an ActorTrackArray as a core ActorTrack (boxes over time, world frame)."""
    tracks = []
    for track in message.tracks:
        if not track.states:
            raise WireError(f"track {track.actor_id!r} of query {message.query_id} has no states")
        try:
            actor_class = ActorClass(track.actor_class)
        except ValueError:
            actor_class = ActorClass.OTHER
        tracks.append(
            ActorTrack(
                actor_id=str(track.actor_id),
                actor_class=actor_class,
                size=np.array([track.length, track.width, track.height]),
                stamps_ns=np.array([stamp_of(state.stamp) for state in track.states], dtype=np.int64),
                centers=np.array([[state.x, state.y, state.z] for state in track.states]),
                yaws=np.array([state.yaw for state in track.states]),
            )
        )
    return tuple(tracks)


# ----------------------------------------------------------------------------- scores


def failed_score_msg(wire: Wire, query_id: int, status: int, message: str, wall_time: float = float("nan")) -> Any:
    """A QueryScore for a query that produced no usable plan: every metric NaN."""
    return wire.store.types[QUERY_SCORE](
        query_id=int(query_id),
        status=int(status),
        message=message,
        wall_time=float(wall_time),
        **dict.fromkeys(SCORE_METRICS, float("nan")),
    )


# ----------------------------------------------------------------------------- plans


def plan_from_path(message: Any, time_offset_ns: int = 0) -> Plan:
    """A nav_msgs/Path as a Plan (positions and headings); pose stamps shifted by -time_offset_ns.

    Poses stamped 0 (stacks that stamp only the header) are taken as 0.1 s apart after the header.
    Raises WireError for an empty path or non-finite poses, so the scorer can mark the stack's error.
    """
    poses = message.poses
    if not poses:
        raise WireError("the plan (nav_msgs/Path) has no poses")
    header_ns = stamp_of(message.header.stamp)
    stamps = np.array([stamp_of(pose.header.stamp) for pose in poses], dtype=np.int64)
    if np.all(stamps == 0):
        stamps = header_ns + 100_000_000 * np.arange(1, len(poses) + 1, dtype=np.int64)
    xy = np.array([[pose.pose.position.x, pose.pose.position.y] for pose in poses], dtype=np.float64)
    quaternions = np.array(
        [[p.pose.orientation.x, p.pose.orientation.y, p.pose.orientation.z, p.pose.orientation.w] for p in poses]
    )
    if not (np.all(np.isfinite(xy)) and np.all(np.isfinite(quaternions))):
        raise WireError("the plan (nav_msgs/Path) has NaN or infinite poses")
    if np.any(np.diff(stamps) <= 0):
        raise WireError("the plan's pose stamps are not strictly increasing")
    x, y, z, w = quaternions.T
    yaws = np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return Plan(stamps_ns=stamps - time_offset_ns, xy=xy, yaws=yaws)


def path_msg(wire: Wire, plan: Plan, header_stamp_ns: int, frame_id: str) -> Any:
    """A Plan as nav_msgs/Path (for stacks written with the core types, and for recording)."""
    types = wire.store.types
    poses = []
    for stamp, (x, y), yaw in zip(plan.stamps_ns.tolist(), plan.xy, plan.yaws, strict=True):
        orientation = types["geometry_msgs/msg/Quaternion"](
            x=0.0, y=0.0, z=float(math.sin(yaw / 2.0)), w=float(math.cos(yaw / 2.0))
        )
        position = types["geometry_msgs/msg/Point"](x=float(x), y=float(y), z=0.0)
        poses.append(
            types["geometry_msgs/msg/PoseStamped"](
                header=header_msg(wire.store, stamp, frame_id),
                pose=types["geometry_msgs/msg/Pose"](position=position, orientation=orientation),
            )
        )
    return types[PATH](header=header_msg(wire.store, header_stamp_ns, frame_id), poses=poses)


# ----------------------------------------------------------------------------- episodes


def episode_msg(
    wire: Wire,
    query_id: int,
    phase: int,
    frame_index: int,
    num_frames: int,
    segment: tuple[int, int],
    sweeps_delivered: int = 0,
    plans_received: int = 0,
    outcome: int = 0,
) -> Any:
    return wire.store.types[EPISODE](
        query_id=int(query_id),
        phase=int(phase),
        frame_index=int(frame_index),
        num_frames=int(num_frames),
        segment_start=time_msg(wire.store, segment[0]),
        segment_end=time_msg(wire.store, segment[1]),
        sweeps_delivered=int(sweeps_delivered),
        plans_received=int(plans_received),
        outcome=int(outcome),
    )
