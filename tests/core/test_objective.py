"""Objective terms, presets and baselines on hand-made scenes with known values; the scorer parameters file."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from advsim_ros import graph
from advsim_ros.core.futures import ActorFutures, actor_futures_at
from advsim_ros.core.metrics import MetricsConfig
from advsim_ros.core.objective import (
    PRESET_NAMES,
    ObjectiveConfig,
    evaluate_objective,
    load_scorer_settings,
    objective_preset,
    scorer_settings_from_params,
)
from advsim_ros.core.params import ParamsError
from advsim_ros.core.types import (
    ActorClass,
    ActorTrack,
    DrivableArea,
    EgoGeometry,
    EgoTrajectory,
    Plan,
    RoadMap,
    ScenarioError,
)

REPO = Path(__file__).resolve().parents[2]
DT = 0.1  # [s]
STEPS = 50
START_NS = 5_000_000_000
EGO = EgoGeometry(np.array([4.5, 1.9, 1.7]), forward_offset=1.0)  # the SDV's box, 1 m ahead of its origin
CONFIG = ObjectiveConfig()


def _plan(xy: np.ndarray, yaws: np.ndarray | None = None) -> Plan:
    stamps = START_NS + np.round(np.arange(xy.shape[0]) * DT * 1e9).astype(np.int64)
    return Plan(stamps, xy, np.zeros(xy.shape[0]) if yaws is None else yaws)


def _human(xy: np.ndarray) -> EgoTrajectory:
    poses = np.tile(np.eye(4), (xy.shape[0], 1, 1))
    poses[:, :2, 3] = xy
    return EgoTrajectory(START_NS + np.round(np.arange(xy.shape[0]) * DT * 1e9).astype(np.int64), poses)


def _straight(speed: float = 10.0, lateral: float = 0.0) -> np.ndarray:
    times = np.arange(STEPS) * DT
    return np.stack([speed * times, np.full(STEPS, lateral)], axis=-1)


def _alongside(gap: float) -> ActorFutures:
    """A 4.5 x 1.9 m car driving beside the ego box with `gap` metres between the boxes (negative: overlapping)."""
    ego_centre = _straight() + np.array([1.0, 0.0])
    states = np.concatenate([ego_centre + np.array([0.0, 1.9 + gap]), np.zeros((STEPS, 1))], axis=-1)[None]
    return ActorFutures(states, np.array([[4.5, 1.9]]))


NO_ACTORS = ActorFutures(np.zeros((0, STEPS, 3)), np.zeros((0, 2)))


def test_imitation_loss_is_the_mean_smooth_l1_to_the_human_poses() -> None:
    human = _human(_straight())
    small = evaluate_objective(_plan(_straight(lateral=0.5)), human, NO_ACTORS, EGO, CONFIG)
    assert small.imitation == pytest.approx(0.5 * 0.5**2)  # quadratic below beta = 1 m
    large = evaluate_objective(_plan(_straight(lateral=3.0)), human, NO_ACTORS, EGO, CONFIG)
    assert large.imitation == pytest.approx(3.0 - 0.5)  # linear above


def test_collision_cost_rises_before_contact_and_exceeds_one_on_overlap() -> None:
    plan, human = _plan(_straight()), _human(_straight())
    one_metre = evaluate_objective(plan, human, _alongside(1.0), EGO, CONFIG)
    assert one_metre.collision == pytest.approx(STEPS * (1.0 - 1.0 / CONFIG.collision_margin))
    assert one_metre.closest_distance == pytest.approx(1.0)
    far = evaluate_objective(plan, human, _alongside(3.0), EGO, CONFIG)
    assert far.collision == 0.0
    same_box = evaluate_objective(plan, human, _alongside(-1.9), EGO, CONFIG)  # exactly on the ego box
    assert same_box.collision == pytest.approx(STEPS * 2.0)  # 1 + IoU of 1 at every step
    assert same_box.closest_distance == 0.0


def test_comfort_cost_charges_jerk_above_the_limit() -> None:
    times = np.arange(STEPS) * DT
    xy = np.stack([10.0 * times + 3.0 * times**3 / 6.0, np.zeros(STEPS)], axis=-1)  # jerk 3 m/s^3, limit 2
    terms = evaluate_objective(_plan(xy), _human(xy), NO_ACTORS, EGO, CONFIG)
    assert terms.comfort == pytest.approx(CONFIG.jerk_weight * 1.0 * (STEPS - 3), rel=1e-6)
    smooth = evaluate_objective(_plan(_straight()), _human(_straight()), NO_ACTORS, EGO, CONFIG)
    assert smooth.comfort == 0.0
    assert not smooth.lane_available


def test_leaving_the_drivable_area_and_the_lane_costs_only_when_a_map_is_given() -> None:
    # A 200 x 4 m drivable strip along y = 0 and a centreline on it; the plan runs 5 m to its left.
    mask = np.zeros((32, 800), dtype=bool)  # 0.25 m cells from (-50, -4): x in [-50, 150), y in [-4, 4)
    mask[8:24, :] = True  # y in [-2, 2)
    drivable = DrivableArea(origin=np.array([-50.0, -4.0]), resolution=0.25, mask=mask, source="map")
    road_map = RoadMap(lane_centerlines=(np.array([[-50.0, 0.0], [150.0, 0.0]]),))
    plan, human = _plan(_straight(lateral=5.0)), _human(_straight(lateral=5.0))
    off_road = evaluate_objective(plan, human, NO_ACTORS, EGO, CONFIG, drivable=drivable, road_map=road_map)
    expected = STEPS * (CONFIG.drivable_weight * 1.0 + CONFIG.lane_weight * (5.0 - CONFIG.lane_half_width))
    assert off_road.lane_available
    assert off_road.comfort == pytest.approx(expected)
    plan, human = _plan(_straight()), _human(_straight())
    on_road = evaluate_objective(plan, human, NO_ACTORS, EGO, CONFIG, drivable=drivable, road_map=road_map)
    assert on_road.comfort == 0.0


def test_lane_cost_works_with_centrelines_of_different_lengths() -> None:
    # Real maps (Argoverse 2) have lanes of many point counts; the plan runs 5 m left of the nearer one.
    road_map = RoadMap(
        lane_centerlines=(
            np.array([[-50.0, 0.0], [50.0, 0.0], [150.0, 0.0]]),
            np.array([[-50.0, -20.0], [150.0, -20.0]]),
        )
    )
    plan, human = _plan(_straight(lateral=5.0)), _human(_straight(lateral=5.0))
    terms = evaluate_objective(plan, human, NO_ACTORS, EGO, CONFIG, road_map=road_map)
    assert terms.lane_available
    assert terms.comfort == pytest.approx(STEPS * CONFIG.lane_weight * (5.0 - CONFIG.lane_half_width))


def test_presets_switch_terms_and_the_full_objective_is_their_weighted_sum() -> None:
    plan, human = _plan(_straight(lateral=0.5)), _human(_straight())
    actors = _alongside(1.0)
    terms = evaluate_objective(plan, human, actors, EGO, CONFIG)
    expected = {
        "M0": terms.imitation,
        "M1": terms.collision,
        "M2": terms.imitation + terms.collision,
        "M3": terms.imitation + terms.comfort,
        "M4": terms.collision + terms.comfort,
        "M5": terms.imitation + terms.collision + terms.comfort,
    }
    for name, value in expected.items():
        assert evaluate_objective(plan, human, actors, EGO, objective_preset(name)).value == pytest.approx(value)
    weighted = dataclasses.replace(CONFIG, imitation_weight=2.0, collision_weight=3.0)
    assert evaluate_objective(plan, human, actors, EGO, weighted).value == pytest.approx(
        2.0 * terms.imitation + 3.0 * terms.collision + terms.comfort,
    )


def test_an_actor_costs_nothing_and_is_not_close_before_it_first_appears() -> None:
    # A 4.5 x 1.9 m car labelled from 4.0 s after the decision on, standing at x = 20 m (box 17.75-22.25 m).
    # The ego at 10 m/s (box from x - 1.25 to x + 3.25 m) drives through that spot at 1.5-2.3 s; at 4.0 s
    # its rear is at 38.75 m: 16.5 m past the car.
    stamps = START_NS + np.round(np.arange(40, 51) * DT * 1e9).astype(np.int64)
    car = ActorTrack("late", ActorClass.VEHICLE, np.array([4.5, 1.9, 1.5]), stamps, np.tile([20.0, 0.0, 0.0], (11, 1)),
                     np.zeros(11))  # fmt: skip
    plan, human = _plan(_straight()), _human(_straight())
    late = actor_futures_at([car], plan.stamps_ns)
    terms = evaluate_objective(plan, human, late, EGO, CONFIG)
    assert terms.collision == 0.0
    assert terms.closest_distance == pytest.approx(16.5)
    baseline = evaluate_objective(plan, human, late, EGO, objective_preset("closest_distance"))
    assert baseline.value == pytest.approx(-16.5)
    held = ActorFutures(np.tile([20.0, 0.0, 0.0], (1, STEPS, 1)), late.sizes)  # the old rule: there from the start
    assert evaluate_objective(plan, human, held, EGO, CONFIG).collision > 8.0


def test_closest_distance_baseline_is_minus_the_smallest_gap() -> None:
    plan, human = _plan(_straight()), _human(_straight())
    config = objective_preset("closest_distance")
    assert evaluate_objective(plan, human, _alongside(1.5), EGO, config).value == pytest.approx(-1.5)
    assert evaluate_objective(plan, human, NO_ACTORS, EGO, config).value == pytest.approx(-np.hypot(72.0, 40.0))


def test_max_margin_baseline_is_how_much_costlier_the_plan_is_than_the_human_trajectory() -> None:
    # The actor drives where the plan swerves to (2.5 m left) but 1 m clear of the human trajectory.
    human = _human(_straight())
    plan = _plan(_straight(lateral=2.5))
    actors = _alongside(1.0)
    config = objective_preset("max_margin")
    value = evaluate_objective(plan, human, actors, EGO, config).value
    plan_cost = evaluate_objective(plan, human, actors, EGO, CONFIG).collision
    human_cost = STEPS * (1.0 - 1.0 / CONFIG.collision_margin)
    assert plan_cost > human_cost
    assert value == pytest.approx(plan_cost - human_cost)
    assert evaluate_objective(_plan(_straight()), human, actors, EGO, config).value == pytest.approx(0.0)


def test_plans_too_short_for_jerk_are_rejected() -> None:
    short = _straight()[:3]
    actors = ActorFutures(np.zeros((0, 3, 3)), np.zeros((0, 2)))
    with pytest.raises(ScenarioError, match="needs >= 4"):
        evaluate_objective(_plan(short), _human(_straight()), actors, EGO, CONFIG)


def test_a_plan_beyond_the_log_is_rejected_by_the_imitation_term() -> None:
    human = EgoTrajectory(np.array([0, 1_000_000_000]), np.tile(np.eye(4), (2, 1, 1)))
    with pytest.raises(ScenarioError, match="does not cover"):
        evaluate_objective(_plan(_straight()), human, NO_ACTORS, EGO, CONFIG)


def test_objective_config_names_the_bad_key() -> None:
    with pytest.raises(ScenarioError, match=r"ObjectiveConfig.collision_margin: must be positive"):
        ObjectiveConfig(collision_margin=0.0)
    with pytest.raises(ScenarioError, match="all off"):
        ObjectiveConfig(use_imitation=False, use_collision=False, use_comfort=False)
    with pytest.raises(ScenarioError, match="unknown objective preset 'M9'"):
        objective_preset("M9")


def test_the_scorer_parameters_file_loads_into_the_full_objective() -> None:
    settings = load_scorer_settings(REPO / "params" / "scorer.yaml", node=graph.SCORER.name)
    assert settings.objective == ObjectiveConfig()
    assert settings.metrics == MetricsConfig()  # the file holds every metrics default (actor_extrapolation too)
    assert settings.metrics.horizons == (3.0, 5.0)
    assert settings.metrics.x_range == (-72.0, 72.0)
    assert set(PRESET_NAMES) >= {"M0", "M5"}


def test_scorer_parameters_name_unknown_and_mistyped_keys() -> None:
    with pytest.raises(ParamsError, match=r"objective: unknown parameter\(s\) \['colision_weight'\]"):
        scorer_settings_from_params({"objective": {"colision_weight": 1.0}}, "scorer")
    with pytest.raises(ParamsError, match=r"scorer.metrics.iou_threshold: expected a number"):
        scorer_settings_from_params({"metrics": {"iou_threshold": "high"}}, "scorer")
    with pytest.raises(ParamsError, match=r"scorer.objective.preset"):
        scorer_settings_from_params({"objective": {"preset": "M7"}}, "scorer")
    preset = scorer_settings_from_params({"objective": {"preset": "M1", "collision_weight": 2.0}}, "scorer")
    assert preset.objective.collision_weight == 2.0
    assert not preset.objective.use_imitation


def test_a_range_with_the_wrong_number_of_entries_is_named() -> None:
    with pytest.raises(ParamsError, match=r"scorer.metrics.x_range: expected 2 entries, got 3"):
        scorer_settings_from_params({"metrics": {"x_range": [-72.0, 0.0, 72.0]}}, "scorer")
