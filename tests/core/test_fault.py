"""Fault and avoidability of colliding queries on hand-made scenes whose classes are known, and on a KITTI window."""

from __future__ import annotations

import json

import numpy as np
import pytest

from advsim_ros.core.closed_loop import ControllerConfig
from advsim_ros.core.evasion import EgoLimits, EgoStart, EvasionFamily, evasion_candidates, longitudinal_profiles
from advsim_ros.core.fault import Avoidability, EgoSide, Mover, Verdict, avoidability, classify_collision, first_contact
from advsim_ros.core.futures import ActorFutures
from advsim_ros.core.metrics import MetricsConfig, query_metrics
from advsim_ros.core.types import (
    ActorClass,
    ActorTrack,
    DrivableArea,
    EgoGeometry,
    EgoTrajectory,
    Plan,
    Scenario,
)

DT = 0.1  # [s]
START_NS = 1_000_000_000_000
DECISION = 10  # the human's log starts 1 s before the decision
EGO = EgoGeometry(np.array([4.5, 1.9, 1.7]), forward_offset=1.0)  # box from 1.25 m behind the origin to 3.25 ahead
TIMES = np.arange(51) * DT  # the plan's stamps: the decision, then 5 s at 10 Hz
CAR = (4.0, 2.0)  # an actor's length and width [m]


def _human(speed: float, frames: int = 80) -> EgoTrajectory:
    """The logged ego driving along +x at a constant speed, through x = 0 at the decision."""
    times = (np.arange(frames) - DECISION) * DT
    poses = np.tile(np.eye(4), (frames, 1, 1))
    poses[:, 0, 3] = speed * times
    return EgoTrajectory(START_NS + np.round(times * 1e9).astype(np.int64), poses)


def _stamps() -> np.ndarray:
    return START_NS + np.round(TIMES * 1e9).astype(np.int64)


def _keeping(speed: float) -> Plan:
    """A plan that keeps the speed on the human's path (it does not brake)."""
    return Plan(_stamps(), np.stack([speed * TIMES, np.zeros_like(TIMES)], axis=-1), np.zeros_like(TIMES))


def _actor(x: np.ndarray, y: np.ndarray, yaw: np.ndarray | float = 0.0) -> ActorFutures:
    states = np.stack([x, y, np.broadcast_to(yaw, x.shape)], axis=-1)[None]
    return ActorFutures(states, np.array([CAR]))


def _braking_lead() -> ActorFutures:
    """A lead 15 m ahead at 10 m/s that brakes at 6 m/s² from 0.5 s to a standstill (rear at 26.33 m)."""
    speed = np.where(TIMES < 0.5, 10.0, np.maximum(10.0 - 6.0 * (TIMES - 0.5), 0.0))
    x = 15.0 + np.concatenate([[0.0], np.cumsum(0.5 * (speed[1:] + speed[:-1]) * DT)])
    return _actor(x, np.zeros_like(x))


def _cutting_in() -> ActorFutures:
    """A car at 5 m/s, 10 m ahead in the left lane, cutting in at 3.5 m/s to straddle the lane line (y = 1.5)."""
    y = np.maximum(3.5 - 3.5 * TIMES, 1.5)
    return _actor(10.0 + 5.0 * TIMES, y, np.where(y > 1.5, -np.arctan2(3.5, 5.0), 0.0))


def _two_lanes() -> DrivableArea:
    """A road of the ego's lane (|y| <= 1.75 m) and the lane to its left, nothing to the right."""
    return DrivableArea(np.array([-50.0, -1.75]), 0.25, np.ones((28, 800), dtype=bool), "map")  # x in [-50, 150]


def _judge(speed: float, actors: ActorFutures, drivable: DrivableArea | None = None) -> Avoidability:
    human = _human(speed)
    return avoidability(EgoStart.from_log(human, DECISION), human, EGO, actors, _stamps(), drivable=drivable)


def test_rear_ended_while_following_the_humans_path_is_unavoidable_and_the_actor_moved_into_the_ego() -> None:
    # 12 m behind at 20 m/s against the ego's 10 m/s: 8.75 m closed at 10 m/s, contact at 0.875 s. Neither
    # braking, accelerating (3 m/s²) nor a swerve the steering can make in time gets the ego out of the way.
    actors = _actor(-12.0 + 20.0 * TIMES, np.zeros_like(TIMES))
    found = _judge(10.0, actors)
    assert found.verdict is Verdict.UNAVOIDABLE
    assert found.within_limits > 0
    assert found.collision_free == 0
    assert found.first_free == ""
    contact = first_contact(_keeping(10.0), actors, EGO)
    assert contact is not None
    assert contact.time_s == pytest.approx(0.875, abs=1e-3)
    assert contact.side is EgoSide.REAR
    assert contact.point_ego == pytest.approx((-1.25, 0.0), abs=1e-3)
    assert contact.mover is Mover.ACTOR_INTO_EGO
    assert (contact.ego_speed, contact.actor_speed) == pytest.approx((-10.0, 20.0))


def test_a_braking_lead_the_ego_could_stop_behind_is_avoidable_by_braking_in_lane() -> None:
    found = _judge(10.0, _braking_lead())
    assert found.verdict is Verdict.AVOIDABLE
    assert found.in_lane_free > 0
    assert found.first_free.startswith("in lane, brake at")
    # The plan that keeps 10 m/s reaches the standing lead's rear (26.33 m) with its front at 2.308 s.
    contact = first_contact(_keeping(10.0), _braking_lead(), EGO)
    assert contact is not None
    assert contact.time_s == pytest.approx((15.0 + 5.0 + 100.0 / 12.0 - 2.0 - 3.25) / 10.0, abs=1e-3)
    assert contact.side is EgoSide.FRONT
    assert contact.mover is Mover.EGO_INTO_ACTOR
    assert (contact.ego_speed, contact.actor_speed) == pytest.approx((10.0, 0.0))


def test_a_cut_in_too_late_to_brake_for_is_avoidable_only_by_swerving_away() -> None:
    found = _judge(15.0, _cutting_in())
    assert found.verdict is Verdict.AVOIDABLE
    assert found.in_lane_free == 0  # 4.75 m ahead, closing at 10 m/s: no braking in lane gets out of it
    assert found.first_free.startswith("offset -")  # to the right, away from the car
    assert _judge(15.0, _cutting_in(), _two_lanes()).first_free == found.first_free  # a shift within the lane
    contact = first_contact(_keeping(15.0), _cutting_in(), EGO)
    assert contact is not None
    assert contact.side in (EgoSide.FRONT, EgoSide.LEFT)
    assert contact.closing_speed > 0.0


def test_a_car_alongside_drifting_into_the_ego_hits_its_left_side_and_moved_into_it() -> None:
    # Alongside at the ego's 10 m/s, 3.5 m to the left, drifting right at 2 m/s: contact at (3.5 - 1.95) / 2 s.
    y = np.maximum(3.5 - 2.0 * TIMES, 0.0)
    actors = _actor(1.0 + 10.0 * TIMES, y, np.where(y > 0.0, -np.arctan2(2.0, 10.0), 0.0))
    contact = first_contact(_keeping(10.0), actors, EGO)
    assert contact is not None
    assert contact.side is EgoSide.LEFT
    assert contact.mover is Mover.ACTOR_INTO_EGO
    assert contact.ego_speed == pytest.approx(0.0, abs=1e-9)
    assert contact.actor_speed == pytest.approx(2.0, abs=0.05)
    # A swerve into the lane to the right gets away; with no lane there (a box centre stays on the road, as the
    # perturbed actors' do) the ego is rammed from the side on the human's path.
    assert _judge(10.0, actors).first_free.startswith("offset -")
    narrow = _judge(10.0, actors, _two_lanes())
    assert narrow.verdict is Verdict.UNAVOIDABLE
    assert narrow.within_limits < _judge(10.0, actors).within_limits


def test_head_on_both_moved_into_each_other() -> None:
    actors = _actor(40.0 - 10.0 * TIMES, np.zeros_like(TIMES), np.pi)
    contact = first_contact(_keeping(10.0), actors, EGO)
    assert contact is not None
    assert contact.side is EgoSide.FRONT
    assert contact.mover is Mover.BOTH
    assert (contact.ego_speed, contact.actor_speed) == pytest.approx((10.0, 10.0))


def test_without_actors_every_trajectory_within_the_limits_is_free_and_nothing_collides() -> None:
    empty = ActorFutures(np.zeros((0, TIMES.shape[0], 3)), np.zeros((0, 2)))
    found = _judge(10.0, empty)
    assert found.verdict is Verdict.AVOIDABLE
    assert 0 < found.collision_free == found.within_limits < found.tried
    assert found.first_free == "in lane, keep 10.0 m/s"
    assert first_contact(_keeping(10.0), empty, EGO) is None


def _scenario(actors: ActorFutures) -> Scenario:
    human = _human(10.0)
    stamps = human.stamps_ns[DECISION : DECISION + TIMES.shape[0]]
    heights = np.zeros((TIMES.shape[0], 1))
    track = ActorTrack(
        "lead", ActorClass.VEHICLE, np.array([*CAR, 1.5]), stamps, np.hstack([actors.states[0, :, :2], heights]),
        actors.states[0, :, 2],
    )  # fmt: skip
    return Scenario("lead", human.stamps_ns, human, (track,), ego_geometry=EGO)


def test_classify_collision_judges_the_query_as_the_collision_metric_does() -> None:
    scenario = _scenario(_braking_lead())
    plan = _keeping(10.0)
    stack_plan = Plan(plan.stamps_ns[1:], plan.xy[1:], plan.yaws[1:])  # the contract's plans start a step after
    fault = classify_collision(stack_plan, scenario, (), DECISION)
    assert fault is not None
    metrics = query_metrics(plan, scenario.ego, _braking_lead(), EGO, MetricsConfig())
    assert fault.contact.stamp_ns == plan.stamps_ns[round(metrics.first_collision_time / DT)]
    record = json.loads(json.dumps(fault.as_json()))
    assert record["class"] == "avoidable"
    assert record["escape"].startswith("in lane, brake at")
    assert record["contact"]["actor_id"] == "lead"
    assert record["contact"]["perturbed"] is False
    assert record["contact"]["side"] == "front"
    assert record["contact"]["mover"] == "ego_into_actor"
    assert (
        record["candidates"]["tried"] >= record["candidates"]["within_limits"] >= record["candidates"]["collision_free"]
    )
    # The same lead moved out of the lane by the search: no collision, nothing to classify.
    lead = scenario.actors[0]
    shifted = lead.centers + np.array([0.0, 5.0, 0.0])
    aside = ActorTrack(lead.actor_id, lead.actor_class, lead.size, lead.stamps_ns, shifted, lead.yaws)
    assert classify_collision(stack_plan, scenario, (aside,), DECISION) is None


def test_the_ego_limits_are_the_closed_loop_controllers() -> None:
    assert EgoLimits() == EgoLimits.from_controller(ControllerConfig())


def test_full_braking_builds_up_at_max_jerk_and_stops_in_the_closed_form_distance() -> None:
    # 15 m/s³ up to 8 m/s² takes 8/15 s: 4.954 m and 7.867 m/s left, then 7.867² / 16 = 3.868 m.
    profiles = longitudinal_profiles(10.0, TIMES, EgoLimits(), EvasionFamily())
    full = profiles.labels.index("brake at 8.0 m/s²")
    assert profiles.s[full, -1] == pytest.approx(8.822, abs=0.01)
    assert profiles.speed[full, -1] == 0.0
    assert profiles.within_limits[full]


def test_the_frenet_part_is_the_modular_planners_family() -> None:
    from advsim_ros.stacks.modular.planner import _quartic_speed, _quintic_lateral

    profiles = longitudinal_profiles(10.0, TIMES, EgoLimits(), EvasionFamily())
    row = profiles.labels.index("speed to 5.0 m/s in 3.0 s")
    _, planner_speed = _quartic_speed(10.0, 0.0, np.array([5.0]), np.array([3.0]), TIMES[1:], DT)
    assert profiles.speed[row, 1:] == pytest.approx(planner_speed[0], abs=1e-9)
    candidates = evasion_candidates(
        EgoStart.from_log(_human(10.0), DECISION), _human(10.0), TIMES, EgoLimits(), EvasionFamily()
    )
    index = next(
        i for i in range(candidates.xy.shape[0]) if candidates.label(i) == "offset +2.0 m in 2.5 s, keep 10.0 m/s"
    )
    planner_offset = _quintic_lateral(0.0, 0.0, np.array([2.0]), np.array([2.5]), TIMES)
    assert candidates.xy[index, :, 1] == pytest.approx(planner_offset[0], abs=1e-9)


def test_a_swerve_within_the_limits_depends_on_speed_and_a_standing_ego_cannot_move_sideways() -> None:
    def within(speed: float, label: str) -> bool:
        human = _human(speed)
        candidates = evasion_candidates(EgoStart.from_log(human, DECISION), human, TIMES, EgoLimits(), EvasionFamily())
        return bool(
            next(candidates.within_limits[i] for i in range(candidates.xy.shape[0]) if candidates.label(i) == label)
        )

    # 3 m in 1.5 s: curvature rate 53 m/s³ / v², the road wheels turn 2.8 x that: 1.5 rad/s at 10 m/s, 0.66 at 15.
    assert not within(10.0, "offset +3.0 m in 1.5 s, keep 10.0 m/s")
    assert within(15.0, "offset +3.0 m in 1.5 s, keep 15.0 m/s")
    assert within(10.0, "offset +3.0 m in 4.0 s, keep 10.0 m/s")
    human = _human(0.0)
    standing = evasion_candidates(EgoStart.from_log(human, DECISION), human, TIMES, EgoLimits(), EvasionFamily())
    assert standing.longitudinal_labels[0] == "keep 0.0 m/s"  # every brake and quartic is the same standstill
    assert len(standing.longitudinal_labels) == 1 + len(EvasionFamily().accel_shares)
    sideways = [i for i in range(standing.xy.shape[0]) if standing.label(i).endswith("keep 0.0 m/s") and i > 0]
    assert sideways
    assert not np.any(standing.within_limits[sideways])


def _kitti_track(base: ActorTrack, stamps: np.ndarray, xy: np.ndarray, yaws: np.ndarray) -> ActorTrack:
    centres = np.hstack([xy, np.full((xy.shape[0], 1), base.centers[0, 2])])
    return ActorTrack(base.actor_id, base.actor_class, base.size, stamps, centres, yaws)


def test_kitti_window_queries_are_classified_on_real_data(kitti_scenario: Scenario) -> None:
    scenario, frame = kitti_scenario, 20
    stamps, human_xy = scenario.frame_stamps_ns, scenario.ego.xy
    plan = Plan(
        stamps[frame + 1 : frame + 51], human_xy[frame + 1 : frame + 51], scenario.ego.yaws[frame + 1 : frame + 51]
    )
    assert classify_collision(plan, scenario, (), frame) is None  # the logged drive hits no labelled actor
    along = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(human_xy, axis=0), axis=1))])
    yaws = np.unwrap(scenario.ego.yaws)

    def on_path(s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        xy = np.stack([np.interp(s, along, human_xy[:, 0]), np.interp(s, along, human_xy[:, 1])], axis=-1)
        return xy, np.interp(s, along, yaws)

    car = scenario.actor("0")
    # A car parked on the human's path where the human is 3 s later: the ego (~3.9 m/s) could have braked.
    xy, yaw = on_path(np.full(stamps.shape[0], along[frame + 30]))
    parked = classify_collision(plan, scenario, (_kitti_track(car, stamps, xy, yaw),), frame)
    assert parked is not None
    assert parked.perturbed
    assert parked.avoidability.verdict is Verdict.AVOIDABLE
    assert parked.avoidability.in_lane_free > 0
    assert (parked.contact.side, parked.contact.mover) == (EgoSide.FRONT, Mover.EGO_INTO_ACTOR)
    # A car from 9 m behind along the human's path, 8 m/s faster than the ego: rear-ended, nowhere to go.
    elapsed = (stamps - stamps[frame]) / 1e9
    speed = EgoStart.from_log(scenario.ego, frame).speed
    xy, yaw = on_path(along[frame] - 9.0 + (speed + 8.0) * elapsed)
    rammed = classify_collision(plan, scenario, (_kitti_track(car, stamps, xy, yaw),), frame)
    assert rammed is not None
    assert rammed.avoidability.verdict is Verdict.UNAVOIDABLE
    assert (rammed.contact.side, rammed.contact.mover) == (EgoSide.REAR, Mover.ACTOR_INTO_EGO)
