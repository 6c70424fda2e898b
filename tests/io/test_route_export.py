"""`advsim export route`: the logged ego route of a real log, in the frame a stack's profile plans in.

Read back independently: the CSV with the csv module, the GeoJSON with json and pymap3d, the
Path bag with rosbags' own reader and type store (not this project's bag reader).
"""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pymap3d
import pytest
import yaml
from rosbags.highlevel import AnyReader

from advsim_ros.core.types import Scenario

DATUM = {"latitude": 49.011, "longitude": 8.423, "altitude": 112.0}
START = 20  # a window that does not begin at the log's first frame


def _export(*arguments: str) -> subprocess.CompletedProcess[str]:
    command = [sys.executable, "-m", "advsim_ros.cli", "export", "route", *arguments]
    return subprocess.run(command, capture_output=True, text=True, timeout=300, check=False)


def _profile(folder: Path, **plan: object) -> Path:
    profile = {
        "profile": 1,
        "name": "route_follower",
        "processes": [{"name": "planner", "command": "planner"}],
        "timing": {"mode": "timer"},
        "inputs": {"pose": {"type": "navsatfix", "topic": "/fix", "datum": DATUM}},
        "outputs": {"plan": {"type": "spatial_path", "topic": "/path", **plan}},
    }
    path = folder / "profile.yaml"
    path.write_text(yaml.safe_dump(profile))
    return path


def _csv(path: Path) -> np.ndarray:
    with path.open() as file:
        rows = list(csv.reader(file))
    assert rows[0] == ["x", "y", "yaw", "speed"]
    return np.array(rows[1:], dtype=float)


def test_the_route_from_the_window_on_is_the_logged_drive_in_world_and_in_the_first_fix_frame(
    kitti_bag: Path, kitti_scenario: Scenario, tmp_path: Path
) -> None:
    world_csv = tmp_path / "world.csv"
    done = _export(str(kitti_bag), "-o", str(world_csv), "--window-start", str(START))
    assert done.returncode == 0, done.stderr
    logged = kitti_scenario.ego.xy[START:]
    rows = _csv(world_csv)
    assert rows.shape == (logged.shape[0], 4)
    assert np.max(np.abs(rows[:, :2] - logged)) < 1e-4
    assert np.max(np.abs(np.angle(np.exp(1j * (rows[:, 2] - kitti_scenario.ego.yaws[START:]))))) < 1e-5
    steps = np.hypot(*np.diff(logged, axis=0).T) / (np.diff(kitti_scenario.frame_stamps_ns[START:]) / 1e9)
    assert np.allclose(rows[:-1, 3], steps, atol=1e-3)
    assert f"{logged.shape[0]} poses" in done.stdout

    anchored = tmp_path / "first_fix.csv"
    profile = _profile(tmp_path, frame_id="map", frame_origin="first_fix")
    done = _export(str(kitti_bag), "-o", str(anchored), "--window-start", str(START), "--stack-profile", str(profile))
    assert done.returncode == 0, done.stderr
    rows = _csv(anchored)
    assert np.max(np.abs(rows[:, :2] - (logged - logged[0]))) < 1e-4  # east-north axes from the window's first pose
    assert "frame map" in done.stdout


def test_geojson_is_the_drive_in_longitude_latitude_and_the_path_bag_reads_back_with_rosbags(
    kitti_bag: Path, kitti_scenario: Scenario, tmp_path: Path
) -> None:
    profile = _profile(tmp_path, frame_id="map", frame_origin="first_fix")
    geojson = tmp_path / "route.geojson"
    assert _export(str(kitti_bag), "-o", str(geojson), "--stack-profile", str(profile)).returncode == 0
    (feature,) = json.loads(geojson.read_text())["features"]
    longitude, latitude = np.array(feature["geometry"]["coordinates"]).T
    east, north, _ = pymap3d.geodetic2enu(
        latitude, longitude, 0.0, DATUM["latitude"], DATUM["longitude"], DATUM["altitude"]
    )
    assert np.max(np.hypot(east - kitti_scenario.ego.xy[:, 0], north - kitti_scenario.ego.xy[:, 1])) < 0.01

    bag = tmp_path / "route_bag"
    assert _export(str(kitti_bag), "-o", str(bag), "--window-start", str(START)).returncode == 0
    with AnyReader([bag]) as reader:
        (connection,) = reader.connections
        assert (connection.topic, connection.msgtype) == ("/route", "nav_msgs/msg/Path")
        ((_, stamp, raw),) = list(reader.messages())
        path = reader.deserialize(raw, connection.msgtype)
    assert stamp == kitti_scenario.frame_stamps_ns[START]
    xy = np.array([[pose.pose.position.x, pose.pose.position.y] for pose in path.poses])
    assert np.max(np.abs(xy - kitti_scenario.ego.xy[START:])) < 1e-9
    times = [pose.header.stamp.sec * 10**9 + pose.header.stamp.nanosec for pose in path.poses]
    assert times == kitti_scenario.frame_stamps_ns[START:].tolist()


@pytest.mark.parametrize(
    ("arguments", "message"),
    [
        (["--window-start", "100000"], "--window-start 100000: the log has frames 0..153"),
        (["-o", "{tmp}/exists.csv"], "exists (pass --overwrite to replace it)"),
        (["-o", "{tmp}/route.geojson"], "GeoJSON needs the world frame's datum"),
    ],
)
def test_bad_requests_are_one_line_and_write_nothing(
    kitti_bag: Path, tmp_path: Path, arguments: list[str], message: str
) -> None:
    (tmp_path / "exists.csv").write_text("kept\n")
    arguments = [argument.replace("{tmp}", str(tmp_path)) for argument in arguments]
    output = ["-o", str(tmp_path / "new.csv")] if "-o" not in arguments else []
    done = _export(str(kitti_bag), *output, *arguments)
    assert done.returncode != 0
    assert message in done.stderr
    assert "Traceback" not in done.stderr
    assert sorted(path.name for path in tmp_path.iterdir()) == ["exists.csv"]
    assert (tmp_path / "exists.csv").read_text() == "kept\n"
