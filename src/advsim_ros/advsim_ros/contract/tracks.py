"""Actor tracks on the wire: advsim_msgs/ActorTrack and ActorTrackArray, one builder and one parser.

Logged tracks (bags, the actor selection), perturbed trajectories (the perturber) and a stack's
detections and predictions all travel as ActorTrack: a box with a class and stamped states.
``TrackRecord`` is what one ActorTrack carries; each source converts itself into one.
"""

from __future__ import annotations

import dataclasses
import math
import struct
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from advsim_ros.contract import codec, names
from advsim_ros.contract.codec import NS_PER_S, ContractError, Msg, header_msg, message, stamp_ns
from advsim_ros.core.closed_loop import ExecutedTrajectory
from advsim_ros.core.feasibility import PerturbedTrajectory
from advsim_ros.core.types import ActorClass, ActorTrack, FloatArray, IntArray

_MIN_SPEED_FOR_CURVATURE = 0.5  # [m/s] below this heading noise swamps a finite-difference curvature


def _gradient(values: FloatArray, times_s: FloatArray) -> FloatArray:
    if values.shape[0] < 2:
        return np.zeros_like(values)
    result: FloatArray = np.gradient(values, times_s, axis=0)
    return result


@dataclass(frozen=True, eq=False)
class TrackRecord:
    """One advsim_msgs/ActorTrack: an actor's box and its stamped states (world frame)."""

    actor_id: str
    actor_class: ActorClass
    size: FloatArray  # (3,) length, width, height [m]
    confidence: float  # detection score in [0, 1]; 1 for ground truth and perturbations
    stamps_ns: IntArray  # (T,) [ns]
    xyz: FloatArray  # (T, 3) box centre [m]
    yaw: FloatArray  # (T,) heading [rad]
    velocity: FloatArray  # (T,) speed along the heading [m/s]
    curvature: FloatArray  # (T,) [1/m]
    acceleration: FloatArray  # (T,) longitudinal [m/s^2]

    @staticmethod
    def from_actor_track(track: ActorTrack) -> TrackRecord:
        """A logged track; speed, curvature and acceleration are finite-difference estimates."""
        times_s = (track.stamps_ns - track.stamps_ns[0]) * 1e-9
        velocity = _gradient(track.centers[:, :2], times_s)
        speed = velocity[:, 0] * np.cos(track.yaws) + velocity[:, 1] * np.sin(track.yaws)  # signed, along heading
        yaw_rate = _gradient(np.unwrap(track.yaws), times_s)
        moving = np.abs(speed) > _MIN_SPEED_FOR_CURVATURE
        curvature = np.where(moving, yaw_rate / np.where(moving, speed, 1.0), 0.0)
        return TrackRecord(
            actor_id=track.actor_id,
            actor_class=track.actor_class,
            size=track.size,
            confidence=1.0,
            stamps_ns=track.stamps_ns,
            xyz=track.centers,
            yaw=track.yaws,
            velocity=speed,
            curvature=curvature,
            acceleration=_gradient(speed, times_s),
        )

    @staticmethod
    def from_perturbed(trajectory: PerturbedTrajectory) -> TrackRecord:
        """A perturbed trajectory with its own speed, curvature and acceleration (headings wrapped)."""
        return TrackRecord(
            actor_id=trajectory.actor_id,
            actor_class=trajectory.actor_class,
            size=trajectory.size,
            confidence=1.0,
            stamps_ns=trajectory.stamps_ns,
            xyz=np.column_stack([trajectory.x, trajectory.y, trajectory.z]),
            yaw=wrapped(trajectory.yaw),
            velocity=trajectory.speed,
            curvature=trajectory.curvature,
            acceleration=trajectory.accel,
        )

    @staticmethod
    def from_executed(executed: ExecutedTrajectory, size: FloatArray, wheelbase: float, offset_ns: int) -> TrackRecord:
        """What the ego drove in closed loop (the Episode's executed track), stamps shifted by +offset_ns."""
        states = executed.states
        return TrackRecord(
            actor_id="ego",
            actor_class=ActorClass.VEHICLE,
            size=size,
            confidence=1.0,
            stamps_ns=executed.stamps_ns + offset_ns,
            xyz=np.column_stack([states[:, :2], np.zeros(states.shape[0])]),
            yaw=states[:, 2],
            velocity=states[:, 3],
            curvature=np.tan(states[:, 5]) / wheelbase,
            acceleration=states[:, 4],
        )

    def to_executed(self, wheelbase: float, offset_ns: int) -> ExecutedTrajectory:
        """The inverse of from_executed, stamps shifted by -offset_ns (the plans are not carried)."""
        steer = np.arctan(self.curvature * wheelbase)
        states = np.column_stack([self.xyz[:, :2], self.yaw, self.velocity, self.acceleration, steer])
        return ExecutedTrajectory(self.stamps_ns - offset_ns, states, ())

    def to_actor_track(self) -> ActorTrack:
        return ActorTrack(
            actor_id=self.actor_id,
            actor_class=self.actor_class,
            size=self.size,
            stamps_ns=self.stamps_ns,
            centers=self.xyz,
            yaws=self.yaw,
        )

    def shifted(self, offset_ns: int) -> TrackRecord:
        """The same states stamped offset_ns later (log time <-> a query's sim time)."""
        return dataclasses.replace(self, stamps_ns=self.stamps_ns + offset_ns)

    def state(self, index: int) -> TrackRecord:
        """The record with only state ``index`` (a scenario bag's per-frame ActorTrackArray)."""
        pick = slice(index, index + 1)
        return TrackRecord(
            self.actor_id, self.actor_class, self.size, self.confidence, self.stamps_ns[pick], self.xyz[pick],
            self.yaw[pick], self.velocity[pick], self.curvature[pick], self.acceleration[pick],
        )  # fmt: skip


def track_msg(record: TrackRecord) -> Msg:
    # A prediction carries tracks x 50 states per sweep: the classes are looked up once and the
    # states built positionally (fields in the .msg order), which halves the cost per state.
    types = codec.typestore().types
    state, time = types[names.ACTOR_STATE], types[names.TIME]
    seconds, nanoseconds = np.divmod(record.stamps_ns, NS_PER_S)
    states = [
        state(time(sec, nanosec), x, y, z, yaw, velocity, curvature, acceleration)
        for sec, nanosec, (x, y, z), yaw, velocity, curvature, acceleration in zip(
            seconds.tolist(),
            nanoseconds.tolist(),
            record.xyz.tolist(),
            record.yaw.tolist(),
            record.velocity.tolist(),
            record.curvature.tolist(),
            record.acceleration.tolist(),
            strict=True,
        )
    ]
    length, width, height = (float(v) for v in record.size)
    return message(
        names.ACTOR_TRACK,
        actor_id=record.actor_id,
        actor_class=record.actor_class.value,
        length=length,
        width=width,
        height=height,
        confidence=float(record.confidence),
        states=states,
    )


def track_array_msg(
    records: Sequence[TrackRecord], stamp: int, frame_id: str, *, query_id: int = 0, run_id: int = 0
) -> Msg:
    return message(
        names.ACTOR_TRACK_ARRAY,
        header=header_msg(stamp, frame_id),
        run_id=int(run_id),
        query_id=int(query_id),
        tracks=[track_msg(record) for record in records],
    )


# CDR (little-endian) of one ActorState that starts 8-aligned: the stamp, then its seven float64 unpadded.
_STATE_CDR = np.dtype([("sec", "<i4"), ("nanosec", "<u4"), ("values", "<f8", (7,))])


def track_array_cdr(
    actor_ids: Sequence[str],
    actor_classes: Sequence[ActorClass],
    sizes: FloatArray,
    confidences: FloatArray,
    stamps_ns: IntArray,
    states: FloatArray,
    stamp: int,
    frame_id: str,
    *,
    query_id: int = 0,
    run_id: int = 0,
) -> bytes:
    """CDR of an ActorTrackArray whose N tracks share T stamps, straight from arrays.

    sizes (N, 3), confidences (N,), stamps_ns (T,), states (N, T, 7): x, y, z, yaw, velocity,
    curvature, acceleration. Byte for byte what ``codec.encode(track_array_msg(...))`` gives for
    the same tracks; a stack's detections and predictions (hundreds of tracks x 50 states every
    sweep) cost a few milliseconds this way instead of tens through message objects.
    """
    count, steps = len(actor_ids), int(np.asarray(stamps_ns).shape[0])
    values = np.asarray(states, dtype=np.float64).reshape(count, steps, 7)
    block = np.zeros((count, steps), dtype=_STATE_CDR)
    seconds, nanoseconds = np.divmod(np.asarray(stamps_ns, dtype=np.int64), NS_PER_S)
    block["sec"], block["nanosec"], block["values"] = seconds, nanoseconds, values
    raw = block.tobytes()
    track_bytes = steps * _STATE_CDR.itemsize
    payload = bytearray()
    codec.cdr_header(payload, stamp, frame_id)
    codec.cdr_align(payload, 8)
    payload.extend(struct.pack("<QQI", int(run_id), int(query_id), count))
    dimensions = np.asarray(sizes, dtype=np.float64).tolist()
    scores = np.asarray(confidences, dtype=np.float64).tolist()
    for index in range(count):
        codec.cdr_string(payload, actor_ids[index])
        codec.cdr_string(payload, actor_classes[index].value)
        codec.cdr_align(payload, 8)
        payload.extend(struct.pack("<dddfI", *dimensions[index], scores[index], steps))
        chunk = raw[index * track_bytes : (index + 1) * track_bytes]
        if steps and len(payload) % 8:
            # The first stamp sits 4 bytes off an 8-byte boundary: its x is padded, the rest are aligned.
            payload.extend(chunk[:8])
            payload.extend(bytes(4))
            payload.extend(chunk[8:])
        else:
            payload.extend(chunk)
    return codec.CDR_LE_HEADER + bytes(payload)


def track_from_msg(track: Msg) -> TrackRecord:
    """The TrackRecord of one ActorTrack; ContractError for no states, an unknown class or non-finite values."""
    actor_id = str(track.actor_id)
    if not track.states:
        raise ContractError(f"track {actor_id!r} has no states")
    try:
        actor_class = ActorClass(str(track.actor_class))
    except ValueError:
        known = ", ".join(c.value for c in ActorClass)
        raise ContractError(f"track {actor_id!r} has unknown class {track.actor_class!r} (one of {known})") from None
    values = np.array(
        [(s.x, s.y, s.z, s.yaw, s.velocity, s.curvature, s.acceleration) for s in track.states],
        dtype=np.float64,
    )
    if not np.all(np.isfinite(values[:, :4])):
        raise ContractError(f"track {actor_id!r} has a NaN or infinite state")
    size = np.array([track.length, track.width, track.height], dtype=np.float64)
    return TrackRecord(
        actor_id=actor_id,
        actor_class=actor_class,
        size=size,
        confidence=float(track.confidence),
        stamps_ns=np.array([stamp_ns(s.stamp) for s in track.states], dtype=np.int64),
        xyz=values[:, :3],
        yaw=values[:, 3],
        velocity=values[:, 4],
        curvature=values[:, 5],
        acceleration=values[:, 6],
    )


@dataclass(frozen=True, eq=False)
class TrackArrayRecord:
    """What one advsim_msgs/ActorTrackArray carries."""

    stamp_ns: int  # header stamp [ns]
    frame_id: str
    run_id: int
    query_id: int
    tracks: tuple[TrackRecord, ...]

    def actor_tracks(self) -> tuple[ActorTrack, ...]:
        return tuple(track.to_actor_track() for track in self.tracks)


def track_array_from_msg(array: Msg) -> TrackArrayRecord:
    try:
        tracks = tuple(track_from_msg(track) for track in array.tracks)
    except ContractError as error:
        raise ContractError(f"ActorTrackArray of query {array.query_id}: {error}") from None
    return TrackArrayRecord(
        stamp_ns=stamp_ns(array.header.stamp),
        frame_id=str(array.header.frame_id),
        run_id=int(getattr(array, "run_id", 0)),  # bags written before run ids existed
        query_id=int(array.query_id),
        tracks=tracks,
    )


def wrapped(yaws: FloatArray) -> FloatArray:
    """Headings in [-pi, pi] (IEEE remainder, as states on the wire carry them)."""
    return np.array([math.remainder(float(yaw), math.tau) for yaw in yaws], dtype=np.float64)
