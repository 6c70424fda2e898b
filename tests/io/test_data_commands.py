"""`advsim convert` and `advsim curate`: exit codes, messages, and no partial output on bad input."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from advsim_ros.cli import main
from advsim_ros.io.bag import read_scenario_bag


def _av2_log_with_lidar(av2_logs: list[Path]) -> Path:
    return next(log for log in av2_logs if (log / "sensors").is_dir())


def test_convert_av2_writes_a_bag_and_reports_it(
    av2_logs: list[Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    log = _av2_log_with_lidar(av2_logs)
    assert main(["convert", "av2", str(log), "-o", str(tmp_path / "out")]) == 0
    assert f"wrote {tmp_path / 'out'}: av2_{log.name}" in capsys.readouterr().out
    scenario = read_scenario_bag(tmp_path / "out")
    assert scenario.road_map is not None
    assert len(scenario.sweeps) >= 1


def test_convert_refuses_to_overwrite_unless_asked(
    av2_logs: list[Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    log = av2_logs[0]
    (tmp_path / "out").mkdir()
    assert main(["convert", "av2", str(log), "-o", str(tmp_path / "out")]) == 1
    assert "exists already" in capsys.readouterr().err
    assert main(["convert", "av2", str(log), "-o", str(tmp_path / "out"), "--overwrite"]) == 0
    assert (tmp_path / "out" / "metadata.yaml").is_file()


def test_convert_kitti_with_a_label_file_that_does_not_match_fails_without_output(
    kitti_root: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    root = tmp_path / "kitti"
    root.mkdir()
    for name in ("calib", "poses"):
        shutil.copytree(kitti_root / name, root / name)
    (root / "label_02").mkdir()
    labels = (kitti_root / "label_02" / "0000.txt").read_text()
    (root / "label_02" / "0000.txt").write_text(labels + "200 3 Car 0 0 0 1 1 2 2 1.5 1.6 3.9 1.0 1.6 20.0 0.1\n")
    (root / "velodyne.tar.xz").symlink_to(kitti_root / "velodyne.tar.xz")  # same archive, same cache entry
    code = main(["convert", "kitti", str(root), "--seq", "0000", "-o", str(tmp_path / "out")])
    assert code == 1
    assert "does not match the sweeps: it labels frame 200 but sequence 0000 has only 154" in capsys.readouterr().err
    assert sorted(path.name for path in tmp_path.iterdir()) == ["kitti"]


def test_convert_kitti_with_nan_poses_fails_naming_the_line(
    kitti_root: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    poses = tmp_path / "0000_bad_velo.txt"
    rows = (kitti_root / "poses" / "0000_kissicp_velo.txt").read_text().splitlines()
    rows[10] = " ".join(["nan"] * 12)
    poses.write_text("\n".join(rows) + "\n")
    code = main(["convert", "kitti", str(kitti_root), "--poses", str(poses), "-o", str(tmp_path / "out")])
    assert code == 1
    assert "0000_bad_velo.txt line 11: pose contains NaN" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_curate_lists_windows_and_writes_the_best_one(
    kitti_bag: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["curate", str(kitti_bag), "--json", "-o", str(tmp_path / "best")]) == 0
    report = json.loads(capsys.readouterr().out)
    assert [window["start_frame"] for window in report["windows"]] == [0, 20, 40, 60, 80]
    rates = [window["collision_rate"] for window in report["windows"]]
    assert all(0.0 <= rate <= 1.0 for rate in rates)
    best = report["windows"][[w["start_frame"] for w in report["windows"]].index(report["best_start_frame"])]
    assert best["collision_rate"] == max(rates)
    cropped = read_scenario_bag(tmp_path / "best")
    assert cropped.num_frames == 60
    assert len(cropped.sweeps) == 60
    assert cropped.frame_stamps_ns[0] == best["start_ns"]
    assert np.all(np.diff(cropped.frame_stamps_ns) == 100_000_000)


def test_curate_prints_a_table_marking_the_best_window(kitti_bag: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["curate", str(kitti_bag)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == "kitti_tracking_0000: 5 windows"
    assert sum("<- best" in line for line in lines) == 1


def test_curate_a_truncated_bag_fails_clearly(
    av2_logs: list[Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["convert", "av2", str(av2_logs[0]), "-o", str(tmp_path / "bag")]) == 0
    (mcap,) = (tmp_path / "bag").glob("*.mcap")
    mcap.write_bytes(mcap.read_bytes()[:100_000])
    capsys.readouterr()
    assert main(["curate", str(tmp_path / "bag"), "-o", str(tmp_path / "best")]) == 1
    assert "truncated or corrupt" in capsys.readouterr().err
    assert not (tmp_path / "best").exists()


def test_curate_a_bag_without_the_lidar_topic_fails_naming_it(
    av2_logs: list[Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["convert", "av2", str(av2_logs[0]), "-o", str(tmp_path / "bag")]) == 0
    params = tmp_path / "bag.yaml"
    params.write_text("/**:\n  ros__parameters:\n    bag:\n      lidar_topic: /points_raw\n")
    capsys.readouterr()
    assert main(["curate", str(tmp_path / "bag"), "--bag-params", str(params)]) == 1
    assert "has no LiDAR (sensor_msgs/msg/PointCloud2) topic /points_raw" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("problem", "message"),
    [
        ({"drop_field": "x"}, "LiDAR topic /velodyne_points at 1003000000 ns: PointCloud2 without x field(s)"),
        ({"nan_at": 3}, "/odom at 1010000000 ns: pose contains NaN or infinite values"),
        ({"lidar_topic": "/points_raw"}, "has no LiDAR (sensor_msgs/msg/PointCloud2) topic /velodyne_points"),
    ],
)
def test_curate_on_a_bad_user_bag_exits_non_zero_with_the_problem_and_writes_nothing(
    tmp_path: Path,
    user_bags: Any,
    capsys: pytest.CaptureFixture[str],
    problem: dict[str, Any],
    message: str,
) -> None:
    bag = user_bags.write(tmp_path / "user", user_bags.messages(**problem))
    params = tmp_path / "bag.yaml"
    params.write_text(
        "/**:\n  ros__parameters:\n    bag:\n      lidar_topic: /velodyne_points\n      odom_topic: /odom\n"
        "      world_frame: odom\n"
    )
    code = main(["curate", str(bag), "--bag-params", str(params), "-o", str(tmp_path / "best")])
    assert code == 1
    assert message in capsys.readouterr().err
    assert not (tmp_path / "best").exists()
