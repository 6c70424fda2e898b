"""Fixtures every test shares: the real driving data beside the repository, loaded once per session.

Tests that need the data skip with a message naming the missing folder when it is absent.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from advsim_ros.core.types import Scenario
from advsim_ros.io.bag import BagConfig
from advsim_ros.io.kitti import load_kitti_tracking

SHARED_DATA = Path(__file__).resolve().parent / "../shared/data"


def _imported_after(code: str, modules: tuple[str, ...]) -> list[str]:
    """Which of ``modules`` a fresh interpreter has imported after running ``code``."""
    probe = f"{code}\nimport sys\nprint(','.join(sorted(m for m in {modules!r} if m in sys.modules)))\n"
    result = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True)
    return [name for name in result.stdout.strip().split(",") if name]


@pytest.fixture(scope="session")
def imported_after() -> Callable[[str, tuple[str, ...]], list[str]]:
    """Run code in a fresh interpreter; the listed modules it imported (import costs of a command)."""
    return _imported_after


@pytest.fixture(scope="session")
def shared_data() -> Path:
    if not SHARED_DATA.is_dir():
        pytest.skip(f"real driving data not found at {SHARED_DATA.resolve()} (see README, 'Data')")
    return SHARED_DATA.resolve()


@pytest.fixture(scope="session")
def kitti_root(shared_data: Path) -> Path:
    root = shared_data / "kitti_tracking_0000"
    if not root.is_dir():
        pytest.skip(f"KITTI tracking 0000 not found at {root}")
    return root


@pytest.fixture(scope="session")
def av2_logs(shared_data: Path) -> list[Path]:
    logs = sorted(path for path in (shared_data / "av2").glob("*-*-*-*-*") if path.is_dir())
    if not logs:
        pytest.skip(f"Argoverse 2 logs not found under {shared_data / 'av2'}")
    return logs


@pytest.fixture(scope="session")
def kitti_scenario(kitti_root: Path) -> Scenario:
    """KITTI tracking 0000 (the first run unpacks the Velodyne archive into the cache, ~15 s)."""
    return load_kitti_tracking(kitti_root, "0000")


class RecordedYourWay:
    """A scenario written as a user's recorder writes a drive, in a layout of its own: the LiDAR on
    /velodyne_points in frame `velodyne` (log times 30 ms after the stamps), odometry on /vehicle/odom from
    `odom` to `base_footprint`, tracks on /perception/tracks in `odom`, the mount on /tf_static; no /clock,
    no /tf, no ScenarioInfo. ``params`` writes the --bag-params file that describes it."""

    layout = BagConfig(
        lidar_topic="/velodyne_points",
        odom_topic="/vehicle/odom",
        tracks_topic="/perception/tracks",
        world_frame="odom",
        ego_frame="base_footprint",
    )
    params_text = (
        "/**:\n  ros__parameters:\n    bag:\n      lidar_topic: /velodyne_points\n      odom_topic: /vehicle/odom\n"
        "      tracks_topic: /perception/tracks\n      world_frame: odom\n      ego_frame: base_footprint\n"
    )

    def params(self, path: Path) -> Path:
        path.write_text(self.params_text, encoding="utf-8")
        return path

    def write(self, scenario: Scenario, path: Path) -> Path:
        from rosbags.rosbag2 import StoragePlugin, Writer

        from advsim_ros.contract import codec, names
        from advsim_ros.contract.scenario import cloud_msg
        from advsim_ros.contract.spatial import odometry_msgs, tf_message
        from advsim_ros.contract.tracks import TrackRecord, track_array_msg

        layout, store = self.layout, codec.typestore()
        per_frame: dict[int, list[TrackRecord]] = {int(stamp): [] for stamp in scenario.frame_stamps_ns}
        for actor in scenario.actors:
            record = TrackRecord.from_actor_track(actor)
            for index, stamp in enumerate(actor.stamps_ns.tolist()):
                per_frame[stamp].append(record.state(index))
        odometry = odometry_msgs(scenario.ego, layout.world_frame, layout.ego_frame)
        with Writer(path, version=Writer.VERSION_LATEST, storage_plugin=StoragePlugin.MCAP) as writer:
            static = writer.add_connection("/tf_static", names.TF_MESSAGE, typestore=store)
            odom = writer.add_connection(layout.odom_topic, names.ODOMETRY, typestore=store)
            tracks = writer.add_connection(layout.tracks_topic, names.ACTOR_TRACK_ARRAY, typestore=store)
            lidar = writer.add_connection(layout.lidar_topic, names.POINTCLOUD2, typestore=store)
            first = int(scenario.frame_stamps_ns[0])
            mount = tf_message(first, layout.ego_frame, "velodyne", scenario.ego_T_sensor)
            writer.write(static, first, codec.encode(mount))
            for index, stamp in enumerate(scenario.frame_stamps_ns.tolist()):
                writer.write(odom, stamp, codec.encode(odometry[index]))
                arrays = track_array_msg(per_frame[stamp], stamp, layout.world_frame)
                writer.write(tracks, stamp, codec.encode(arrays))
            for sweep in scenario.sweeps:
                cloud = cloud_msg(dataclasses.replace(sweep, frame_id="velodyne"))
                writer.write(lidar, sweep.stamp_ns + 30_000_000, codec.encode(cloud))
        return path


@pytest.fixture(scope="session")
def recorded_your_way() -> RecordedYourWay:
    """Writes scenarios as a user records drives, in a layout of its own (see RecordedYourWay)."""
    return RecordedYourWay()


@pytest.fixture(scope="session")
def s3_server() -> Iterator[dict[str, str]]:
    """An S3-compatible server (moto's) on a free loopback port, for as long as the session runs: the environment
    that points a process's S3 clients at it (endpoint, dummy credentials), also set in this process."""
    from moto.server import ThreadedMotoServer

    logging.getLogger("werkzeug").setLevel(logging.ERROR)  # one line per request otherwise
    server = ThreadedMotoServer(ip_address="127.0.0.1", port=0, verbose=False)
    server.start()
    host, port = server.get_host_and_port()
    environment = {
        "AWS_ENDPOINT_URL": f"http://{host}:{port}",
        "AWS_ACCESS_KEY_ID": "testing",
        "AWS_SECRET_ACCESS_KEY": "testing",
        "AWS_DEFAULT_REGION": "us-east-1",
    }
    before = {name: os.environ.get(name) for name in environment}
    os.environ.update(environment)
    try:
        yield environment
    finally:
        for name, value in before.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value
        server.stop()


@pytest.fixture
def s3_bucket(s3_server: dict[str, str], request: pytest.FixtureRequest) -> str:
    """A fresh bucket on the test's S3 server: its s3:// URI."""
    import fsspec

    name = "t-" + "".join(c if c.isalnum() else "-" for c in request.node.name.lower())[:50].strip("-")
    fs = fsspec.filesystem("s3", skip_instance_cache=True)
    if not fs.exists(name):
        fs.mkdir(name)
    return f"s3://{name}"
