"""An attack on a window of a whole log reads and models only the window (issue: the README's path as lean as
the benchmark's): the bag's sweeps outside it are not converted, and the window's re-simulation model is the
one an attack on the window cut out into a bag of its own builds (one cache entry for both)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from advsim_ros.core.episode import WindowConfig
from advsim_ros.core.lidar.config import ResimConfig
from advsim_ros.core.lidar.model_cache import scenario_digest
from advsim_ros.core.types import Scenario
from advsim_ros.io.bag import read_scenario_bag, write_scenario_bag


def test_only_the_sweeps_between_two_stamps_are_read_and_the_log_keeps_every_frame(kitti_bag: Path) -> None:
    whole = read_scenario_bag(kitti_bag, load_sweeps=False)
    first, last = int(whole.frame_stamps_ns[20]), int(whole.frame_stamps_ns[79])
    window = read_scenario_bag(kitti_bag, sweeps_between=(first, last))
    np.testing.assert_array_equal(window.frame_stamps_ns, whole.frame_stamps_ns)  # every frame and pose
    assert [sweep.stamp_ns for sweep in window.sweeps] == whole.frame_stamps_ns[20:80].tolist()
    every = read_scenario_bag(kitti_bag)
    kept = {sweep.stamp_ns: sweep for sweep in every.sweeps}
    for sweep in window.sweeps:
        np.testing.assert_array_equal(sweep.points, kept[sweep.stamp_ns].points)
        np.testing.assert_array_equal(sweep.sensor_pose, kept[sweep.stamp_ns].sensor_pose)


def test_the_window_of_a_whole_log_is_the_model_of_the_windows_own_bag(
    kitti_scenario: Scenario, kitti_bag: Path, tmp_path: Path
) -> None:
    window = WindowConfig(window_start_frame=20)
    from_whole_log = window.crop(read_scenario_bag(kitti_bag))
    assert from_whole_log.num_frames == window.num_frames == len(from_whole_log.sweeps)
    own_bag = write_scenario_bag(WindowConfig(window_start_frame=20).crop(kitti_scenario), tmp_path / "window")
    from_own_bag = read_scenario_bag(own_bag)
    config = ResimConfig()
    assert scenario_digest(from_whole_log, config) == scenario_digest(from_own_bag, config)
    assert scenario_digest(from_whole_log, config) != scenario_digest(WindowConfig().crop(kitti_scenario), config)
