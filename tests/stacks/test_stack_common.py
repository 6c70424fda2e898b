"""What both stacks share: parameter files, ego motion from poses, points, plan stamps, windows."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from advsim_ros.core.params import ParamsError
from advsim_ros.stacks.interface import (
    EgoMotion,
    StackError,
    ego_motion_from_poses,
    plan_stamps,
    points_xyz,
    transform_points,
)
from advsim_ros.stacks.learned.config import LearnedStackConfig, load_learned_config
from advsim_ros.stacks.modular.config import ModularStackConfig, load_modular_config


def test_the_shipped_parameter_files_hold_exactly_the_defaults() -> None:
    assert load_modular_config() == ModularStackConfig()
    assert load_learned_config() == LearnedStackConfig()


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("planner:\n      speed_limitt: 10.0", r"speed_limitt"),
        ("ground:\n      cell_size: -1.0", r"ground.*cell_size"),
        ("tracker:\n      min_hits: 1.5", r"tracker\.min_hits"),
        ("detectr:\n      min_points: 3", r"detectr"),
    ],
)
def test_a_bad_parameter_file_is_refused_with_the_key_named(tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / "stack.yaml"
    path.write_text(f"/modular_stack:\n  ros__parameters:\n    {text}\n")
    with pytest.raises(ParamsError, match=message):
        load_modular_config(path)


def _circle_poses(speed: float, yaw_rate: float, times: np.ndarray) -> np.ndarray:
    yaw = yaw_rate * times
    poses = np.tile(np.eye(4), (times.shape[0], 1, 1))
    poses[:, 0, 0], poses[:, 0, 1], poses[:, 1, 0], poses[:, 1, 1] = np.cos(yaw), -np.sin(yaw), np.sin(yaw), np.cos(yaw)
    poses[:, 0, 3] = speed * np.sin(yaw) / yaw_rate
    poses[:, 1, 3] = speed * (1.0 - np.cos(yaw)) / yaw_rate
    return poses


def test_ego_motion_comes_from_past_poses_only_and_ignores_stale_ones() -> None:
    times = np.arange(0.0, 2.0, 0.1)
    stamps = (times * 1e9).astype(np.int64)
    poses = _circle_poses(6.0, 0.3, times)
    motion = ego_motion_from_poses(stamps, poses, int(stamps[10]))
    assert motion.speed == pytest.approx(6.0, rel=0.01)
    assert motion.yaw_rate == pytest.approx(0.3, rel=1e-6)
    assert motion.acceleration == pytest.approx(0.0, abs=1e-6)
    # Poses from before a jump in time (another query's segment) do not count: the twist fallback does.
    fallback = EgoMotion(speed=1.0, yaw_rate=0.0)
    jumped = ego_motion_from_poses(stamps[[0, 19]] + [0, 5 * 10**9], poses[[0, 19]], 5 * 10**9 + int(stamps[19]),
                                   fallback=fallback)  # fmt: skip
    assert jumped is fallback


def test_points_come_from_any_field_layout_and_move_with_a_transform() -> None:
    points = np.zeros(3, dtype=[("intensity", "<f4"), ("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("ring", "<u2")])
    points["x"], points["y"], points["z"] = [1, 2, 3], [4, 5, 6], [7, 8, 9]
    xyz = points_xyz(points)
    np.testing.assert_array_equal(xyz, [[1, 4, 7], [2, 5, 8], [3, 6, 9]])
    transform = _circle_poses(5.0, 0.4, np.array([1.3]))[0]
    transform[2, 3] = 1.73
    np.testing.assert_allclose(
        transform_points(xyz.astype(np.float64), transform), xyz @ transform[:3, :3].T + transform[:3, 3]
    )
    with pytest.raises(StackError, match="z"):
        points_xyz(np.zeros(2, dtype=[("x", "<f4"), ("y", "<f4")]))


def test_a_plan_has_fifty_stamps_a_tenth_of_a_second_apart_after_the_sweep() -> None:
    stamps = plan_stamps(3_000_000_000, 5.0, 0.1)
    np.testing.assert_array_equal(stamps, 3_000_000_000 + 100_000_000 * np.arange(1, 51))
