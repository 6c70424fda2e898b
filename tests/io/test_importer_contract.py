"""What every importer's scenario must hold, whatever the source: one test, parametrised over them.

KITTI tracking 0000, every Argoverse 2 log, a synthetic log and a user's own bag (odometry at
50 Hz, a two-link mount in /tf_static) all go through the same checks, written here without the
code under test: frames in time order, rigid ego poses and mount, a plausible ego box, actors
observed only at frame times and never the ego itself, sweeps at frame times seen from the ego's
mounted sensor. A new importer is added to SOURCES and gets every check.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from advsim_ros.core.types import Scenario
from advsim_ros.io.av2 import load_av2_log
from advsim_ros.io.bag import read_scenario_bag
from advsim_ros.io.synthetic import generate_synthetic_log


def _kitti(request: pytest.FixtureRequest, tmp_path: Path) -> list[Scenario]:
    return [request.getfixturevalue("kitti_scenario")]


def _av2(request: pytest.FixtureRequest, tmp_path: Path) -> list[Scenario]:
    return [load_av2_log(log) for log in request.getfixturevalue("av2_logs")]


def _synthetic(request: pytest.FixtureRequest, tmp_path: Path) -> list[Scenario]:
    return [generate_synthetic_log(np.random.default_rng(3)).scenario]


def _users_bag(request: pytest.FixtureRequest, tmp_path: Path) -> list[Scenario]:
    bags, config = request.getfixturevalue("user_bags"), request.getfixturevalue("user_bag_config")
    return [read_scenario_bag(bags.write(tmp_path / "user", bags.messages()), config=config)]


SOURCES: dict[str, Callable[[pytest.FixtureRequest, Path], list[Scenario]]] = {
    "kitti": _kitti,
    "av2": _av2,
    "synthetic": _synthetic,
    "users_bag": _users_bag,
}


def _assert_rigid(transform: Any, what: str) -> None:
    transform = np.asarray(transform, dtype=np.float64)
    assert transform.shape == (4, 4), what
    assert np.isfinite(transform).all(), what
    rotation = transform[:3, :3]
    np.testing.assert_allclose(rotation.T @ rotation, np.eye(3), atol=1e-6, err_msg=what)
    assert np.linalg.det(rotation) == pytest.approx(1.0, abs=1e-6), what
    np.testing.assert_array_equal(transform[3], [0.0, 0.0, 0.0, 1.0], err_msg=what)


@pytest.mark.parametrize("source", sorted(SOURCES))
def test_every_importer_gives_a_scenario_the_attack_can_use(
    source: str, request: pytest.FixtureRequest, tmp_path: Path
) -> None:
    for scenario in SOURCES[source](request, tmp_path):
        name = f"{source}: {scenario.scenario_id}"
        frames = scenario.frame_stamps_ns
        assert frames.dtype == np.int64, name
        assert frames.ndim == 1, name
        assert frames.size >= 2, name
        assert (np.diff(frames) > 0).all(), f"{name}: frame stamps not strictly increasing"

        # the ego: one rigid pose per frame, a rigid mount (identity for AV2's merged sweeps), a car-sized box
        np.testing.assert_array_equal(scenario.ego.stamps_ns, frames, err_msg=name)
        for index, pose in enumerate(scenario.ego.poses):
            _assert_rigid(pose, f"{name}: ego pose {index}")
        _assert_rigid(scenario.ego_T_sensor, f"{name}: mount")
        length, width, height = scenario.ego_geometry.size
        assert 3.0 <= length <= 6.5, f"{name}: ego length {length}"
        assert 1.4 <= width <= 2.6, f"{name}: ego width {width}"
        assert 1.0 <= height <= 3.0, f"{name}: ego height {height}"

        # actors: unique, observed only at frame times, finite, and never the ego itself
        ids = [actor.actor_id for actor in scenario.actors]
        assert len(ids) == len(set(ids)), f"{name}: duplicate actor ids"
        ego_xy = dict(zip(frames.tolist(), scenario.ego.poses[:, :2, 3], strict=True))
        for actor in scenario.actors:
            what = f"{name}: actor {actor.actor_id}"
            assert np.isin(actor.stamps_ns, frames).all(), f"{what} has stamps that are not frame stamps"
            assert (np.diff(actor.stamps_ns) > 0).all(), what
            assert np.isfinite(actor.centers).all(), what
            assert np.isfinite(actor.yaws).all(), what
            assert (actor.size > 0).all(), what
            distances = [
                np.hypot(*(center[:2] - ego_xy[int(stamp)]))
                for stamp, center in zip(actor.stamps_ns, actor.centers, strict=True)
            ]
            assert min(distances) > 0.5, f"{what} sits on the ego (the ego among the actors?)"

        # sweeps: at frame times, finite points, seen from the ego's pose through the mount
        mounted = scenario.ego.poses @ scenario.ego_T_sensor
        world_T_sensor = {int(stamp): pose for stamp, pose in zip(frames, mounted, strict=True)}
        for sweep in scenario.sweeps:
            what = f"{name}: sweep at {sweep.stamp_ns}"
            assert sweep.stamp_ns in world_T_sensor, f"{what} is not at a frame stamp"
            assert sweep.points.size > 0, what
            for axis in "xyz":
                assert np.isfinite(sweep.points[axis]).all(), what
            np.testing.assert_allclose(sweep.sensor_pose, world_T_sensor[sweep.stamp_ns], atol=1e-6, err_msg=what)
