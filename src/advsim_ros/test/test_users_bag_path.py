"""The README's path for a user's own drive, command by command: label -> curate -> attack -> replay --check -> report.

The drive is recorded as a user's recorder writes it: 8 s of KITTI tracking 0000's Velodyne on
/velodyne_points in frame `velodyne`, the mount on /tf_static, no poses, no tracks, no clock, no
ScenarioInfo. No command gets --bag-params or --mount: the one PointCloud2 topic is the LiDAR,
KISS-ICP gives the poses, and the labelled bag has the contract's layout.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from rosbags.rosbag2 import StoragePlugin, Writer

from advsim_ros.contract import codec, names
from advsim_ros.contract.scenario import cloud_msg
from advsim_ros.contract.spatial import tf_message
from advsim_ros.core.types import Scenario

FRAMES = 80  # 8 s: the 6 s window (10 history + 50 future frames) and some room for curation


def _users_drive(scenario: Scenario, path: Path) -> Path:
    store = codec.typestore()
    with Writer(path, version=Writer.VERSION_LATEST, storage_plugin=StoragePlugin.MCAP) as writer:
        static = writer.add_connection("/tf_static", names.TF_MESSAGE, typestore=store)
        lidar = writer.add_connection("/velodyne_points", names.POINTCLOUD2, typestore=store)
        first = int(scenario.frame_stamps_ns[0])
        sensor = scenario.sweeps[0].frame_id
        writer.write(static, first, codec.encode(tf_message(first, "base_link", sensor, scenario.ego_T_sensor)))
        for sweep in scenario.sweeps[:FRAMES]:
            writer.write(lidar, sweep.stamp_ns + 30_000_000, codec.encode(cloud_msg(sweep)))  # received later
    return path


def _advsim(*arguments: str) -> subprocess.CompletedProcess[str]:
    command = [sys.executable, "-m", "advsim_ros.cli", *arguments]
    return subprocess.run(command, capture_output=True, text=True, timeout=1200, check=False)


@pytest.mark.slow
def test_a_users_unlabelled_drive_goes_from_label_to_a_replayed_finding_with_the_readmes_commands(
    kitti_scenario: Scenario, tmp_path: Path
) -> None:
    drive = _users_drive(kitti_scenario, tmp_path / "my_drive")
    labelled, out = tmp_path / "logs" / "my_drive", tmp_path / "out" / "my_drive"

    steps = [
        ("label", str(drive), "-o", str(labelled)),
        ("curate", str(labelled)),
        ("attack", str(labelled), "--stack", "reference", "--algo", "random", "--queries", "3", "--reruns", "1",
         "--actors", "1", "-o", str(out)),
        ("replay", str(out / "adversarial"), "--stack", "reference", "--check", "--runs", "2", "--no-visuals",
         "-o", str(tmp_path / "r")),
        ("report", str(out)),
    ]  # fmt: skip
    for step in steps:
        done = _advsim(*step)
        assert done.returncode == 0, f"advsim {' '.join(step)}:\n{done.stdout[-2000:]}\n{done.stderr[-3000:]}"
        if step[0] == "label":
            assert "ego poses: kiss-icp" in done.stdout
            assert "LiDAR read from /velodyne_points, its only PointCloud2 topic" in done.stderr

    summary = json.loads((out / "summary.json").read_text())
    assert {query["score"]["status"] for query in summary["queries"]} == {"ok"}
    assert (out / "report.html").is_file()
    # the attack on a window of the 8 s log re-simulated from the window's 60 frames, as on the window's own bag
    assert "keeping 10 of 60 sweeps" in (out / "run" / "logs" / "lidar_resim.log").read_text()
    assert not (tmp_path / "r" / "report.html").exists()  # --no-visuals
    assert not (tmp_path / "r" / "bev.gif").exists()
    losses = json.loads((tmp_path / "r" / "summary.json").read_text())["replay"]["adversarial_losses"]
    assert len(losses) == 2
    assert len(set(losses)) == 1  # and --check's exit 0: the bag's recorded score, run after run
