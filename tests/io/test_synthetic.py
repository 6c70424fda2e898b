"""Synthetic street logs: deterministic per seed, complete (tracks, map, 64-beam sweeps), re-renderable."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from advsim_ros.cli import main
from advsim_ros.core.lidar.boxes import inside, removal_region, to_box_frame, yaw_pose
from advsim_ros.core.lidar.sensor import xyz_of
from advsim_ros.core.types import ActorClass, ScenarioError
from advsim_ros.io.bag import read_scenario_bag
from advsim_ros.io.synthetic import SyntheticConfig, generate_synthetic_log, synthetic_sensor_model

SHORT = SyntheticConfig(duration=1.0)


def test_the_same_seed_gives_the_same_log_and_another_seed_another() -> None:
    first = generate_synthetic_log(np.random.default_rng(11), SHORT).scenario
    again = generate_synthetic_log(np.random.default_rng(11), SHORT).scenario
    other = generate_synthetic_log(np.random.default_rng(12), SHORT).scenario
    assert all(np.array_equal(a.points, b.points) for a, b in zip(first.sweeps, again.sweeps, strict=True))
    assert all(np.array_equal(a.centers, b.centers) for a, b in zip(first.actors, again.actors, strict=True))
    assert not np.array_equal(first.actors[0].centers, other.actors[0].centers)


def test_a_log_has_a_street_scene_with_every_kind_of_actor_and_a_map() -> None:
    log = generate_synthetic_log(np.random.default_rng(5), SHORT)
    scenario = log.scenario
    assert scenario.num_frames == 10
    assert len(scenario.sweeps) == 10
    classes = [actor.actor_class for actor in scenario.actors]
    assert classes.count(ActorClass.VEHICLE) >= 10
    assert ActorClass.PEDESTRIAN in classes
    speeds = [np.linalg.norm(actor.centers[-1] - actor.centers[0]) for actor in scenario.actors]
    assert sum(speed > 0.5 for speed in speeds) == 4  # three moving vehicles and the pedestrian
    assert scenario.road_map is not None
    assert len(scenario.road_map.lane_centerlines) == 4
    assert scenario.sensor is not None
    assert scenario.sensor.num_beams == 64
    points = scenario.sweeps[0].points
    assert points.dtype.names == ("x", "y", "z", "intensity", "ring")
    assert points.shape[0] > 80_000
    assert int(points["ring"].max()) == 63


def test_every_actor_is_seen_inside_its_box_and_nothing_else_is() -> None:
    log = generate_synthetic_log(np.random.default_rng(5), SHORT)
    sweep = log.scenario.sweeps[5]
    xyz = xyz_of(sweep.points)
    to_sensor = np.linalg.inv(sweep.sensor_pose)
    for actor in log.scenario.actors:
        pose = to_sensor @ yaw_pose(actor.centers[5], float(actor.yaws[5]))
        near = inside(to_box_frame(xyz, pose), removal_region(actor.size, 0.01))
        # Boxes are exact: the ground under an actor lies on the box bottom, its body inside.
        assert np.all(to_box_frame(xyz[near], pose)[:, 2] >= -0.5 * actor.size[2] - 0.05)


def test_rendering_again_with_an_actor_moved_changes_only_what_it_covers() -> None:
    log = generate_synthetic_log(np.random.default_rng(5), SyntheticConfig(duration=1.0, range_noise_std=0.0))
    sweep = log.scenario.sweeps[3]
    poses = log.actor_poses_at(sweep.stamp_ns)
    same = log.render(sweep.sensor_pose, poses, np.random.default_rng(0))
    assert np.array_equal(same, sweep.points) or np.allclose(xyz_of(same), xyz_of(sweep.points), atol=1e-4)
    poses["lead"] = poses["lead"] @ yaw_pose([0.0, 2.0, 0.0], 0.0)
    moved = log.render(sweep.sensor_pose, poses, np.random.default_rng(0))
    changed = np.mean(~np.isin(moved, same))
    assert 0.0 < changed < 0.05


def test_bad_settings_are_refused_naming_the_setting() -> None:
    with pytest.raises(ScenarioError, match="duration"):
        SyntheticConfig(duration=0.1)
    with pytest.raises(ScenarioError, match="ray_drop_probability"):
        SyntheticConfig(ray_drop_probability=1.0)
    assert synthetic_sensor_model(SyntheticConfig(azimuth_resolution_deg=0.4)).num_azimuths == 900
    log = generate_synthetic_log(np.random.default_rng(5), SHORT)
    with pytest.raises(ScenarioError, match="unknown actors"):
        log.render(np.eye(4), {"nobody": np.eye(4)}, np.random.default_rng(0))


def test_synth_command_writes_a_bag_and_refuses_to_overwrite(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "street"
    assert main(["synth", "-o", str(out), "--seed", "4", "--duration", "1"]) == 0
    assert "synthetic_4" in capsys.readouterr().out
    scenario = read_scenario_bag(out)
    assert scenario.num_frames == 10
    assert len(scenario.sweeps) == 10
    assert main(["synth", "-o", str(out), "--seed", "4", "--duration", "1"]) == 1  # exists: refuses
    assert "exists" in capsys.readouterr().err
    assert main(["synth", "-o", str(tmp_path / "bad"), "--duration", "0.01"]) == 1
    assert not (tmp_path / "bad").exists()
