"""Reactive actors in closed loop: each keeps its path, the Intelligent Driver Model governs its progress.

Non-reactive actors replay their (perturbed or logged) tracks whatever the ego does, so a car
logged behind the ego drives through a simulated ego that braked. A reactive actor keeps the
geometry of its track (the polyline of its box centres) but its progress along it follows the
Intelligent Driver Model (M. Treiber, A. Hennecke, D. Helbing, "Congested traffic states in
empirical observations and microscopic simulations", Phys. Rev. E 62, 1805, 2000), its leader
being the simulated ego whenever the ego's box is ahead on the path and within its corridor
(the ego's centre no further from the path than half the actor's width, half the ego box's
extent across the path and ``corridor_margin``):

    s*      = max(min(s0, base), base + v dv / (2 sqrt(a b)))   desired gap, base = s0 + v T
    a_free  = a (1 - (v / v0)^delta)                            free road; v0: the track's speed at that time
    a_int   = a (1 - (s* / s)^2)                                the leader at gap s (bumper to bumper, along the path)
    dv/dt   = min(a_free, a_int), within [-max_decel, a]

- The actor keeps *exactly* to its track until the ego, as its leader, is closer than s*; from
  then on the law above moves it, but never ahead of where its track is at that time: once it has
  caught up with its track it drives the track again. Reacting only ever holds an actor back, and
  an actor the ego never comes that close to is where its track says, state for state.
- ``min(a_free, a_int)`` instead of IDM's ``a_free - a (s*/s)^2``: with v0 the track's own speed,
  IDM's sum would make a follower fall back from any leader however far (its equilibrium gap at
  v = v0 is infinite), so an actor driving its track at a comfortable distance behind an ego that
  drives as logged would still brake. For gaps below s* this is the improved IDM's law (Treiber &
  Kesting, "Traffic Flow Dynamics", 2013); at larger gaps the interaction only caps acceleration.
- Logs hold drivers who follow closer than IDM's s0 + v T (1.6 s). With ``accept_logged_gaps``
  the static part of the desired gap is at most the gap the actor's track kept to the *logged*
  ego at that time (when the logged ego led it), so a car tailgating in the log is not made to
  brake by an ego that drives as logged; the closing-speed part of s* is kept, so it brakes as
  IDM does when the ego brakes harder than logged.
- Only vehicles whose track moves (``moving_speed`` at some time from the start on) react;
  pedestrians, cyclists, other classes and standing vehicles keep their tracks.
- Longitudinal only, along the fixed path: no lane changes, no swerving, no reaction to other
  actors or to an ego behind or beside it.

Deterministic: stepped at the closed loop's control period with the ego's state at the start of
each step (``drive_closed_loop(traffic=...)``); no clocks, no randomness.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, fields

import numpy as np

from advsim_ros.core.closed_loop import VehicleState
from advsim_ros.core.futures import interpolate_trajectory
from advsim_ros.core.metrics import NS_PER_S, human_at
from advsim_ros.core.types import (
    ActorClass,
    ActorTrack,
    EgoGeometry,
    EgoTrajectory,
    FloatArray,
    IntArray,
    ScenarioError,
)

EXTENSION = 200.0  # the path goes on straight this far past the track's end (an ego ahead of its end) [m]
LOGGED_GAP_FLOOR = 0.5  # a logged gap counts as at least this: a log's touching boxes do not license contact [m]
GAP_TOLERANCE = 0.01  # closer than desired by less than this keeps an actor on its track (rounding, tracking) [m]
SAME_POINT = 1e-6  # consecutive track positions closer than this are one point of the path [m]


@dataclass(frozen=True)
class IdmConfig:
    """Reactive actors' law; IDM's defaults are the car values of Treiber, Hennecke & Helbing (2000), Table 1."""

    time_headway: float = 1.6  # T: desired time gap to the leader [s]
    min_gap: float = 2.0  # s0: bumper-to-bumper gap at a standstill [m]
    max_accel: float = 0.73  # a [m/s^2]
    comfortable_decel: float = 1.67  # b [m/s^2]
    exponent: float = 4.0  # delta: how acceleration falls off toward the desired speed
    max_decel: float = 8.0  # physical braking limit (IDM's is unbounded; the ego controller's full brake) [m/s^2]
    corridor_margin: float = 0.5  # the ego leads when its centre is within half the two widths plus this [m]
    moving_speed: float = 0.5  # only vehicles whose track reaches this speed from the start on react [m/s]
    accept_logged_gaps: bool = True  # desired gap at most what the track kept to the logged ego (see module)

    def __post_init__(self) -> None:
        for item in fields(self):
            value = getattr(self, item.name)
            if isinstance(value, bool):
                continue
            if not (math.isfinite(value) and (value >= 0.0 if item.name == "corridor_margin" else value > 0.0)):
                raise ScenarioError(f"IdmConfig {item.name}: must be a positive number, got {value}")

    def desired_gap(self, speed: float, closing: float, logged_gap: float | None) -> float:
        """s* at a speed and a closing speed (own minus the leader's) [m]; see the module for the logged gap."""
        base = self.min_gap + speed * self.time_headway
        if logged_gap is not None and self.accept_logged_gaps:
            base = min(base, max(logged_gap, LOGGED_GAP_FLOOR))
        dynamic = speed * closing / (2.0 * math.sqrt(self.max_accel * self.comfortable_decel))
        return max(min(self.min_gap, base), base + dynamic)

    def acceleration(self, speed: float, desired_speed: float, leader: tuple[float, float] | None) -> float:
        """min(free road, interaction) within the limits; leader: (gap [m], desired gap [m]) or None."""
        ratio = speed / max(desired_speed, 1e-3)  # a track standing (v0 = 0): the free term brakes hard
        accel = self.max_accel * (1.0 - ratio**self.exponent)
        if leader is not None:
            gap, desired = leader
            interaction = -math.inf if gap <= 0.0 else self.max_accel * (1.0 - (desired / gap) ** 2)
            accel = min(accel, interaction)
        return float(np.clip(accel, -self.max_decel, self.max_accel))


@dataclass(frozen=True, eq=False)
class ActorPath:
    """One track as a path: arc length at each of its states, and positions and headings by arc length."""

    track: ActorTrack
    times: FloatArray  # (T,) the track's stamps since its first [s]
    arc: FloatArray  # (T,) arc length of the box centre at each track state [m]
    knots: FloatArray  # (M,) strictly increasing arc lengths of the path's points, the straight extension last [m]
    points: FloatArray  # (M, 3) box centre x, y, z there [m]
    yaws: FloatArray  # (M,) heading there, unwrapped [rad]

    @staticmethod
    def of(track: ActorTrack) -> ActorPath:
        xy = track.centers[:, :2]
        steps = np.linalg.norm(np.diff(xy, axis=0), axis=1)
        arc = np.concatenate([[0.0], np.cumsum(steps)])
        keep = np.concatenate([[True], steps > SAME_POINT])  # standing still adds no point to the path
        yaws = np.unwrap(track.yaws)
        knots, points, headings = arc[keep], track.centers[keep], yaws[keep]
        last = float(headings[-1])
        ahead = points[-1] + EXTENSION * np.array([math.cos(last), math.sin(last), 0.0])
        return ActorPath(
            track,
            (track.stamps_ns - track.stamps_ns[0]).astype(np.float64) / NS_PER_S,
            arc,
            np.append(knots, knots[-1] + EXTENSION),
            np.vstack([points, ahead]),
            np.append(headings, last),
        )

    def progress_at(self, stamp_ns: int) -> float:
        """Where the track is along the path at a stamp (held outside the track's span) [m]."""
        now = (stamp_ns - int(self.track.stamps_ns[0])) / NS_PER_S
        return float(np.interp(now, self.times, self.arc))

    def speed_at(self, stamp_ns: int) -> float:
        """The track's speed along the path over the frame interval holding the stamp (0 outside its span) [m/s]."""
        stamps = self.track.stamps_ns
        index = int(np.searchsorted(stamps, stamp_ns, side="right")) - 1
        if index < 0 or index >= stamps.shape[0] - 1:
            return 0.0
        return float((self.arc[index + 1] - self.arc[index]) / ((stamps[index + 1] - stamps[index]) / NS_PER_S))

    def pose_at(self, progress: float) -> tuple[FloatArray, float]:
        """Box centre (3,) and heading at an arc length (the extension past the track's end)."""
        point = np.array([np.interp(progress, self.knots, self.points[:, axis]) for axis in range(3)])
        return point, float(np.interp(progress, self.knots, self.yaws))

    def project(self, xy: FloatArray) -> tuple[float, float, float]:
        """The point of the path nearest xy: (its arc length [m], the distance to it [m], the path's heading there)."""
        starts, ends = self.points[:-1, :2], self.points[1:, :2]
        segments = ends - starts
        lengths = np.linalg.norm(segments, axis=1)
        fraction = np.clip(np.einsum("ij,ij->i", xy - starts, segments) / lengths**2, 0.0, 1.0)
        nearest = starts + fraction[:, None] * segments
        distances = np.linalg.norm(xy - nearest, axis=1)
        index = int(np.argmin(distances))
        heading = math.atan2(float(segments[index, 1]), float(segments[index, 0]))
        return float(self.knots[index] + fraction[index] * lengths[index]), float(distances[index]), heading


def ego_ahead(
    path: ActorPath, progress: float, ego_box: FloatArray, ego_speed: float, margin: float
) -> tuple[float, float] | None:
    """(gap [m], the ego's speed along the path [m/s]) when the ego's box leads the actor at ``progress``, else None.

    The gap is bumper to bumper along the path: the ego's centre's arc length minus the actor's,
    less half the actor's length and the ego box's half extent along the path.
    """
    along_ego, lateral, heading = path.project(ego_box[:2])
    if along_ego <= progress:
        return None  # behind or beside the actor: IDM follows what is ahead only
    relative = float(ego_box[2]) - heading
    length, width = float(ego_box[3]), float(ego_box[4])
    cos, sin = abs(math.cos(relative)), abs(math.sin(relative))
    half_along, half_across = 0.5 * (length * cos + width * sin), 0.5 * (length * sin + width * cos)
    if lateral > half_across + 0.5 * path.track.width + margin:
        return None
    gap = along_ego - progress - half_along - 0.5 * path.track.length
    return gap, ego_speed * math.cos(relative)


class _Actor:
    """One reactive actor's state during a drive (mutable; owned by ReactiveTraffic)."""

    def __init__(self, path: ActorPath, start_ns: int) -> None:
        self.path = path
        self.progress = path.progress_at(start_ns)
        self.speed = path.speed_at(start_ns)
        self.reacting = False  # off its track now: the IDM moves it
        self.reacted = False  # left its track at some time of the drive
        self.rows: list[FloatArray] = []

    def record_on_track(self, stamps_ns: IntArray) -> None:
        """Rows of the track's own poses (exactly as the non-reactive actor's) at these stamps."""
        track = self.path.track
        xy, yaws, _ = interpolate_trajectory(track.stamps_ns, track.centers[:, :2], track.yaws, stamps_ns)
        times = (track.stamps_ns - track.stamps_ns[0]).astype(np.float64)
        z = np.interp((stamps_ns - track.stamps_ns[0]).astype(np.float64), times, track.centers[:, 2])
        self.rows.extend(np.column_stack([xy, z, yaws]))

    def record_at_progress(self) -> None:
        point, yaw = self.path.pose_at(self.progress)
        self.rows.append(np.array([*point, math.remainder(yaw, math.tau)]))


class ReactiveTraffic:
    """The actors of one closed-loop drive, stepped with the ego (one object per drive: it keeps state).

    ``step(now_ns, ego)`` moves every reactive actor from ``now_ns`` to ``now_ns`` + the control
    period with the ego's state at ``now_ns`` (``drive_closed_loop`` calls it after each control
    step). ``off_track()`` gives where the actors that reacted are now (for the sweep of this
    frame), ``drives()`` their whole drive.
    """

    def __init__(
        self,
        actors: Sequence[ActorTrack],
        start_ns: int,
        control_period: float,
        ego: EgoGeometry,
        config: IdmConfig | None = None,
        logged_ego: EgoTrajectory | None = None,
    ) -> None:
        self.config = config or IdmConfig()
        self.ego = ego
        self.logged_ego = logged_ego
        self.start_ns = start_ns
        self.now_ns = start_ns
        self.step_ns = round(control_period * NS_PER_S)
        if self.step_ns <= 0:
            raise ScenarioError(f"reactive actors: control period must be positive, got {control_period} s")
        self.actors = [_Actor(ActorPath.of(track), start_ns) for track in actors if self._reacts(track, start_ns)]
        for actor in self.actors:
            actor.record_on_track(np.array([start_ns], dtype=np.int64))

    def _reacts(self, track: ActorTrack, start_ns: int) -> bool:
        """Vehicles whose track spans the start and moves from then on (the others keep their tracks)."""
        stamps = track.stamps_ns
        if track.actor_class is not ActorClass.VEHICLE or not stamps[0] <= start_ns < stamps[-1]:
            return False
        later = stamps >= stamps[max(int(np.searchsorted(stamps, start_ns, side="right")) - 1, 0)]
        steps = np.linalg.norm(np.diff(track.centers[later, :2], axis=0), axis=1)
        speeds = steps / (np.diff(stamps[later]) / NS_PER_S)
        return bool(speeds.size and speeds.max() >= self.config.moving_speed)

    @property
    def reactive_ids(self) -> tuple[str, ...]:
        return tuple(actor.path.track.actor_id for actor in self.actors)

    def step(self, now_ns: int, ego: VehicleState) -> None:
        if now_ns != self.now_ns:
            raise ScenarioError(f"reactive actors: stepped at {now_ns} ns, they are at {self.now_ns} ns")
        config, dt = self.config, self.step_ns / NS_PER_S
        ego_box = self.ego.boxes(np.array([ego.x, ego.y]), np.array(ego.yaw))
        logged_box = self._logged_box(now_ns)
        after = now_ns + self.step_ns
        for actor in self.actors:
            path = actor.path
            leader = ego_ahead(path, actor.progress, ego_box, ego.speed, config.corridor_margin)
            desired = None
            if leader is not None:
                logged_gap = None
                if logged_box is not None:
                    logged = ego_ahead(path, path.progress_at(now_ns), logged_box, 0.0, config.corridor_margin)
                    logged_gap = None if logged is None else logged[0]
                desired = config.desired_gap(actor.speed, actor.speed - leader[1], logged_gap)
                if not actor.reacting and leader[0] < desired - GAP_TOLERANCE:
                    actor.reacting = actor.reacted = True  # the ego is closer than it wants: the IDM takes over
            if not actor.reacting:
                actor.progress, actor.speed = path.progress_at(after), path.speed_at(after)
                actor.record_on_track(np.array([after], dtype=np.int64))
                continue
            gap = None if leader is None or desired is None else (leader[0], desired)
            accel = config.acceleration(actor.speed, path.speed_at(now_ns), gap)
            speed = actor.speed + accel * dt
            if speed < 0.0:  # stops within the step: no reversing
                actor.progress += actor.speed**2 / (2.0 * -accel)
                actor.speed = 0.0
            else:
                actor.progress += 0.5 * (actor.speed + speed) * dt
                actor.speed = speed
            if actor.progress >= path.progress_at(after):  # caught up with its track: never ahead of it
                actor.reacting = False
                actor.progress, actor.speed = path.progress_at(after), path.speed_at(after)
                actor.record_on_track(np.array([after], dtype=np.int64))
                continue
            actor.record_at_progress()
        self.now_ns = after

    def _logged_box(self, stamp_ns: int) -> FloatArray | None:
        if self.logged_ego is None or not self.config.accept_logged_gaps:
            return None
        xy, yaws, valid = human_at(self.logged_ego, np.array([stamp_ns], dtype=np.int64))
        return self.ego.boxes(xy[0], yaws[0]) if bool(valid[0]) else None

    def off_track(self) -> tuple[ActorTrack, ...]:
        """The actors off their tracks now, each with one state: where it is (log time); none after its track ends."""
        return tuple(
            _track(actor.path.track, np.array([self.now_ns], dtype=np.int64), actor.rows[-1][None])
            for actor in self.actors
            if actor.reacting and self.now_ns <= int(actor.path.track.stamps_ns[-1])
        )

    def drives(self, reacted_only: bool = True) -> tuple[ActorTrack, ...]:
        """Each reactive actor's drive, one state per control step from the start (log time): by default only
        of those that left their tracks at some time (the others drove their tracks exactly).

        A drive ends where its track ends: the actor was not observed after that, so it does not exist then
        (its rows beyond would be the track's last state held, or the straight extension of its path).
        """
        stamps = self.start_ns + self.step_ns * np.arange(len(self.actors[0].rows) if self.actors else 0)
        drives = []
        for actor in self.actors:
            if actor.reacted or not reacted_only:
                observed = stamps <= int(actor.path.track.stamps_ns[-1])  # the first row is: tracks span the start
                rows = np.array(actor.rows)[observed]
                drives.append(_track(actor.path.track, stamps[observed].astype(np.int64), rows))
        return tuple(drives)


def _track(track: ActorTrack, stamps_ns: IntArray, rows: FloatArray) -> ActorTrack:
    return ActorTrack(track.actor_id, track.actor_class, track.size, stamps_ns, rows[:, :3], rows[:, 3])


def with_reactions(actors: Sequence[ActorTrack], reacted: Sequence[ActorTrack]) -> tuple[ActorTrack, ...]:
    """The actors with each reacted drive spliced in: the track before the drive's first stamp, the drive after."""
    by_id = {track.actor_id: track for track in reacted}
    spliced = []
    for actor in actors:
        drive = by_id.get(actor.actor_id)
        if drive is None:
            spliced.append(actor)
            continue
        before = actor.stamps_ns < drive.stamps_ns[0]
        spliced.append(
            ActorTrack(
                actor.actor_id,
                actor.actor_class,
                actor.size,
                np.concatenate([actor.stamps_ns[before], drive.stamps_ns]),
                np.vstack([actor.centers[before], drive.centers]),
                np.concatenate([actor.yaws[before], drive.yaws]),
            )
        )
    return tuple(spliced)


def with_overrides(moved: Sequence[ActorTrack], overrides: Sequence[ActorTrack]) -> tuple[ActorTrack, ...]:
    """A query's moved actors with these tracks in place of (or beside) theirs: a reactive frame's world."""
    replaced = {track.actor_id for track in overrides}
    return (*(track for track in moved if track.actor_id not in replaced), *overrides)
