"""Scenario curation: Frenet sampling, which actors count, and which window wins, on small exact scenes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from advsim_ros.core.curation import (
    CurationConfig,
    best_window,
    crop_scenario,
    curate_windows,
    evaluate_window,
    frenet_to_world,
    load_curation_config,
    sample_sdv_trajectories,
    world_to_frenet,
)
from advsim_ros.core.params import ParamsError
from advsim_ros.core.types import ActorClass, ActorTrack, EgoTrajectory, Scenario, ScenarioError

REPO = Path(__file__).resolve().parents[2]
PERIOD_NS = 100_000_000
CONFIG = CurationConfig()


def _straight_ego(num_frames: int, speed: float = 10.0) -> EgoTrajectory:
    stamps = PERIOD_NS * np.arange(1, num_frames + 1, dtype=np.int64)
    poses = np.tile(np.eye(4), (num_frames, 1, 1))
    poses[:, 0, 3] = speed * 0.1 * np.arange(num_frames)
    return EgoTrajectory(stamps_ns=stamps, poses=poses)


def _actor(actor_id: str, stamps: np.ndarray, xy: np.ndarray, yaw: float = 0.0) -> ActorTrack:
    return ActorTrack(
        actor_id=actor_id,
        actor_class=ActorClass.VEHICLE,
        size=np.array([4.5, 1.9, 1.6]),
        stamps_ns=stamps,
        centers=np.column_stack([xy, np.zeros(len(stamps))]),
        yaws=np.full(len(stamps), yaw),
    )


def _scene(*actors: ActorTrack, num_frames: int = 120) -> Scenario:
    ego = _straight_ego(num_frames)
    return Scenario("scene", ego.stamps_ns, ego, actors)


def test_frenet_coordinates_round_trip_on_a_curved_path() -> None:
    angles = np.linspace(0.0, np.pi / 2, 60)
    path = np.column_stack([30.0 * np.sin(angles), 30.0 - 30.0 * np.cos(angles)])  # quarter circle, radius 30 m
    s = np.array([1.0, 10.0, 20.0, 40.0])
    d = np.array([0.0, 1.5, -2.0, 0.5])
    back_s, back_d = world_to_frenet(path, frenet_to_world(path, s, d))
    np.testing.assert_allclose(back_s, s, atol=1e-9)
    np.testing.assert_allclose(back_d, d, atol=1e-9)


def test_samples_keep_lane_and_change_lanes_by_one_lane_width() -> None:
    path = np.array([[0.0, 0.0], [200.0, 0.0]])
    times = 0.1 * np.arange(1, 51)
    xy, headings = sample_sdv_trajectories(path, 10.0, times, CONFIG)
    assert xy.shape == (CONFIG.num_trajectories, 50, 2) == (30, 50, 2)
    keep_lane_constant_speed = 3 * (1 + 2 * len(CONFIG.lane_change_durations))  # acceleration 0.0 is the 4th
    np.testing.assert_allclose(xy[keep_lane_constant_speed, :, 0], 10.0 * times)
    np.testing.assert_allclose(xy[keep_lane_constant_speed, :, 1], 0.0)
    np.testing.assert_allclose(headings[keep_lane_constant_speed], 0.0, atol=1e-12)
    finals = np.round(xy[:, -1, 1], 9)
    assert set(finals.tolist()) == {0.0, 3.5, -3.5}
    hard_braking = xy[0, :, 0]  # -3 m/s^2 from 10 m/s stops after 3.33 s, 16.7 m on
    np.testing.assert_allclose(hard_braking[-1], 10.0**2 / (2 * 3.0))


def test_a_crossing_vehicle_makes_its_window_the_most_critical() -> None:
    stamps = _straight_ego(120).stamps_ns
    # Crosses the ego's lane (y from -15 to +15 m at 5 m/s) at x = 85 m around t = 8.5 s, when the ego is there.
    frames = np.arange(55, 120)
    seconds = frames * 0.1
    crossing = _actor("crossing", stamps[frames], np.column_stack([np.full(len(frames), 85.0), 5.0 * (seconds - 8.5)]))
    crossing = ActorTrack(
        crossing.actor_id, crossing.actor_class, crossing.size, crossing.stamps_ns, crossing.centers,
        np.full(len(frames), np.pi / 2),
    )  # fmt: skip
    windows = curate_windows(_scene(crossing), CONFIG)
    assert [window.start_frame for window in windows] == [0, 20, 40, 60]
    rates = {window.start_frame: window.collision_rate for window in windows}
    assert rates[0] == 0.0  # the crossing happens after this window's future ends
    assert rates[0] < rates[20] < rates[40] < rates[60]
    assert rates[60] == 1.0  # decided 1.6 s before the crossing: not even hard braking avoids it
    assert best_window(windows).start_frame == 60


def test_the_vehicle_directly_ahead_is_ignored_but_one_in_the_next_lane_is_not() -> None:
    stamps = _straight_ego(120).stamps_ns
    t = np.arange(120) * 0.1
    slow_lead = _actor("lead", stamps, np.column_stack([15.0 + 5.0 * t, np.zeros(120)]))  # ego closes in at 5 m/s
    window = evaluate_window(_scene(slow_lead), 0, CONFIG)
    assert window.lead_actor_id == "lead"
    assert (window.collision_rate, window.num_actors) == (0.0, 0)
    beside = _actor("beside", stamps, np.column_stack([15.0 + 5.0 * t, np.full(120, 3.5)]))
    window = evaluate_window(_scene(beside), 0, CONFIG)
    assert window.lead_actor_id == ""
    assert window.num_actors == 1
    assert 0.0 < window.collision_rate < 1.0  # only the changes into its lane hit it


def test_static_actors_are_ignored() -> None:
    stamps = _straight_ego(120).stamps_ns
    jitter = np.random.default_rng(3).normal(0.0, 0.05, (120, 2))  # label noise of a parked car
    parked = _actor("parked", stamps, np.array([30.0, 3.5]) + jitter)
    window = evaluate_window(_scene(parked), 0, CONFIG)
    assert (window.num_actors, window.collision_rate) == (0, 0.0)


def test_a_log_shorter_than_one_window_is_rejected() -> None:
    with pytest.raises(ScenarioError, match="has 40 frames; a curation window needs 60"):
        curate_windows(_scene(num_frames=40), CONFIG)


def test_cropping_keeps_the_window_frames_and_the_actors_seen_in_them() -> None:
    stamps = _straight_ego(120).stamps_ns
    early = _actor("early", stamps[:10], np.full((10, 2), 5.0))
    late = _actor("late", stamps[70:], np.full((50, 2), 5.0))
    scenario = _scene(early, late)
    window = evaluate_window(scenario, 60, CONFIG)
    cropped = crop_scenario(scenario, window)
    assert cropped.num_frames == 60
    np.testing.assert_array_equal(cropped.frame_stamps_ns, stamps[60:120])
    assert [actor.actor_id for actor in cropped.actors] == ["late"]
    assert cropped.scenario_id == "scene@60"


def test_params_curation_yaml_holds_the_defaults_and_bad_values_are_named(tmp_path: Path) -> None:
    assert load_curation_config(REPO / "params" / "curation.yaml") == CurationConfig()
    bad = tmp_path / "curation.yaml"
    bad.write_text("/curation:\n  ros__parameters:\n    lane_width: -1.0\n")
    with pytest.raises(ParamsError, match="lane_width: must be positive"):
        load_curation_config(bad)
