"""Feasible sets, actor selection and projection, checked by an independent checker.

The checker rebuilds every box as a shapely polygon and every bound from finite differences of
the returned trajectories, so it shares no code with the pruning it checks.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
import shapely

from advsim_ros import graph
from advsim_ros.core.drivable import (
    DrivableConfig,
    drivable_area_for,
    drivable_area_from_map,
    estimate_drivable_area,
    scenario_extent,
)
from advsim_ros.core.dynamics import interpolate_knots, knot_weights, rollout
from advsim_ros.core.feasibility import (
    FeasibleSet,
    InfeasibleError,
    PerturbedTrajectory,
    PerturberConfig,
    TooFewActorsError,
    Window,
    build_feasible_set,
    fit_reference,
    load_perturber_config,
    perturbation_names,
    perturbation_to_trajectory,
    project,
    rank_actors,
    select_actors,
)
from advsim_ros.core.params import ParamsError
from advsim_ros.core.types import ActorTrack, DrivableArea, EgoGeometry, EgoTrajectory, RoadMap, Scenario, ScenarioError

REPO = Path(__file__).resolve().parents[2]

DT = 0.1
FRAMES = 80
STAMPS = 1_000_000_000 + 100_000_000 * np.arange(FRAMES, dtype=np.int64)
ROAD = np.array([[-60.0, -7.0], [260.0, -7.0], [260.0, 7.0], [-60.0, 7.0]])  # a straight two-lane road [m]
TEST_CONFIG = PerturberConfig(num_candidates=20_000)


# --- a small synthetic street -------------------------------------------------------------------


def _model_track(initial: list[float], accel_knots: list[float], rate_knots: list[float]) -> np.ndarray:
    """(FRAMES, 3) x, y, yaw of a bicycle-model trajectory (so it is feasible by construction)."""
    weights = knot_weights(FRAMES, len(accel_knots))
    accel = interpolate_knots(np.array([accel_knots]), weights)
    rate = interpolate_knots(np.array([rate_knots]), weights)
    traj = rollout(np.array([initial]), accel, rate, DT)
    return np.column_stack([traj.x[0], traj.y[0], traj.yaw[0]])


def _track(actor_id: str, actor_class: str, size: tuple[float, float, float], xyyaw: np.ndarray) -> ActorTrack:
    count = xyyaw.shape[0]
    centers = np.column_stack([xyyaw[:, :2], np.full(count, size[2] / 2)])
    return ActorTrack(actor_id, actor_class, np.array(size), STAMPS[:count], centers, xyyaw[:, 2])


def street_scenario(with_map: bool = True) -> Scenario:
    """Ego in the right lane at 8 m/s, a lead car, an oncoming car, a parked car, a pedestrian on the kerb."""
    ego_path = _model_track([0.0, -1.75, 0.0, 8.0, 0.0], [0.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0])
    poses = np.tile(np.eye(4), (FRAMES, 1, 1))
    poses[:, 0, 3], poses[:, 1, 3] = ego_path[:, 0] - 1.0, ego_path[:, 1]  # ego origin 1 m behind the box centre
    lead = _model_track([22.0, -1.75, 0.0, 7.0, 0.0], [0.5, -0.5, 0.3, 0.0], [0.0, 0.0, 0.0, 0.0])
    oncoming = _model_track([120.0, 1.75, math.pi, 9.0, 0.0], [0.0, 0.5, 0.0, -0.5], [0.0, 0.0, 0.0, 0.0])
    parked = np.tile([45.0, 5.0, 0.0], (FRAMES, 1))
    walker = np.column_stack([np.linspace(30.0, 34.0, FRAMES), np.full(FRAMES, 8.5), np.zeros(FRAMES)])
    actors = (
        _track("lead", "vehicle", (4.5, 1.9, 1.6), lead),
        _track("oncoming", "vehicle", (4.8, 1.9, 1.7), oncoming),
        _track("parked", "vehicle", (4.2, 1.8, 1.5), parked[:50]),
        _track("walker", "pedestrian", (0.8, 0.8, 1.8), walker),
    )
    road_map = RoadMap(drivable_areas=(ROAD,)) if with_map else None
    return Scenario(
        scenario_id="street",
        frame_stamps_ns=STAMPS,
        ego=EgoTrajectory(STAMPS, poses),
        actors=actors,
        road_map=road_map,
        ego_geometry=EgoGeometry(np.array([4.5, 1.9, 1.6])),
    )


@pytest.fixture(scope="module")
def street() -> Scenario:
    return street_scenario()


@pytest.fixture(scope="module")
def lead_set(street: Scenario) -> FeasibleSet:
    return build_feasible_set(street, Window(0, 60), "lead", TEST_CONFIG, np.random.default_rng(7))


# --- the independent checker --------------------------------------------------------------------


def _polygon(x: float, y: float, yaw: float, length: float, width: float) -> shapely.Polygon:
    outline = shapely.box(-length / 2, -width / 2, length / 2, width / 2)
    return shapely.affinity.translate(shapely.affinity.rotate(outline, yaw, origin=(0, 0), use_radians=True), x, y)


def _labelled_obstacles(
    scenario: Scenario, window: Window, actor_id: str, ego_offset: float
) -> list[list[shapely.Polygon]]:
    """Per window step, polygons of the SDV and of every other actor labelled at that frame."""
    steps: list[list[shapely.Polygon]] = []
    for step in range(window.num_steps):
        frame = window.start_frame + step
        stamp = scenario.frame_stamps_ns[frame]
        pose = scenario.ego.poses[frame]
        yaw = math.atan2(pose[1, 0], pose[0, 0])
        x, y = pose[0, 3] + ego_offset * math.cos(yaw), pose[1, 3] + ego_offset * math.sin(yaw)
        polygons = [_polygon(x, y, yaw, scenario.ego_geometry.length, scenario.ego_geometry.width)]
        for actor in scenario.actors:
            if actor.actor_id == actor_id:
                continue
            hits = np.nonzero(actor.stamps_ns == stamp)[0]
            if hits.size:
                i = int(hits[0])
                polygons.append(_polygon(*actor.centers[i, :2], actor.yaws[i], actor.length, actor.width))
        steps.append(polygons)
    return steps


def assert_physically_plausible(trajectory: PerturbedTrajectory, config: PerturberConfig) -> None:
    """Every bound from finite differences, and positions that follow the bicycle model."""
    dt = float(np.mean(np.diff(trajectory.stamps_ns))) * 1e-9  # the model steps at the mean frame spacing
    speed, curvature = trajectory.speed, trajectory.curvature
    assert np.all(speed >= 0.0)
    assert np.max(speed) <= config.max_speed
    assert np.max(np.abs(curvature)) <= config.max_curvature
    assert np.max(np.abs(np.diff(curvature) / dt)) <= config.max_curvature_rate + 1e-9
    assert np.max(np.abs(np.diff(speed) / dt)) <= config.max_accel + 1e-9
    assert np.max(np.abs(speed**2 * curvature)) <= config.max_lateral_accel + 1e-9
    steps = np.hypot(np.diff(trajectory.x), np.diff(trajectory.y))
    np.testing.assert_allclose(steps, speed[:-1] * dt, atol=1e-6)
    np.testing.assert_allclose(np.diff(trajectory.yaw), speed[:-1] * curvature[:-1] * dt, atol=1e-9)


def assert_collides_with_nothing(trajectory: PerturbedTrajectory, obstacles: list[list[shapely.Polygon]]) -> None:
    for step, polygons in enumerate(obstacles):
        mine = _polygon(
            trajectory.x[step], trajectory.y[step], trajectory.yaw[step], trajectory.size[0], trajectory.size[1]
        )
        for other in polygons:
            assert not mine.intersects(other), f"step {step}: {trajectory.actor_id} overlaps an obstacle"


def assert_on_road(trajectory: PerturbedTrajectory, road: shapely.Polygon) -> None:
    assert all(road.contains(shapely.Point(x, y)) for x, y in zip(trajectory.x, trajectory.y, strict=True))


# --- configuration ------------------------------------------------------------------------------


def test_params_file_holds_the_defaults_and_the_perturbation_dimension_is_twelve() -> None:
    config = load_perturber_config(REPO / "params" / "perturber.yaml", node=graph.PERTURBER.name)
    assert config == PerturberConfig()
    assert config.perturbation_dim == 12
    assert perturbation_names(4)[:4] == ("dx0", "dy0", "dheading0", "dv0")
    assert len(perturbation_names(4)) == 12


def test_unknown_or_invalid_parameters_are_rejected_by_name(tmp_path: Path) -> None:
    with pytest.raises(ParamsError, match="max_sped"):
        PerturberConfig.from_mapping({"max_sped": 3.0})
    with pytest.raises(ScenarioError, match="max_speed"):
        PerturberConfig(max_speed=-1.0)
    with pytest.raises(ScenarioError, match="perturbable_classes"):
        PerturberConfig(perturbable_classes=("truck",))
    path = tmp_path / "bad.yaml"
    path.write_text("/perturber:\n  ros__parameters:\n    num_knots: 1\n", encoding="utf-8")
    with pytest.raises(ParamsError, match="num_knots"):
        load_perturber_config(path, node=graph.PERTURBER.name)


def test_a_window_beyond_the_log_is_rejected(street: Scenario) -> None:
    with pytest.raises(ScenarioError, match="leave scenario"):
        Window(30, 60).stamps(street, 0.1)


# --- the feasible set ---------------------------------------------------------------------------


def test_pruning_counts_shrink_step_by_step_and_keep_enough_candidates(lead_set: FeasibleSet) -> None:
    counts = lead_set.counts
    assert counts.sampled == TEST_CONFIG.num_candidates
    assert counts.sampled >= counts.kinematic >= counts.drivable >= counts.ego >= counts.actors
    assert counts.actors == lead_set.size >= TEST_CONFIG.min_feasible
    assert counts.sampled - counts.kinematic == sum(counts.violations.values())
    assert lead_set.deltas.shape == (lead_set.size, 12)
    assert np.all(np.abs(lead_set.deltas) <= 1.0)


def test_every_feasible_candidate_respects_the_bounds_the_road_and_every_obstacle(
    street: Scenario, lead_set: FeasibleSet
) -> None:
    obstacles = _labelled_obstacles(street, Window(0, 60), "lead", street.ego_geometry.forward_offset)
    road = shapely.Polygon(ROAD)
    rng = np.random.default_rng(0)
    for candidate in rng.choice(lead_set.size, size=60, replace=False):
        trajectory = lead_set.trajectory(int(candidate))
        assert_physically_plausible(trajectory, TEST_CONFIG)
        assert_on_road(trajectory, road)
        assert_collides_with_nothing(trajectory, obstacles)


def test_pruned_candidates_really_break_a_rule(street: Scenario, lead_set: FeasibleSet) -> None:
    """The pruning is not over-eager: a sample of removed candidates each break a bound, the road or an obstacle."""
    config = dataclasses.replace(TEST_CONFIG, num_candidates=3000)
    kept = build_feasible_set(street, Window(0, 60), "lead", config, np.random.default_rng(7))
    sampled = np.random.default_rng(7).random((3000, 12), dtype=np.float32) * np.float32(2) - np.float32(1)
    sampled[0] = 0.0
    kept_rows = {row.tobytes() for row in kept.deltas}
    removed = [row for row in sampled if row.tobytes() not in kept_rows]
    assert len(removed) == 3000 - kept.size
    obstacles = _labelled_obstacles(street, Window(0, 60), "lead", street.ego_geometry.forward_offset)
    # Tolerances of the pruning: raster cells of the road, the collision margin, float32 slack.
    inner_road = shapely.Polygon(ROAD).buffer(-0.36)
    grown = [[polygon.buffer(config.collision_margin * 1.5) for polygon in step] for step in obstacles]
    for row in removed[:: max(1, len(removed) // 40)]:
        trajectory = perturbation_to_trajectory(kept.reference, row.astype(np.float64), config)
        assert _breaks_a_rule(trajectory, config, inner_road, grown), f"candidate {row} was pruned for nothing"


def _breaks_a_rule(
    trajectory: PerturbedTrajectory,
    config: PerturberConfig,
    road: shapely.Polygon,
    obstacles: list[list[shapely.Polygon]],
) -> bool:
    tight = 1.0 - 1e-3
    speed, curvature = trajectory.speed, trajectory.curvature
    if (
        np.max(speed) > config.max_speed * tight
        or np.max(np.abs(curvature)) > config.max_curvature * tight
        or np.max(np.abs(np.diff(curvature) / DT)) > config.max_curvature_rate * tight
        or np.max(np.abs(np.diff(speed) / DT)) > config.max_accel * tight
        or np.max(np.abs(speed**2 * curvature)) > config.max_lateral_accel * tight
    ):
        return True
    if not all(road.contains(shapely.Point(x, y)) for x, y in zip(trajectory.x, trajectory.y, strict=True)):
        return True
    size = trajectory.size
    return any(
        _polygon(trajectory.x[step], trajectory.y[step], trajectory.yaw[step], size[0], size[1]).intersects(other)
        for step, polygons in enumerate(obstacles)
        for other in polygons
    )


def test_zero_perturbation_reproduces_the_logged_track_and_is_feasible(street: Scenario, lead_set: FeasibleSet) -> None:
    logged = street.actor("lead")
    replay = perturbation_to_trajectory(lead_set.reference, np.zeros(12), TEST_CONFIG)
    np.testing.assert_allclose(replay.x, logged.centers[:60, 0], atol=0.05)
    np.testing.assert_allclose(replay.y, logged.centers[:60, 1], atol=0.05)
    assert np.all(lead_set.deltas[0] == 0.0)  # the logged behaviour survived pruning
    (projected,) = project([lead_set], np.zeros(12))
    np.testing.assert_array_equal(projected.delta, np.zeros(12))
    np.testing.assert_allclose(projected.x, replay.x, atol=1e-9)


def test_projecting_a_feasible_candidate_returns_that_candidate(lead_set: FeasibleSet) -> None:
    for candidate in np.random.default_rng(1).choice(lead_set.size, size=20, replace=False):
        delta = lead_set.deltas[candidate].astype(np.float64)
        (projected,) = project([lead_set], delta)
        np.testing.assert_array_equal(projected.delta, delta)


def test_projection_returns_the_l2_nearest_feasible_candidate_deterministically(
    street: Scenario, lead_set: FeasibleSet
) -> None:
    obstacles = _labelled_obstacles(street, Window(0, 60), "lead", street.ego_geometry.forward_offset)
    rng = np.random.default_rng(2)
    origin = lead_set.reference.origin
    for _ in range(15):
        delta = rng.uniform(-1, 1, 12)
        query = perturbation_to_trajectory(lead_set.reference, delta, TEST_CONFIG)
        (projected,) = project([lead_set], delta)
        (again,) = project([lead_set], delta)
        np.testing.assert_array_equal(projected.x, again.x)
        flat_query = np.column_stack([query.x - origin[0], query.y - origin[1]]).reshape(-1)
        distances = np.linalg.norm(lead_set.positions.astype(np.float64) - flat_query, axis=1)
        mine = np.linalg.norm(np.column_stack([projected.x - query.x, projected.y - query.y]))
        assert mine <= distances.min() + 1e-3
        assert_physically_plausible(projected, TEST_CONFIG)
        assert_collides_with_nothing(projected, obstacles)


def test_perturbed_trajectory_converts_to_an_actor_track(lead_set: FeasibleSet) -> None:
    trajectory = lead_set.trajectory(3)
    track = trajectory.to_actor_track()
    assert track.actor_id == "lead"
    np.testing.assert_array_equal(track.stamps_ns, STAMPS[:60])
    np.testing.assert_allclose(track.centers[:, 0], trajectory.x)
    assert np.all(np.abs(track.yaws) <= math.pi)


def test_malformed_perturbations_are_rejected(lead_set: FeasibleSet) -> None:
    with pytest.raises(ScenarioError, match="expected delta of 12"):
        project([lead_set], np.zeros(11))
    with pytest.raises(ScenarioError, match=r"\[-1, 1\]"):
        project([lead_set], np.full(12, 1.5))


# --- actor selection and joint projection -------------------------------------------------------


def test_actors_are_ranked_by_their_smallest_gap_to_the_sdv(street: Scenario) -> None:
    window = Window(0, 60)
    ranked = rank_actors(street, window, TEST_CONFIG)
    gaps = dict(ranked)
    assert [gap for _, gap in ranked] == sorted(gaps.values())
    assert set(gaps) == {"lead", "oncoming", "parked", "walker"}
    offset = street.ego_geometry.forward_offset
    for actor_id in ("lead", "oncoming", "walker"):  # labelled at every window frame
        actor = street.actor(actor_id)
        ego = [polygons[0] for polygons in _labelled_obstacles(street, window, actor_id, offset)]
        expected = min(
            _polygon(*actor.centers[step, :2], actor.yaws[step], actor.length, actor.width).distance(ego[step])
            for step in range(window.num_steps)
        )
        assert gaps[actor_id] == pytest.approx(expected, abs=1e-6)


def test_selection_takes_the_closest_perturbable_actors_and_skips_pedestrians(street: Scenario) -> None:
    config = dataclasses.replace(TEST_CONFIG, num_actors=2)
    selection = select_actors(street, Window(0, 60), config, np.random.default_rng(3))
    assert len(selection.actor_ids) == 2
    assert selection.dimension == 24
    reasons = {report.actor_id: report.reason for report in selection.reports}
    assert "not perturbable" in reasons["walker"]
    closest = [actor_id for actor_id, _ in rank_actors(street, Window(0, 60), config) if actor_id != "walker"][:2]
    assert list(selection.actor_ids) == closest


def test_joint_projection_keeps_the_perturbed_actors_apart(street: Scenario) -> None:
    config = dataclasses.replace(TEST_CONFIG, num_actors=2)
    window = Window(0, 60)
    selection = select_actors(street, window, config, np.random.default_rng(3))
    rng = np.random.default_rng(4)
    road = shapely.Polygon(ROAD)
    for _ in range(8):
        first, second = selection.project(rng.uniform(-1, 1, selection.dimension))
        for trajectory in (first, second):
            assert_physically_plausible(trajectory, config)
            assert_on_road(trajectory, road)
            assert_collides_with_nothing(
                trajectory, _labelled_obstacles(street, window, trajectory.actor_id, street.ego_geometry.forward_offset)
            )
        for step in range(window.num_steps):
            a = _polygon(first.x[step], first.y[step], first.yaw[step], first.size[0], first.size[1])
            b = _polygon(second.x[step], second.y[step], second.yaw[step], second.size[0], second.size[1])
            assert not a.intersects(b)


def test_selection_fails_clearly_when_too_few_actors_can_be_perturbed(street: Scenario) -> None:
    config = dataclasses.replace(TEST_CONFIG, num_actors=4)
    with pytest.raises(TooFewActorsError, match="found 3 of 4") as caught:
        select_actors(street, Window(0, 60), config, np.random.default_rng(5))
    assert isinstance(caught.value, InfeasibleError)  # what the perturber and the checks catch
    assert len(caught.value.reports) == 4


def test_an_actor_unlabelled_at_the_window_start_cannot_be_fitted(street: Scenario) -> None:
    moving_late = ActorTrack(
        "late",
        "vehicle",
        np.array([4.0, 1.8, 1.5]),
        STAMPS[5:30],
        np.column_stack([np.linspace(0, 20, 25), np.full(25, 1.75), np.zeros(25)]),
        np.zeros(25),
    )
    scenario = dataclasses.replace(street, actors=(*street.actors, moving_late))
    with pytest.raises(InfeasibleError, match="not labelled at the first frame"):
        fit_reference(scenario, Window(0, 60), "late", TEST_CONFIG)


def test_a_parked_car_seen_late_stands_at_its_place_from_the_window_start(street: Scenario) -> None:
    reference = fit_reference(street, Window(55, 20), "parked", TEST_CONFIG)  # labelled in frames 0..49 only
    np.testing.assert_allclose(reference.fit.initial[:2], [45.0, 5.0])
    assert reference.fit.initial[3] == 0.0


# --- drivable area ------------------------------------------------------------------------------


def test_map_raster_agrees_with_the_polygon(street: Scenario) -> None:
    area = drivable_area_from_map(street.road_map or RoadMap(), (-70.0, -20.0, 270.0, 20.0), 0.25)
    rng = np.random.default_rng(6)
    points = np.column_stack([rng.uniform(-70, 270, 4000), rng.uniform(-20, 20, 4000)])
    road = shapely.Polygon(ROAD)
    inside = shapely.contains_xy(road, points[:, 0], points[:, 1])
    # Cells are 0.25 m: points farther than a cell from the edge must agree.
    clear = shapely.distance(road.exterior, shapely.points(points)) > 0.36
    np.testing.assert_array_equal(area.contains(points[:, 0], points[:, 1])[clear], inside[clear])
    shrunk = area.eroded(1.0)
    assert np.count_nonzero(shrunk.mask) < np.count_nonzero(area.mask)
    assert not shrunk.contains(np.array([0.0]), np.array([6.5]))[0]


def test_without_a_map_the_drivable_area_covers_where_vehicles_drove_but_not_the_pedestrian() -> None:
    scenario = street_scenario(with_map=False)
    config = DrivableConfig()
    area = estimate_drivable_area(scenario, config, scenario_extent(scenario, 20.0))
    assert area.source == "log estimate"
    ego_box_centres = scenario.ego.xy + np.array([1.0, 0.0])
    assert np.all(area.contains(ego_box_centres[:, 0], ego_box_centres[:, 1]))
    lead = scenario.actor("lead").centers
    assert np.all(area.contains(lead[:, 0], lead[:, 1]))
    walker = scenario.actor("walker").centers
    assert not np.any(area.contains(walker[:, 0], walker[:, 1]))


def test_drivable_area_for_uses_the_map_when_there_is_one(street: Scenario) -> None:
    area = drivable_area_for(street, dataclasses.replace(DrivableConfig(), reach=5.0))
    assert area.source == "map"
    with pytest.raises(ScenarioError, match="resolution"):
        DrivableArea(np.zeros(2), 0.0, np.ones((2, 2), dtype=bool), "map")


# --- real logs ----------------------------------------------------------------------------------


def _check_selection_on_real_log(scenario: Scenario, window: Window, config: PerturberConfig) -> None:
    drivable = drivable_area_for(scenario, DrivableConfig())
    selection = select_actors(scenario, window, config, np.random.default_rng(0), drivable=drivable)
    assert len(selection.actor_ids) == config.num_actors
    rng = np.random.default_rng(1)
    for feasible in selection.sets:
        assert feasible.size >= config.min_feasible
        obstacles = _labelled_obstacles(scenario, window, feasible.actor_id, scenario.ego_geometry.forward_offset)
        for candidate in rng.choice(feasible.size, size=min(15, feasible.size), replace=False):
            trajectory = feasible.trajectory(int(candidate))
            assert_physically_plausible(trajectory, config)
            assert_collides_with_nothing(trajectory, obstacles)
            assert np.all(drivable.contains(trajectory.x, trajectory.y))
    for trajectory in selection.project(rng.uniform(-1, 1, selection.dimension)):
        assert_physically_plausible(trajectory, config)


@pytest.fixture(scope="module")
def kitti_with_drivable(kitti_scenario: Scenario) -> Scenario:
    """KITTI 0000 with its drivable area estimated once (from 8 sweeps: a test need not take the default 20)."""
    area = drivable_area_for(kitti_scenario, dataclasses.replace(DrivableConfig(), max_sweeps=8))
    return dataclasses.replace(kitti_scenario, drivable_area=area)


@pytest.mark.parametrize("start", [0, 40, 90])
def test_kitti_windows_have_perturbable_actors_with_valid_feasible_sets(
    kitti_with_drivable: Scenario, start: int
) -> None:
    config = dataclasses.replace(TEST_CONFIG, num_candidates=50_000)
    _check_selection_on_real_log(kitti_with_drivable, Window(start, 60), config)


def test_argoverse2_logs_have_perturbable_actors_with_valid_feasible_sets(av2_logs: list[Path]) -> None:
    from advsim_ros.io.av2 import load_av2_log

    config = dataclasses.replace(TEST_CONFIG, num_candidates=50_000, num_actors=2)
    for log in av2_logs:
        scenario = load_av2_log(log)
        assert scenario.road_map is not None
        _check_selection_on_real_log(scenario, Window(0, 60), config)
