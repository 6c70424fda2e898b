"""Synthetic scene families: each stages its interaction, is collision-free as logged, and draws fast."""

from __future__ import annotations

import time

import numpy as np
import pytest

from advsim_ros.core.drivable import drivable_area_from_map
from advsim_ros.core.geometry import box_distance
from advsim_ros.core.lidar.boxes import inside, removal_region, to_box_frame, yaw_pose
from advsim_ros.core.lidar.sensor import xyz_of
from advsim_ros.core.types import ActorClass, EgoGeometry, ScenarioError
from advsim_ros.io.synthetic import SyntheticConfig, _road_map, generate_synthetic_log
from advsim_ros.io.synthetic_families import (
    EGO_LANE_Y,
    FAMILY_NAMES,
    LANE_WIDTH,
    Motion,
    SceneLayout,
    along,
    scene_layout,
)

TIMES = np.arange(80) * 0.1  # the default 8-s log at 10 Hz [s]
SEEDS = range(40)
EGO = EgoGeometry()


def _layout(family: str, seed: int) -> SceneLayout:
    return scene_layout(family, np.random.default_rng(seed), TIMES, 8.0, 5)


def _boxes(motion: Motion) -> np.ndarray:
    count = motion.xy.shape[0]
    return np.column_stack([motion.xy, motion.yaw, np.full(count, motion.size[0]), np.full(count, motion.size[1])])


def _actor(layout: SceneLayout, actor_id: str) -> Motion:
    return next(motion for motion in layout.actors if motion.actor_id == actor_id)


def _gaps(layout: SceneLayout, actor_id: str) -> np.ndarray:
    """Gap between the logged ego box and the actor's box at every frame [m]."""
    return box_distance(EGO.boxes(layout.ego_xy, layout.ego_yaw), _boxes(_actor(layout, actor_id)))


@pytest.mark.parametrize("family", FAMILY_NAMES)
def test_every_family_is_collision_free_as_logged_and_keeps_vehicles_on_the_road(family: str) -> None:
    for seed in SEEDS:
        layout = _layout(family, seed)
        road = _road_map(layout)
        area = drivable_area_from_map(road, (-80.0, -80.0, 200.0, 80.0), 0.5)
        for motion in layout.actors:
            assert _gaps(layout, motion.actor_id).min() > 0.5, (family, seed, motion.actor_id)
            if motion.actor_class is ActorClass.VEHICLE and not motion.actor_id.startswith(("parked", "van")):
                assert area.contains(motion.xy[:, 0], motion.xy[:, 1]).all(), (family, seed, motion.actor_id)
        assert area.contains(layout.ego_xy[:, 0], layout.ego_xy[:, 1]).all()
        assert set(layout.interacting) <= {motion.actor_id for motion in layout.actors}


def test_lead_brake_the_lead_brakes_hard_in_the_ego_lane_and_the_ego_stops_behind_it() -> None:
    for seed in SEEDS:
        layout = _layout("lead_brake", seed)
        lead = _actor(layout, "lead")
        assert np.allclose(lead.xy[:, 1], EGO_LANE_Y)
        speed = np.diff(lead.xy[:, 0]) / 0.1
        assert speed[0] == pytest.approx(8.0)
        assert speed[-1] < 0.5
        assert np.diff(speed).min() / 0.1 < -2.9  # braking of at least 3 m/s^2
        ego_speed = np.diff(layout.ego_xy[:, 0]) / 0.1
        assert ego_speed[-1] < ego_speed[0] - 4.0
        assert np.all(lead.xy[:, 0] > layout.ego_xy[:, 0])
        assert 1.5 < _gaps(layout, "lead").min() < 4.0  # close behind, never touching


def test_cut_in_the_cutter_moves_from_the_next_lane_into_the_ego_lane_ahead_of_the_ego() -> None:
    for seed in SEEDS:
        layout = _layout("cut_in", seed)
        cutter = _actor(layout, "cutter")
        assert cutter.xy[0, 1] == pytest.approx(-1.5 * LANE_WIDTH)
        assert cutter.xy[-1, 1] == pytest.approx(EGO_LANE_Y)
        changing = np.flatnonzero(np.abs(np.diff(cutter.xy[:, 1])) > 1e-6)
        assert TIMES[changing[0]] > 1.7
        assert TIMES[changing[-1]] < 7.0
        assert np.all(cutter.xy[:, 0] > layout.ego_xy[:, 0] + 5.0)
        assert np.abs(cutter.yaw).max() > 0.1  # heading follows the lane change


def test_oncoming_cars_pass_the_ego_close_in_the_opposite_lane() -> None:
    for seed in SEEDS:
        layout = _layout("oncoming", seed)
        passing = [a for a in layout.interacting if np.any(_actor(layout, a).xy[:70, 0] < layout.ego_xy[:70, 0])]
        assert passing, seed  # at least one passes the ego within the first 7 s
        for actor_id in layout.interacting:
            assert _gaps(layout, actor_id).min() < 2.0


def _first_time_within(layout: SceneLayout, motion: Motion, point: np.ndarray, radius: float) -> float:
    near = np.linalg.norm(motion.xy - point, axis=1) < radius
    return float(TIMES[np.flatnonzero(near)[0]])


def test_crossing_vehicles_cross_the_ego_path_just_before_and_just_after_it() -> None:
    for seed in SEEDS:
        layout = _layout("crossing", seed)
        assert layout.crossing_x is not None
        for actor_id, before in (("crossing_before", True), ("crossing_after", False)):
            actor = _actor(layout, actor_id)
            point = np.array([actor.xy[0, 0], EGO_LANE_Y])  # where its path crosses the ego's
            actor_at = _first_time_within(layout, actor, point, 0.5)
            ego_at = _first_time_within(layout, Motion("ego", ActorClass.VEHICLE, (1, 1, 1), 0, layout.ego_xy,
                                                       layout.ego_yaw), point, 0.5)  # fmt: skip
            assert actor_at < 7.0
            assert ego_at < 7.0
            assert (actor_at < ego_at) == before
            assert 0.5 < abs(actor_at - ego_at) < 3.0


def test_left_turn_the_ego_turns_left_and_the_oncoming_car_passes_its_path_after_it() -> None:
    for seed in SEEDS:
        layout = _layout("left_turn", seed)
        turned = layout.ego_yaw[-1] - layout.ego_yaw[0]
        assert turned == pytest.approx(0.5 * np.pi, abs=0.05)
        assert layout.ego_xy[-1, 1] > 5.0  # on the cross street
        (turn_lane,) = layout.turn_lanes  # the map has the lane the ego turns along
        assert any(
            lane.shape == turn_lane.shape and np.allclose(lane, turn_lane)
            for lane in _road_map(layout).lane_centerlines
        )
        turning = layout.ego_xy[layout.ego_xy[:, 0] >= turn_lane[0, 0]]
        length = np.linalg.norm(np.diff(turn_lane, axis=0), axis=1).sum()
        dense, _ = along(turn_lane, np.arange(0.0, length, 0.25))
        assert np.min(np.linalg.norm(turning[:, None] - dense[None], axis=2), axis=1).max() < 0.2
        oncoming = _actor(layout, "oncoming")
        reached = int(np.flatnonzero(layout.ego_xy[:, 1] >= oncoming.xy[0, 1])[0])  # the ego's path meets its lane
        ego_at = float(TIMES[reached])
        oncoming_at = _first_time_within(layout, oncoming, layout.ego_xy[reached], 1.0)
        assert ego_at < oncoming_at < 7.0


def test_occluded_pedestrian_the_van_hides_the_pedestrian_until_it_runs_out() -> None:
    log = generate_synthetic_log(np.random.default_rng(0), SyntheticConfig(family="occluded_pedestrian"))
    scenario = log.scenario
    pedestrian = next(actor for actor in scenario.actors if actor.actor_id == "pedestrian")
    hits = []
    for index, sweep in enumerate(scenario.sweeps):
        pose = np.linalg.inv(sweep.sensor_pose) @ yaw_pose(pedestrian.centers[index], float(pedestrian.yaws[index]))
        local = to_box_frame(xyz_of(sweep.points), pose)
        hits.append(int(inside(local, removal_region(pedestrian.size, 0.05)).sum()))
    walking = np.flatnonzero(np.abs(np.diff(pedestrian.centers[:, 1])) > 1e-6)
    assert walking.size
    assert sum(hits[: walking[0] + 1]) == 0  # waiting behind the van: not one point
    assert max(hits[walking[0] :]) > 20  # out on the road: seen


def test_unknown_family_gets_one_line_naming_the_choices() -> None:
    with pytest.raises(ScenarioError, match="synthetic family: expected one of street, lead_brake"):
        SyntheticConfig(family="roundabout")


def test_a_campaign_sized_draw_of_layouts_is_fast_and_every_seed_differs() -> None:
    started = time.perf_counter()
    layouts = [_layout(family, seed) for family in FAMILY_NAMES for seed in range(15)]  # 105 scenes
    assert time.perf_counter() - started < 10.0  # rendering the LiDAR is the slow part: bench/bench_synthetic.py
    for family in FAMILY_NAMES:
        firsts = {tuple(np.round(layout.actors[0].xy[0], 6)) for layout in layouts if layout.family == family}
        assert len(firsts) == 15
