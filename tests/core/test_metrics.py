"""Planning metrics on hand-made scenes whose answers are known in closed form."""

from __future__ import annotations

import numpy as np
import pytest

from advsim_ros.core.futures import ActorFutures, actor_futures_at
from advsim_ros.core.geometry import bev_iou
from advsim_ros.core.metrics import (
    MetricsConfig,
    Predictions,
    aggregate_metrics,
    average_precision,
    match_detections,
    query_metrics,
    trajectory_kinematics,
)
from advsim_ros.core.types import ActorClass, ActorTrack, EgoGeometry, EgoTrajectory, Plan, ScenarioError

DT = 0.1  # [s]
STEPS = 50  # 5 s plan at 10 Hz
START_NS = 1_000_000_000_000
EGO = EgoGeometry(np.array([4.5, 1.9, 1.7]), forward_offset=1.0)  # the SDV's box, 1 m ahead of its origin
CONFIG = MetricsConfig()


def _stamps(count: int = STEPS) -> np.ndarray:
    return START_NS + np.round(np.arange(count) * DT * 1e9).astype(np.int64)


def _plan(xy: np.ndarray, yaws: np.ndarray | None = None) -> Plan:
    headings = np.zeros(xy.shape[0]) if yaws is None else yaws
    return Plan(_stamps(xy.shape[0]), xy, headings)


def _human(xy: np.ndarray, yaws: np.ndarray | None = None) -> EgoTrajectory:
    headings = np.zeros(xy.shape[0]) if yaws is None else yaws
    poses = np.tile(np.eye(4), (xy.shape[0], 1, 1))
    poses[:, 0, 0], poses[:, 0, 1] = np.cos(headings), -np.sin(headings)
    poses[:, 1, 0], poses[:, 1, 1] = np.sin(headings), np.cos(headings)
    poses[:, :2, 3] = xy
    return EgoTrajectory(_stamps(xy.shape[0]), poses)


def _straight(speed: float, lateral: float = 0.0) -> np.ndarray:
    times = np.arange(STEPS) * DT
    return np.stack([speed * times, np.full(STEPS, lateral)], axis=-1)


def _parked(x: float, y: float, yaw: float = 0.0, size: tuple[float, float] = (4.0, 2.0)) -> ActorFutures:
    states = np.tile([x, y, yaw], (STEPS, 1))[None]
    return ActorFutures(states, np.array([size]))


def test_sdv_driving_into_a_parked_car_collides_at_the_first_stamp_its_box_touches() -> None:
    # Ego box front = origin + 1.0 + 2.25; the car's rear is at 30 - 2 = 28 m: contact from t = 2.475 s.
    plan = _plan(_straight(10.0))
    metrics = query_metrics(plan, _human(_straight(10.0)), _parked(30.0, 0.0), EGO, CONFIG)
    assert metrics.first_collision_time == pytest.approx(2.5)
    assert metrics.at("collision", 3.0) == 1.0
    assert metrics.at("collision", 5.0) == 1.0


def test_a_collision_after_3_s_counts_at_5_s_only() -> None:
    plan = _plan(_straight(10.0))
    metrics = query_metrics(plan, _human(_straight(10.0)), _parked(45.0, 0.0), EGO, CONFIG)  # contact from 3.975 s
    assert metrics.first_collision_time == pytest.approx(4.0)
    np.testing.assert_array_equal(metrics.collision, [0.0, 1.0])


def test_a_car_in_the_next_lane_never_collides() -> None:
    plan = _plan(_straight(10.0))
    metrics = query_metrics(plan, _human(_straight(10.0)), _parked(30.0, 3.5), EGO, CONFIG)
    assert np.isnan(metrics.first_collision_time)
    np.testing.assert_array_equal(metrics.collision, [0.0, 0.0])


def test_actors_outside_the_evaluation_range_at_the_decision_do_not_count() -> None:
    # An actor starting 45 m to the left (outside y in [-40, 40]) drives through the ego's path.
    times = np.arange(STEPS) * DT
    states = np.stack([np.full(STEPS, 20.0), 45.0 - 25.0 * times, np.full(STEPS, -np.pi / 2)], axis=-1)[None]
    actors = ActorFutures(states, np.array([[4.0, 2.0]]))
    plan, human = _plan(_straight(10.0)), _human(_straight(10.0))
    assert query_metrics(plan, human, actors, EGO, CONFIG).at("collision", 5.0) == 0.0
    wide = MetricsConfig(y_range=(-50.0, 50.0))
    assert query_metrics(plan, human, actors, EGO, wide).at("collision", 5.0) == 1.0


def test_l2_to_human_is_the_gap_between_a_slower_plan_and_the_human_at_each_horizon() -> None:
    metrics = query_metrics(_plan(_straight(8.0)), _human(_straight(10.0)), _parked(0.0, 30.0), EGO, CONFIG)
    # At 3 s: 30 - 24 = 6 m; at 5 s the 10 Hz plan ends at 4.9 s, so 5 s is not covered.
    assert metrics.at("l2_human", 3.0) == pytest.approx(6.0)
    assert np.isnan(metrics.at("l2_human", 5.0))
    longer = np.arange(51) * DT
    plan = Plan(_stamps(51), np.stack([8.0 * longer, np.zeros(51)], -1), np.zeros(51))
    human = _human(np.stack([10.0 * longer, np.full(51, 1.5)], -1))
    metrics = query_metrics(plan, human, ActorFutures(np.zeros((0, 51, 3)), np.zeros((0, 2))), EGO, CONFIG)
    assert metrics.at("l2_human", 5.0) == pytest.approx(np.hypot(10.0, 1.5))


def test_constant_jerk_is_recovered_exactly_from_a_cubic_position_profile() -> None:
    times = np.arange(STEPS) * DT
    xy = np.stack([1.5 * times**3 / 6.0, np.zeros(STEPS)], axis=-1)  # jerk 1.5 m/s^3
    kinematics = trajectory_kinematics(times, xy, np.zeros(STEPS))
    np.testing.assert_allclose(kinematics.jerk, 1.5, atol=1e-6)
    np.testing.assert_allclose(kinematics.longitudinal_acceleration, 1.5 * times[1:-1], atol=1e-9)
    np.testing.assert_allclose(kinematics.lateral_acceleration, 0.0, atol=1e-12)
    metrics = query_metrics(_plan(xy), _human(xy), _parked(0.0, 30.0), EGO, CONFIG)
    assert metrics.jerk == pytest.approx(1.5, abs=1e-6)


def test_lateral_acceleration_on_a_circle_is_speed_squared_over_radius() -> None:
    radius, speed = 20.0, 10.0  # [m], [m/s]: 5 m/s^2
    angle = speed / radius * np.arange(STEPS) * DT
    xy = radius * np.stack([np.sin(angle), 1.0 - np.cos(angle)], axis=-1)
    kinematics = trajectory_kinematics(np.arange(STEPS) * DT, xy, angle)
    np.testing.assert_allclose(kinematics.lateral_acceleration, 5.0, rtol=1e-3)
    np.testing.assert_allclose(kinematics.jerk, 0.0, atol=1e-9)
    metrics = query_metrics(_plan(xy, angle), _human(xy, angle), _parked(0.0, -30.0), EGO, CONFIG)
    assert metrics.lateral_acceleration == pytest.approx(5.0, rel=1e-3)


def test_detection_ap_counts_only_matches_at_iou_0_7_inside_the_range() -> None:
    truth = np.array([[10.0, 0.0, 0.0, 4.0, 2.0], [20.0, 5.0, 0.0, 4.0, 2.0], [30.0, -5.0, 0.0, 4.0, 2.0]])
    outside = np.array([[80.0, 0.0, 0.0, 4.0, 2.0]])  # beyond x = 72 m: ignored as truth and as detection
    detections = np.array(
        [
            [31.0, -5.0, 0.0, 4.0, 2.0],  # shifted 1 m along its length: IoU 3/5 = 0.6, a false positive
            [10.0, 0.0, 0.0, 4.0, 2.0],
            [20.0, 5.0, 0.0, 4.0, 2.0],
            [80.0, 0.0, 0.0, 4.0, 2.0],
        ],
    )
    scores = np.array([0.95, 0.9, 0.8, 0.99])
    tally = match_detections(detections, scores, np.vstack([truth, outside]), np.zeros(2), 0.0, CONFIG)
    assert tally.num_ground_truth == 3
    np.testing.assert_array_equal(tally.true_positive, [False, True, True])
    # Precision 0, 1/2, 2/3 at recall 0, 1/3, 2/3: the envelope gives AP = 2/3 * 2/3.
    assert average_precision([tally]) == pytest.approx(4.0 / 9.0)
    assert average_precision([match_detections(truth, np.ones(3), truth, np.zeros(2), 0.0, CONFIG)]) == 1.0


def test_prediction_l2_compares_each_matched_prediction_with_its_actor_at_3_and_5_s() -> None:
    count = 51
    times = np.arange(count) * DT
    states = np.stack([5.0 * times, np.full(count, 10.0), np.zeros(count)], axis=-1)[None]  # 5 m/s
    actors = ActorFutures(states, np.array([[4.0, 2.0]]))
    plan = Plan(_stamps(count), np.stack([10.0 * times, np.zeros(count)], -1), np.zeros(count))
    predicted = np.stack(
        [
            np.stack([4.5 * times, np.full(count, 10.0)], -1),  # 10 % too slow: 1.5 m off at 3 s, 2.5 m at 5 s
            np.stack([4.5 * times, np.full(count, -30.0)], -1),  # a false track far from every actor
        ],
    )
    predictions = Predictions(_stamps(count), predicted)
    human = _human(np.stack([10.0 * times, np.zeros(count)], -1))
    metrics = query_metrics(plan, human, actors, EGO, CONFIG, predictions=predictions)
    np.testing.assert_allclose(metrics.prediction_l2, [1.5, 2.5])


def test_aggregation_averages_rates_and_pools_detections() -> None:
    plan, human = _plan(_straight(10.0)), _human(_straight(10.0))
    truth = np.array([[10.0, 0.0, 0.0, 4.0, 2.0]])
    hit = match_detections(truth, [0.9], truth, np.zeros(2), 0.0, CONFIG)
    miss = match_detections(np.zeros((0, 5)), np.zeros(0), truth, np.zeros(2), 0.0, CONFIG)
    colliding = query_metrics(plan, human, _parked(30.0, 0.0), EGO, CONFIG, detection=hit)
    late = query_metrics(plan, human, _parked(45.0, 0.0), EGO, CONFIG, detection=miss)
    clear = query_metrics(plan, human, _parked(30.0, 3.5), EGO, CONFIG)
    summary = aggregate_metrics([colliding, late, clear])
    assert summary.count == 3
    np.testing.assert_allclose(summary.collision_rate, [1.0 / 3.0, 2.0 / 3.0])
    assert summary.detection_ap == pytest.approx(0.5)  # one of two boxes found, at precision 1
    assert np.all(np.isnan(summary.prediction_l2))
    with pytest.raises(ScenarioError, match="no query metrics"):
        aggregate_metrics([])


def test_actor_futures_must_be_sampled_at_the_plan_stamps() -> None:
    actors = ActorFutures(np.zeros((1, STEPS - 1, 3)), np.array([[4.0, 2.0]]))
    with pytest.raises(ScenarioError, match="sample the futures at the plan's stamps"):
        query_metrics(_plan(_straight(10.0)), _human(_straight(10.0)), actors, EGO, CONFIG)


def test_metrics_config_rejects_an_empty_range_naming_the_key() -> None:
    with pytest.raises(ScenarioError, match=r"MetricsConfig.x_range"):
        MetricsConfig(x_range=(10.0, -10.0))


def test_actor_tracks_are_resampled_at_the_plan_stamps() -> None:
    track_stamps = START_NS + np.arange(0, 6) * 1_000_000_000  # 1 Hz labels
    track = ActorTrack(
        "car",
        ActorClass.VEHICLE,
        np.array([4.0, 2.0, 1.5]),
        track_stamps,
        np.stack([2.0 * np.arange(6.0), np.zeros(6), np.zeros(6)], axis=-1),  # 2 m/s along x
        np.linspace(0.0, 0.5, 6),
    )
    futures = actor_futures_at([track], _stamps())
    assert futures.states.shape == (1, STEPS, 3)
    np.testing.assert_allclose(futures.states[0, :, 0], 2.0 * np.arange(STEPS) * DT, atol=1e-9)
    np.testing.assert_allclose(futures.states[0, :, 2], 0.1 * np.arange(STEPS) * DT, atol=1e-9)
    np.testing.assert_array_equal(futures.sizes, [[4.0, 2.0]])


DECISION_FRAME = 9  # the last of a window's 10 history frames: the plan's first stamp


def _seen_from_frame(first_frame: int, x: float, y: float = 0.0, speed: float = 0.0) -> ActorTrack:
    """A car labelled from window frame `first_frame` to frame 59, at (x, y) there and moving along x at `speed`."""
    frames = np.arange(first_frame, 60)
    times = (frames - DECISION_FRAME) * DT
    centers = np.stack([x + speed * (times - times[0]), np.full(frames.size, y), np.zeros(frames.size)], axis=-1)
    stamps = START_NS + np.round(times * 1e9).astype(np.int64)
    return ActorTrack("late", ActorClass.VEHICLE, np.array([4.0, 2.0, 1.5]), stamps, centers, np.zeros(frames.size))


def test_an_actor_observed_only_from_frame_49_never_collides_before_it_appears() -> None:
    # The car appears 4.0 s after the decision at x = 20 m; the ego at 10 m/s overlaps that spot at 1.5-2.3 s.
    late = actor_futures_at([_seen_from_frame(49, 20.0)], _stamps())
    passing = query_metrics(_plan(_straight(10.0)), _human(_straight(10.0)), late, EGO, CONFIG)
    assert np.isnan(passing.first_collision_time)
    np.testing.assert_array_equal(passing.collision, [0.0, 0.0])
    # Held at its first state (the old rule) it stood there from the decision on and was hit at 1.5 s.
    held = ActorFutures(np.tile([20.0, 0.0, 0.0], (1, STEPS, 1)), late.sizes)
    held_metrics = query_metrics(_plan(_straight(10.0)), _human(_straight(10.0)), held, EGO, CONFIG)
    assert held_metrics.first_collision_time == pytest.approx(1.5)


def test_an_actor_collides_once_it_is_there() -> None:
    # The ego stands with its box at x = 14.75-19.25 m, the car's is 18-22 m: contact from its first label at 4.0 s.
    standing = _plan(np.tile([16.0, 0.0], (STEPS, 1)))
    late = actor_futures_at([_seen_from_frame(49, 20.0)], _stamps())
    metrics = query_metrics(standing, _human(standing.xy), late, EGO, CONFIG)
    assert metrics.first_collision_time == pytest.approx(4.0)
    np.testing.assert_array_equal(metrics.collision, [0.0, 1.0])


def test_an_actor_exists_half_a_frame_beyond_its_labels_at_constant_velocity() -> None:
    track = _seen_from_frame(49, 20.0, speed=10.0)  # labelled 4.0-5.0 s after the decision, 10 m/s along x
    first, last = int(track.stamps_ns[0]), int(track.stamps_ns[-1])
    offsets = np.array([-60, -50, -10, 0, 10, 50, 60]) * 1_000_000  # [ns] around the first and the last label
    futures = actor_futures_at([track], np.concatenate([first + offsets[:4], last + offsets[4:]]))
    np.testing.assert_array_equal(futures.present[0], [False, True, True, True, True, True, False])
    np.testing.assert_allclose(futures.states[0, 1:6, 0], [19.5, 19.9, 20.0, 30.1, 30.5], atol=1e-9)
    assert np.all(np.isnan(futures.states[0, [0, 6]]))  # absent: no state to read, held or otherwise
    strict = actor_futures_at([track], np.array([first - 10_000_000, first]), extrapolation=0.0)
    np.testing.assert_array_equal(strict.present[0], [False, True])
    with pytest.raises(ScenarioError, match=r"MetricsConfig.actor_extrapolation: must be in \[0, 0.5\] s"):
        MetricsConfig(actor_extrapolation=1.0)


def test_an_actor_that_appears_later_is_no_ground_truth_for_predictions_before() -> None:
    # A prediction starting at the decision where the car will only appear 4 s later matches nothing.
    late = actor_futures_at([_seen_from_frame(49, 20.0)], _stamps(51))
    plan = Plan(_stamps(51), np.zeros((51, 2)), np.zeros(51))
    predictions = Predictions(_stamps(51), np.tile([20.0, 0.0], (1, 51, 1)))
    metrics = query_metrics(plan, _human(np.zeros((51, 2))), late, EGO, CONFIG, predictions=predictions)
    assert np.all(np.isnan(metrics.prediction_l2))


def test_bev_iou_of_shifted_crossed_and_disjoint_boxes() -> None:
    box = np.array([0.0, 0.0, 0.0, 4.0, 2.0])
    others = np.array(
        [
            [1.0, 0.0, 0.0, 4.0, 2.0],  # shifted 1 m along: 6 / 10
            [0.0, 0.0, np.pi / 2, 4.0, 2.0],  # crossed: 4 / 12
            [0.0, 0.0, np.pi, 4.0, 2.0],  # the same box turned around: 1
            [10.0, 0.0, 0.0, 4.0, 2.0],  # disjoint: 0
        ],
    )
    np.testing.assert_allclose(bev_iou(box, others), [0.6, 1.0 / 3.0, 1.0, 0.0], atol=1e-12)
    assert bev_iou(others[:, None, :], others[None, :, :]).shape == (4, 4)
