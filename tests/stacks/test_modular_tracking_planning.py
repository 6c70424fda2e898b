"""Tracker, CV/CTRV prediction and the Frenet sampling planner on small scenes with known answers."""

from __future__ import annotations

import numpy as np

from advsim_ros.core.geometry import boxes_overlap
from advsim_ros.core.types import ActorClass, RoadMap
from advsim_ros.stacks.modular.config import PlannerConfig, PredictionConfig, TrackerConfig
from advsim_ros.stacks.modular.detector import CLASS_ORDER, Detections
from advsim_ros.stacks.modular.occupancy import ObstacleGrid
from advsim_ros.stacks.modular.planner import EgoState, plan
from advsim_ros.stacks.modular.prediction import predict_tracks
from advsim_ros.stacks.modular.tracker import MultiObjectTracker, TrackSet

VEHICLE = CLASS_ORDER.index(ActorClass.VEHICLE)
STEP_NS = 100_000_000
PLANNER = PlannerConfig()
FUTURE_NS = STEP_NS * np.arange(1, 51, dtype=np.int64)


def _detections(boxes: np.ndarray) -> Detections:
    count = boxes.shape[0]
    return Detections(
        boxes=boxes,
        z=np.full(count, 0.8),
        heights=np.full(count, 1.5),
        classes=np.full(count, VEHICLE, dtype=np.int64),
        confidences=np.full(count, 0.9),
        num_points=np.full(count, 200, dtype=np.int64),
    )


def _track(steps: int, speed: float, rng: np.random.Generator, jitter: float) -> tuple[MultiObjectTracker, TrackSet]:
    tracker = MultiObjectTracker(TrackerConfig(), PredictionConfig())
    tracks = None
    for step in range(steps):
        x = 10.0 + speed * 0.1 * step + rng.normal(0.0, jitter)
        tracks = tracker.update(
            step * STEP_NS, _detections(np.array([[x, 2.0 + rng.normal(0.0, jitter), 0.0, 4.5, 1.8]]))
        )
    assert tracks is not None
    return tracker, tracks


def test_a_car_driving_at_8_m_s_is_tracked_as_one_moving_track_with_its_speed() -> None:
    _, tracks = _track(30, 8.0, np.random.default_rng(0), jitter=0.1)
    assert tracks.count == 1
    assert bool(tracks.moving[0])
    np.testing.assert_allclose(tracks.state[0, 2:], [8.0, 0.0], atol=0.6)


def test_a_parked_car_whose_box_jitters_stays_a_standing_obstacle() -> None:
    _, tracks = _track(30, 0.0, np.random.default_rng(1), jitter=0.3)  # partial views move box centres by decimetres
    assert tracks.count == 1
    assert not bool(tracks.moving[0])
    xy, _, speeds = predict_tracks(tracks, 29 * STEP_NS, 29 * STEP_NS + FUTURE_NS, PredictionConfig(), TrackerConfig())
    np.testing.assert_allclose(xy[0], np.broadcast_to(tracks.state[0, :2], (50, 2)))
    assert np.all(speeds == 0.0)


def test_tracks_end_after_missed_sweeps_and_a_jump_in_time_starts_afresh() -> None:
    tracker, tracks = _track(5, 5.0, np.random.default_rng(2), jitter=0.0)
    first_id = int(tracks.ids[0])
    for step in range(5, 5 + TrackerConfig().max_misses + 1):
        tracks = tracker.update(step * STEP_NS, Detections.empty())
    assert tracks.count == 0
    tracks = tracker.update(100 * STEP_NS, _detections(np.array([[0.0, 0.0, 0.0, 4.5, 1.8]])))
    tracks = tracker.update(50 * STEP_NS, _detections(np.array([[0.0, 0.0, 0.0, 4.5, 1.8]])))  # time went back
    assert tracks.count == 1
    assert int(tracks.hits[0]) == 1
    assert int(tracks.ids[0]) > first_id


def test_ctrv_prediction_follows_the_circle_of_radius_speed_over_turn_rate() -> None:
    tracks = TrackSet(
        ids=np.array([1]),
        state=np.array([[0.0, 0.0, 5.0, 0.0]]),
        yaw=np.array([0.0]),
        yaw_rate=np.array([0.25]),
        size=np.array([[4.5, 1.8, 1.5]]),
        z=np.array([0.8]),
        classes=np.array([VEHICLE]),
        confidence=np.array([0.9]),
        hits=np.array([10]),
        misses=np.array([0]),
        detected_box=np.zeros((1, 5)),
        moving=np.array([True]),
    )
    xy, yaws, _ = predict_tracks(tracks, 0, FUTURE_NS, PredictionConfig(model="ctrv"), TrackerConfig())
    radius = 5.0 / 0.25
    np.testing.assert_allclose(np.linalg.norm(xy[0] - [0.0, radius], axis=1), radius, atol=1e-9)
    np.testing.assert_allclose(yaws[0, -1], 0.25 * 5.0)
    straight, _, _ = predict_tracks(tracks, 0, FUTURE_NS, PredictionConfig(model="cv"), TrackerConfig())
    np.testing.assert_allclose(straight[0, -1], [25.0, 0.0])


def _ego(speed: float = 8.0) -> EgoState:
    return EgoState(np.zeros(2), 0.0, speed, 0.0, 0.0, 4.7, 1.9, 1.0)


def _ego_boxes(choice_xy: np.ndarray, choice_yaw: np.ndarray) -> np.ndarray:
    centre = choice_xy + 1.0 * np.stack([np.cos(choice_yaw), np.sin(choice_yaw)], axis=-1)
    return np.column_stack([centre, choice_yaw, np.full(len(choice_yaw), 4.7), np.full(len(choice_yaw), 1.9)])


def test_on_an_empty_road_the_plan_keeps_speed_and_lane() -> None:
    choice = plan(_ego(), np.zeros((0, 50, 5)), PLANNER)
    np.testing.assert_allclose(choice.xy[:, 1], 0.0, atol=1e-9)
    np.testing.assert_allclose(choice.xy[-1, 0], 40.0, atol=0.5)  # 5 s at 8 m/s


def test_the_plan_never_runs_into_a_car_stopped_in_the_lane() -> None:
    stopped = np.broadcast_to(np.array([20.0, 0.0, 0.0, 4.5, 1.8]), (1, 50, 5)).copy()
    grid = ObstacleGrid(np.zeros((400, 720), dtype=bool), (-72.0, -40.0), 0.2, np.eye(4))
    choice = plan(_ego(), stopped, PLANNER, static=grid)
    assert not choice.collides
    assert not np.any(boxes_overlap(_ego_boxes(choice.xy, choice.yaw), stopped[0]))


def test_the_plan_keeps_clear_of_a_wall_of_occupied_cells_across_the_lane() -> None:
    occupied = np.zeros((400, 720), dtype=bool)
    rows = ((np.arange(-4.0, 4.0, 0.2) + 40.0) / 0.2).astype(int)
    column = int((25.0 + 72.0) / 0.2)
    occupied[rows, column] = True  # a wall 25 m ahead across the lane, 8 m wide
    grid = ObstacleGrid(occupied, (-72.0, -40.0), 0.2, np.eye(4))
    choice = plan(_ego(), np.zeros((0, 50, 5)), PLANNER, static=grid)
    assert not choice.collides
    # Every cell of the wall (as a 0.2 m square) stays outside every box of the plan.
    cells = np.column_stack([-72.0 + (column + 0.5) * 0.2 + 0 * rows, -40.0 + (rows + 0.5) * 0.2, 0 * rows,
                             np.full(rows.shape, 0.2), np.full(rows.shape, 0.2)])  # fmt: skip
    assert not np.any(boxes_overlap(_ego_boxes(choice.xy, choice.yaw)[:, None], cells[None]))


def test_with_a_map_the_plan_follows_the_lane_it_is_in() -> None:
    lanes = (np.array([[-50.0, 0.0], [200.0, 0.0]]), np.array([[-50.0, 3.5], [200.0, 3.5]]))
    road = RoadMap(lane_centerlines=lanes)
    ego = EgoState(np.array([0.0, 0.6]), 0.0, 8.0, 0.0, 0.0, 4.7, 1.9, 1.0)  # 0.6 m left of its lane's centre
    choice = plan(ego, np.zeros((0, 50, 5)), PLANNER, road_map=road)
    assert choice.reference.source == "lane"
    assert abs(choice.xy[-1, 1]) < 0.1  # back on the centreline by the end
