"""Closed loop in the graph: after the decision, the ego drives the stack's plans and the stack sees where it is.

The player runs ``core.closed_loop.drive_closed_loop`` with a planner that is the lock-step
exchange with the stack: at every frame after the decision the controller's state is the ego's
pose; lidar_resim is asked for that frame's sweep *from that pose* (FrameRequest.world_T_ego),
/clock, /tf and /ego/odom come from the simulated ego, and the stack's answer is the plan the
controller tracks until the next frame. A frame whose plan does not come keeps the previous plan
(counted as missing). Everything sent and answered goes into the query's digests, as in the
history. With reactive actors (``ClosedLoopSetup.reactive``) the query's actors step with the ego
(core.reactive), and each frame is asked for with the actors that left their tracks where they are.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from advsim_ros.contract import codec, names
from advsim_ros.contract.codec import Msg
from advsim_ros.contract.plan import plan_from_path
from advsim_ros.core.closed_loop import (
    ControllerConfig,
    ExecutedTrajectory,
    VehicleState,
    drive_closed_loop,
    initial_state,
)
from advsim_ros.core.episode import EpisodeClock, WindowConfig
from advsim_ros.core.lidar.boxes import yaw_pose
from advsim_ros.core.reactive import IdmConfig, ReactiveTraffic
from advsim_ros.core.types import (
    ActorTrack,
    EgoGeometry,
    EgoTrajectory,
    FloatArray,
    IntArray,
    Plan,
    Scenario,
    ScenarioError,
    replace_actors,
)

LOOPS = ("open", "closed")


@dataclass(frozen=True, eq=False)
class LoopFrame:
    """A frame after the decision, as the closed loop replays it."""

    log_frame: int  # index in the log
    log_stamp_ns: int
    logged_world_T_ego: FloatArray  # (4, 4) where the ego was in the log (its height is kept)


@dataclass(frozen=True, eq=False)
class ReactiveSetup:
    """Reactive actors: what a query's traffic is made of besides its perturbed tracks."""

    config: IdmConfig
    actors: Sequence[ActorTrack]  # the log's actors (a query's perturbed tracks replace theirs)
    logged_ego: EgoTrajectory  # the desired gaps may keep to what the tracks kept to the logged ego
    ego: EgoGeometry

    def traffic(self, moved: Sequence[ActorTrack], start_ns: int, control_period: float) -> ReactiveTraffic:
        world = replace_actors(self.actors, moved)
        return ReactiveTraffic(world, start_ns, control_period, self.ego, self.config, self.logged_ego)


@dataclass(frozen=True, eq=False)
class ClosedLoopSetup:
    """What the player needs to close the loop of one window (the same for every query)."""

    controller: ControllerConfig
    start: VehicleState  # the ego at the decision frame, as logged
    decision_stamp_ns: int  # log time
    frames: Sequence[LoopFrame]  # the frames the stack replans from after the decision, in order
    period_s: float  # frame period: one sweep, one replan [s]
    ego_size: FloatArray  # (3,) the ego's box: length, width, height [m]
    reactive: ReactiveSetup | None = None  # None: actors drive their (perturbed or logged) tracks

    @property
    def horizon_s(self) -> float:
        """The drive lasts one frame beyond the last replan."""
        return (len(self.frames) + 1) * self.period_s


def closed_loop_setup(
    scenario: Scenario,
    frames: range,
    odometry: Sequence[Msg],  # nav_msgs/Odometry
    window: WindowConfig,
    controller: ControllerConfig,
    idm: IdmConfig | None,
) -> ClosedLoopSetup:
    """The drive after the decision: from the logged ego there, over the window's future frames.

    ``frames``: the window's log frames; ``odometry``: the log's nav_msgs/Odometry per frame (its twist
    is the ego's logged speed and yaw rate); ``idm``: the reactive actors' model, None when they are not.
    """
    decision = frames.start + window.decision_index
    logged = odometry[decision].twist.twist
    start = initial_state(
        scenario.ego.poses[decision], float(np.hypot(logged.linear.x, logged.linear.y)), logged.angular.z, controller
    )
    stamps = scenario.frame_stamps_ns
    return ClosedLoopSetup(
        controller=controller,
        start=start,
        decision_stamp_ns=int(stamps[decision]),
        frames=loop_frames(stamps, scenario.ego.poses, range(decision + 1, frames.stop - 1)),  # 5 s
        period_s=window.frame_period,
        ego_size=scenario.ego_geometry.size,
        reactive=ReactiveSetup(idm, scenario.actors, scenario.ego, scenario.ego_geometry) if idm is not None else None,
    )


@dataclass
class LoopCounts:
    delivered: int = 0  # sweeps sent
    received: int = 0  # plans back
    awaited: int = 0


Exchange = Callable[[int, int, LoopFrame, FloatArray, VehicleState, tuple[ActorTrack, ...]], tuple[bool, bytes | None]]


def close_loop(
    query_id: int,
    first_index: int,
    setup: ClosedLoopSetup,
    decision_plan: Plan,
    clock: EpisodeClock,
    exchange: Exchange,
    moved: Sequence[ActorTrack] = (),
) -> tuple[ExecutedTrajectory, LoopCounts, tuple[ActorTrack, ...]]:
    """Drive the window's horizon from the decision; ``exchange`` sends one frame and waits for the plan.

    ``exchange(frame_index, sim_stamp, frame, world_T_ego, state, off_track)`` returns (sweep sent,
    plan CDR or None); ``off_track``: the reactive actors that left their tracks, where they are
    (log time). Plans are taken into log time with the query's clock offset. Returns what the ego
    drove, the counts, and the drives of the actors that reacted (log time; none without
    ``setup.reactive``). ``moved``: the query's perturbed tracks.
    """
    counts = LoopCounts()
    current = [decision_plan]
    by_stamp = {frame.log_stamp_ns: (index, frame) for index, frame in enumerate(setup.frames)}
    traffic = None
    if setup.reactive is not None:
        traffic = setup.reactive.traffic(moved, setup.decision_stamp_ns, setup.controller.control_period)

    def planner(now_ns: int, state: VehicleState) -> Plan:
        if now_ns == setup.decision_stamp_ns:
            return decision_plan
        if now_ns not in by_stamp:
            raise ScenarioError(f"closed loop: no log frame at {now_ns} ns (frame period and control period disagree)")
        index, frame = by_stamp[now_ns]
        world_T_ego = yaw_pose([state.x, state.y, float(frame.logged_world_T_ego[2, 3])], state.yaw)
        sim = clock.to_sim(query_id, now_ns)
        off_track = traffic.off_track() if traffic is not None else ()
        sent, answer = exchange(first_index + index, sim, frame, world_T_ego, state, off_track)
        counts.delivered += int(sent)
        counts.awaited += 1
        if answer is not None:
            counts.received += 1
            current[0] = plan_from_path(codec.decode(answer, names.PATH), sim - now_ns)
        return current[0]

    executed = drive_closed_loop(
        setup.start, planner, setup.decision_stamp_ns, setup.horizon_s, setup.period_s, setup.controller, traffic
    )
    return executed, counts, traffic.drives() if traffic is not None else ()


def loop_frames(stamps_ns: Sequence[int] | IntArray, poses: FloatArray, frames: range) -> list[LoopFrame]:
    """LoopFrames of these log frames."""
    return [LoopFrame(i, int(stamps_ns[i]), np.asarray(poses[i])) for i in frames]
