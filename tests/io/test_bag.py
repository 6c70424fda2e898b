"""Scenario bags: the KITTI acceptance check with the independent mcap reader, lossless round trips,
users' own bags, and bad input that must fail clearly without leaving partial output."""

from __future__ import annotations

import shutil
from collections import defaultdict
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from advsim_ros.contract.pointcloud import PointCloudError
from advsim_ros.core.params import ParamsError
from advsim_ros.core.types import ActorClass, ActorTrack, EgoTrajectory, Scenario, Sweep
from advsim_ros.io.av2 import load_av2_log
from advsim_ros.io.bag import (
    BagConfig,
    BagError,
    iter_bag_sweeps,
    load_bag_config,
    read_scenario_bag,
    summarize_bag,
    write_scenario_bag,
)
from advsim_ros.io.kitti import kitti_velodyne_dir

REPO = Path(__file__).resolve().parents[2]
STORE = get_typestore(Stores.ROS2_JAZZY)
T = STORE.types
Box = tuple[np.ndarray, float, np.ndarray]


# --------------------------------------------------------------------------- acceptance: KITTI 0000 as MCAP


def _quaternion_matrix(q: Any) -> np.ndarray:
    """Rotation matrix of a geometry_msgs/Quaternion (written out here, independent of the code under test)."""
    x, y, z, w = q.x, q.y, q.z, q.w
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def _transform(translation: Any, rotation: Any) -> np.ndarray:
    matrix = np.eye(4)
    matrix[:3, :3] = _quaternion_matrix(rotation)
    matrix[:3, 3] = [translation.x, translation.y, translation.z]
    return matrix


def _xyz(cloud: Any) -> np.ndarray:
    offsets = {field.name: field.offset for field in cloud.fields}
    assert all(field.datatype == 7 for field in cloud.fields if field.name in "xyz")  # FLOAT32
    raw = np.frombuffer(bytes(cloud.data), dtype=np.uint8).reshape(-1, cloud.point_step)
    return np.stack([raw[:, offsets[a] : offsets[a] + 4].copy().view("<f4")[:, 0] for a in "xyz"], axis=-1)


def test_kitti_0000_bag_decodes_with_the_mcap_reader_and_its_boxes_hold_the_points(
    kitti_bag: Path,
    kitti_root: Path,
    points_in_boxes: Callable[[np.ndarray, list[Box]], list[int]],
) -> None:
    (mcap_file,) = kitti_bag.glob("*.mcap")
    clouds: dict[int, np.ndarray] = {}
    ego_poses: dict[int, np.ndarray] = {}
    boxes: dict[int, list[Box]] = defaultdict(list)
    ego_T_sensor = None
    with mcap_file.open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        for _, channel, _, msg in reader.iter_decoded_messages():
            if channel.topic == "/sensor/lidar/points":
                assert msg.header.frame_id == "velodyne"
                clouds[msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec] = _xyz(msg)
            elif channel.topic == "/ego/odom":
                stamp = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
                ego_poses[stamp] = _transform(msg.pose.pose.position, msg.pose.pose.orientation)
            elif channel.topic == "/tf_static":
                (static,) = msg.transforms
                assert (static.header.frame_id, static.child_frame_id) == ("base_link", "velodyne")
                ego_T_sensor = _transform(static.transform.translation, static.transform.rotation)
            elif channel.topic == "/actors/tracks":
                for track in msg.tracks:
                    (state,) = track.states
                    stamp = state.stamp.sec * 10**9 + state.stamp.nanosec
                    size = np.array([track.length, track.width, track.height])
                    boxes[stamp].append((np.array([state.x, state.y, state.z]), state.yaw, size))
    assert ego_T_sensor is not None
    assert len(clouds) == 154
    original = [path.stat().st_size // 16 for path in sorted(kitti_velodyne_dir(kitti_root, "0000").glob("*.bin"))]
    assert [len(clouds[stamp]) for stamp in sorted(clouds)] == original
    counts = []
    for stamp, points in clouds.items():
        world_T_sensor = ego_poses[stamp] @ ego_T_sensor
        world = np.einsum("ij,nj->ni", world_T_sensor[:3, :3], points.astype(np.float64)) + world_T_sensor[:3, 3]
        counts += points_in_boxes(world, boxes[stamp])
    assert len(counts) == 711
    assert sum(count == 0 for count in counts) <= 1
    assert abs(np.mean(counts) - 683) < 10


def test_kitti_0000_round_trips_through_the_bag_losslessly(
    kitti_bag: Path, kitti_scenario: Scenario, scenarios_equal: Callable[[Scenario, Scenario], None]
) -> None:
    scenarios_equal(read_scenario_bag(kitti_bag), kitti_scenario)


def test_reading_without_sweeps_keeps_everything_else(kitti_bag: Path, kitti_scenario: Scenario) -> None:
    scenario = read_scenario_bag(kitti_bag, load_sweeps=False)
    assert scenario.sweeps == ()
    assert len(scenario.actors) == len(kitti_scenario.actors)
    np.testing.assert_allclose(scenario.ego.poses, kitti_scenario.ego.poses, atol=1e-9)


def test_the_bag_summary_lists_topics_counts_and_the_time_span(kitti_bag: Path) -> None:
    summary = summarize_bag(kitti_bag)
    assert summary.storage == "mcap"
    assert summary.topics["/sensor/lidar/points"].message_count == 154
    assert summary.topics["/actors/tracks"].msgtype == "advsim_msgs/msg/ActorTrackArray"
    assert summary.topics["/scenario/info"].message_count == 1
    assert summary.end_ns - summary.start_ns == 153 * 100_000_000 + 1
    assert summary.size_bytes > 287_000_000  # the float32 points alone take 287 MB


def test_sweeps_stream_one_at_a_time_in_order(kitti_bag: Path) -> None:
    stamps = [stamp for stamp, frame_id, _ in iter_bag_sweeps(kitti_bag) if frame_id == "velodyne"]
    assert len(stamps) == 154
    assert stamps == sorted(stamps)


# --------------------------------------------------------------------------- round trips: AV2 and sqlite3


def test_every_av2_log_round_trips_through_the_bag_losslessly(
    av2_logs: list[Path], tmp_path: Path, scenarios_equal: Callable[[Scenario, Scenario], None]
) -> None:
    for log in av2_logs:
        scenario = load_av2_log(log)
        bag = write_scenario_bag(scenario, tmp_path / log.name, source=f"av2/{log.name}")
        scenarios_equal(read_scenario_bag(bag), scenario)


def test_sqlite3_storage_is_read_like_mcap(
    av2_logs: list[Path], tmp_path: Path, scenarios_equal: Callable[[Scenario, Scenario], None]
) -> None:
    scenario = load_av2_log(next(log for log in av2_logs if (log / "sensors").is_dir()))
    bag = write_scenario_bag(scenario, tmp_path / "sqlite", config=BagConfig(storage="sqlite3"))
    assert [path.suffix for path in bag.iterdir() if path.name != "metadata.yaml"] == [".db3"]
    scenarios_equal(read_scenario_bag(bag), scenario)


def _small_scenario(num_frames: int = 5, frame_id: str = "lidar") -> Scenario:
    stamps = 1_000_000_000 + 100_000_000 * np.arange(num_frames, dtype=np.int64)
    poses = np.tile(np.eye(4), (num_frames, 1, 1))
    poses[:, 0, 3] = np.arange(num_frames) * 1.5
    yaw = np.linspace(0.0, 0.4, num_frames)
    poses[:, 0, 0], poses[:, 0, 1], poses[:, 1, 0], poses[:, 1, 1] = np.cos(yaw), -np.sin(yaw), np.sin(yaw), np.cos(yaw)
    ego_T_sensor = np.eye(4)
    ego_T_sensor[:3, 3] = [1.2, 0.0, 1.8]
    rng = np.random.default_rng(1)
    points = np.zeros(40, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "u1"), ("ring", "<u2")])
    for name in ("x", "y", "z"):
        points[name] = rng.uniform(-20, 20, 40)
    points["ring"] = np.arange(40) % 32
    car = ActorTrack(
        actor_id="car",
        actor_class=ActorClass.VEHICLE,
        size=np.array([4.2, 1.8, 1.5]),
        stamps_ns=stamps[1:4],
        centers=np.array([[10.0, 3.0, 0.7], [11.0, 3.1, 0.7], [12.0, 3.3, 0.7]]),
        yaws=np.array([0.0, 0.1, 0.2]),
    )
    sweeps = tuple(
        Sweep(stamp_ns=int(stamps[i]), frame_id=frame_id, points=points, sensor_pose=poses[i] @ ego_T_sensor)
        for i in (0, 2, 4)
    )
    return Scenario(
        scenario_id="small",
        frame_stamps_ns=stamps,
        ego=EgoTrajectory(stamps_ns=stamps, poses=poses),
        actors=(car,),
        sweeps=sweeps,
        ego_T_sensor=ego_T_sensor,
    )


def test_custom_topic_names_and_frames_from_the_config_are_used_both_ways(
    tmp_path: Path, scenarios_equal: Callable[[Scenario, Scenario], None]
) -> None:
    config = BagConfig(lidar_topic="/velodyne_points", odom_topic="/odom", world_frame="map", ego_frame="base")
    bag = write_scenario_bag(_small_scenario(), tmp_path / "custom", config=config)
    assert set(summarize_bag(bag).topics) >= {"/velodyne_points", "/odom"}
    scenarios_equal(read_scenario_bag(bag, config=config), _small_scenario())


# --------------------------------------------------------------------------- users' own bags


@pytest.mark.parametrize("source", ["odom", "tf"])
def test_a_users_bag_gives_sweeps_with_all_fields_and_interpolated_ego_poses(
    tmp_path: Path, user_bags: Any, user_bag_config: BagConfig, source: str
) -> None:
    bag = user_bags.write(tmp_path / "user", user_bags.messages())
    config = BagConfig(**{**user_bag_config.__dict__, "ego_pose_source": source})
    scenario = read_scenario_bag(bag, config=config)
    expected_stamps = [10**9 + 100_000_000 * i for i in range(4)]
    np.testing.assert_array_equal(scenario.frame_stamps_ns, expected_stamps)  # header stamps, not log times
    assert scenario.sweeps[0].points.dtype == user_bags.points(1).dtype  # ring and time survive, padding too
    np.testing.assert_array_equal(scenario.sweeps[2].points["ring"], np.arange(25) % 64)
    for index, stamp in enumerate(expected_stamps):
        # Poses at 50 Hz are offset by 10 ms from the sweeps: interpolation must hit the motion exactly.
        np.testing.assert_allclose(scenario.ego.poses[index], user_bags.ego_pose(stamp), atol=1e-6)
    np.testing.assert_allclose(scenario.ego_T_sensor[:3, 3], [0.5, 0.0, 1.9], atol=1e-12)
    np.testing.assert_allclose(scenario.ego_T_sensor[:3, 0], [0.0, 1.0, 0.0], atol=1e-12)
    assert scenario.actors == ()
    assert scenario.road_map is None


def test_a_users_bag_with_message_types_of_its_own_is_read(
    tmp_path: Path, user_bags: Any, user_bag_config: BagConfig
) -> None:
    store = get_typestore(Stores.ROS2_JAZZY)
    store.register(get_types_from_msg("string mode\nfloat64 confidence", "my_stack/msg/Status"))
    bag = tmp_path / "user"
    with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        status = writer.add_connection("/my_stack/status", "my_stack/msg/Status", typestore=store)
        message = store.types["my_stack/msg/Status"](mode="auto", confidence=0.9)
        writer.write(status, 10**9, store.serialize_cdr(message, "my_stack/msg/Status"))
        connections: dict[str, Any] = {}
        for topic, msgtype, stamp, item in sorted(user_bags.messages(), key=lambda entry: entry[2]):
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msgtype, typestore=store)
            writer.write(connections[topic], stamp, store.serialize_cdr(item, msgtype))
    assert "/my_stack/status" in summarize_bag(bag).topics
    assert len(read_scenario_bag(bag, config=user_bag_config).sweeps) == 4


def test_a_users_sqlite3_bag_is_read(tmp_path: Path, user_bags: Any, user_bag_config: BagConfig) -> None:
    bag = user_bags.write(tmp_path / "user", user_bags.messages(), storage=StoragePlugin.SQLITE3)
    assert len(read_scenario_bag(bag, config=user_bag_config).sweeps) == 4


# --------------------------------------------------------------------------- bad input


def test_a_bag_without_the_lidar_topic_is_rejected_naming_the_topic(
    tmp_path: Path, user_bags: Any, user_bag_config: BagConfig
) -> None:
    bag = user_bags.write(tmp_path / "user", user_bags.messages(lidar_topic="/points_raw"))
    with pytest.raises(BagError, match=r"has no LiDAR \(sensor_msgs/msg/PointCloud2\) topic /velodyne_points"):
        read_scenario_bag(bag, config=user_bag_config)


def test_a_pointcloud2_without_x_is_rejected(tmp_path: Path, user_bags: Any, user_bag_config: BagConfig) -> None:
    bag = user_bags.write(tmp_path / "user", user_bags.messages(drop_field="x"))
    with pytest.raises(BagError, match=r"/velodyne_points.*PointCloud2 without x field"):
        read_scenario_bag(bag, config=user_bag_config)


def test_a_nan_ego_pose_is_rejected(tmp_path: Path, user_bags: Any, user_bag_config: BagConfig) -> None:
    bag = user_bags.write(tmp_path / "user", user_bags.messages(nan_at=7))
    with pytest.raises(BagError, match=r"/odom at 1090000000 ns: pose contains NaN"):
        read_scenario_bag(bag, config=user_bag_config)


def test_ego_frames_that_do_not_match_the_config_are_rejected(
    tmp_path: Path, user_bags: Any, user_bag_config: BagConfig
) -> None:
    bag = user_bags.write(tmp_path / "user", user_bags.messages())
    with pytest.raises(BagError, match=r"gives 'base_link' in 'odom', but world_frame/ego_frame are 'world'"):
        read_scenario_bag(bag, config=BagConfig(lidar_topic="/velodyne_points", odom_topic="/odom"))


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_a_truncated_bag_is_rejected(tmp_path: Path, storage: str) -> None:
    bag = write_scenario_bag(_small_scenario(), tmp_path / "bag", config=BagConfig(storage=storage))
    (data,) = [path for path in bag.iterdir() if path.suffix in (".mcap", ".db3")]
    data.write_bytes(data.read_bytes()[: data.stat().st_size * 2 // 3])
    with pytest.raises(BagError, match="truncated or corrupt"):
        read_scenario_bag(bag)


def test_a_bag_holding_fewer_messages_than_its_metadata_lists_is_rejected(tmp_path: Path) -> None:
    bag = write_scenario_bag(_small_scenario(), tmp_path / "bag")
    metadata = yaml.safe_load((bag / "metadata.yaml").read_text())
    for topic in metadata["rosbag2_bagfile_information"]["topics_with_message_count"]:
        if topic["topic_metadata"]["name"] == "/sensor/lidar/points":
            topic["message_count"] = 5
    (bag / "metadata.yaml").write_text(yaml.safe_dump(metadata))
    with pytest.raises(BagError, match="is truncated: metadata lists 5 messages on /sensor/lidar/points"):
        read_scenario_bag(bag)


def test_a_folder_without_metadata_is_rejected(tmp_path: Path) -> None:
    (tmp_path / "notabag").mkdir()
    with pytest.raises(BagError, match=r"has no metadata\.yaml"):
        read_scenario_bag(tmp_path / "notabag")
    with pytest.raises(BagError, match="bag not found"):
        read_scenario_bag(tmp_path / "missing")


def test_writing_over_an_existing_path_needs_overwrite(tmp_path: Path) -> None:
    target = tmp_path / "bag"
    target.mkdir()
    (target / "keep.txt").write_text("mine")
    with pytest.raises(BagError, match="exists already"):
        write_scenario_bag(_small_scenario(), target)
    assert (target / "keep.txt").read_text() == "mine"
    write_scenario_bag(_small_scenario(), target, overwrite=True)
    assert (target / "metadata.yaml").is_file()
    assert not (target / "keep.txt").exists()
    assert sorted(path.name for path in tmp_path.iterdir()) == ["bag"]


def test_a_failure_while_writing_leaves_no_partial_bag(tmp_path: Path) -> None:
    scenario = _small_scenario()
    half = np.zeros(10, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f2")])  # float16 has no PointField datatype
    broken_sweep = Sweep(scenario.sweeps[2].stamp_ns, "lidar", half, scenario.sweeps[2].sensor_pose)
    broken = Scenario(
        scenario_id="broken",
        frame_stamps_ns=scenario.frame_stamps_ns,
        ego=scenario.ego,
        actors=scenario.actors,
        sweeps=(scenario.sweeps[0], scenario.sweeps[1], broken_sweep),
        ego_T_sensor=scenario.ego_T_sensor,
    )
    with pytest.raises(PointCloudError, match="field 'z': dtype float16"):
        write_scenario_bag(broken, tmp_path / "bag")
    assert list(tmp_path.iterdir()) == []


def test_a_sweep_pose_the_bag_cannot_carry_is_refused(tmp_path: Path) -> None:
    scenario = _small_scenario()
    moved = scenario.sweeps[1].sensor_pose.copy()
    moved[0, 3] += 0.3
    sweeps = (scenario.sweeps[0], Sweep(scenario.sweeps[1].stamp_ns, "lidar", scenario.sweeps[1].points, moved))
    odd = Scenario("odd", scenario.frame_stamps_ns, scenario.ego, (), sweeps, scenario.ego_T_sensor)
    with pytest.raises(BagError, match=r"differs from ego pose @ ego_T_sensor by 0\.3"):
        write_scenario_bag(odd, tmp_path / "bag")
    assert list(tmp_path.iterdir()) == []


# --------------------------------------------------------------------------- parameters


def test_params_bag_yaml_holds_the_defaults() -> None:
    assert load_bag_config(REPO / "params" / "bag.yaml") == BagConfig()


def test_a_bad_bag_parameter_is_named(tmp_path: Path) -> None:
    params = yaml.safe_load((REPO / "params" / "bag.yaml").read_text())
    params["/**"]["ros__parameters"]["bag"]["ego_pose_source"] = "gps"
    path = tmp_path / "bag.yaml"
    path.write_text(yaml.safe_dump(params))
    with pytest.raises(ParamsError, match="ego_pose_source: must be 'odom' or 'tf', got 'gps'"):
        load_bag_config(path)
    params["/**"]["ros__parameters"]["bag"]["lidar_topc"] = "/x"
    path.write_text(yaml.safe_dump(params))
    with pytest.raises(ParamsError, match=r"unknown parameter\(s\) \['lidar_topc'\]"):
        load_bag_config(path)


def test_the_mcap_file_sits_in_a_rosbag2_folder_as_ros2_bag_makes_it(tmp_path: Path) -> None:
    bag = write_scenario_bag(_small_scenario(), tmp_path / "demo")
    metadata = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert metadata["storage_identifier"] == "mcap"
    assert metadata["relative_file_paths"] == ["demo.mcap"]
    qos = {
        topic["topic_metadata"]["name"]: topic["topic_metadata"]["offered_qos_profiles"]
        for topic in metadata["topics_with_message_count"]
    }
    assert qos["/scenario/info"][0]["durability"] == "transient_local"
    assert qos["/sensor/lidar/points"][0]["durability"] == "volatile"
    # offered reliable, as lidar_resim publishes it: matches sensor-data (best-effort) subscribers and reliable ones
    assert qos["/sensor/lidar/points"][0]["reliability"] == "reliable"
    shutil.rmtree(bag)
