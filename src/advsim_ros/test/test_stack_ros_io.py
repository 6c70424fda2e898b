"""The reference stacks' message side: odometry lookup, plans and tracks as messages, maps and mounts from messages."""

import numpy as np
from geometry_msgs.msg import TransformStamped
from nav_msgs.msg import Odometry
from tf2_msgs.msg import TFMessage

from advsim_msgs.msg import Polyline, RoadMap
from advsim_ros.contract import codec, names
from advsim_ros.contract.codec import stamp_ns
from advsim_ros.contract.scenario import road_map_from_msg
from advsim_ros.contract.spatial import transforms_of
from advsim_ros.core.types import ActorClass, Plan
from advsim_ros.stacks.interface import ObjectTrajectories, StackOutput
from advsim_ros.stacks.ros_io import PoseBuffer, output_messages

STEP = 100_000_000


def _odometry(stamp: int, x: float, twist_speed: float = 0.0) -> Odometry:
    message = Odometry()
    message.header.stamp.sec, message.header.stamp.nanosec = divmod(stamp, 1_000_000_000)
    message.header.frame_id = "map"
    message.child_frame_id = "base_link"
    message.pose.pose.position.x = x
    message.pose.pose.orientation.w = 1.0
    message.twist.twist.linear.x = twist_speed
    return message


def test_a_sweep_gets_the_odometry_pose_of_its_stamp_and_the_speed_from_the_poses_before_it() -> None:
    buffer = PoseBuffer(capacity=10)
    assert buffer.lookup(STEP, tolerance_ns=0) is None
    buffer.add_odometry(_odometry(10 * STEP, 0.0, twist_speed=3.0))
    pose, motion = buffer.lookup(10 * STEP, tolerance_ns=0)
    assert motion.speed == 3.0  # one pose: the twist is all there is
    for index in range(11, 14):
        buffer.add_odometry(_odometry(index * STEP, 0.5 * (index - 10)))
    assert buffer.world_frame == "map"
    assert buffer.ego_frame == "base_link"
    pose, motion = buffer.lookup(12 * STEP + 10_000_000, tolerance_ns=20_000_000)
    assert pose[0, 3] == 1.0  # the nearest odometry, at 1.2 s
    assert abs(motion.speed - 5.0) < 1e-9  # 0.5 m per 0.1 s, from poses up to that stamp only
    assert buffer.lookup(20 * STEP, tolerance_ns=20_000_000) is None
    buffer.add_odometry(_odometry(5 * STEP, 9.0))  # time went back (a new drive): newer poses are forgotten
    assert buffer.newest_ns == 5 * STEP


def test_a_plan_becomes_a_path_stamped_at_the_sweep_with_every_pose_at_its_own_time() -> None:
    stamps = 3 * 10**9 + STEP * np.arange(1, 51)
    plan = Plan(stamps_ns=stamps, xy=np.column_stack([np.arange(50.0), np.zeros(50)]), yaws=np.full(50, np.pi / 2))
    plan_cdr, detections, predictions = output_messages(StackOutput(plan=plan, plan_z=1.5), 3 * 10**9, "map")
    assert detections is None  # the stack made none
    assert predictions is None
    message = codec.decode(plan_cdr, names.PATH)
    assert stamp_ns(message.header.stamp) == 3 * 10**9
    assert message.header.frame_id == "map"
    assert [stamp_ns(pose.header.stamp) for pose in message.poses] == stamps.tolist()
    last = message.poses[-1].pose
    assert (last.position.x, last.position.z) == (49.0, 1.5)
    assert np.isclose(last.orientation.z, np.sin(np.pi / 4))
    assert np.isclose(last.orientation.w, np.cos(np.pi / 4))


def test_predictions_become_tracks_with_one_state_per_future_stamp() -> None:
    stamps = np.array([STEP, 2 * STEP], dtype=np.int64)
    objects = ObjectTrajectories(
        actor_ids=("7",),
        actor_classes=(ActorClass.CYCLIST,),
        sizes=np.array([[1.8, 0.6, 1.7]]),
        confidences=np.array([1.3]),
        stamps_ns=stamps,
        xy=np.array([[[1.0, 2.0], [1.5, 2.0]]]),
        z=np.array([0.9]),
        yaws=np.array([[0.1, 0.1]]),
        velocities=np.array([[5.0, 5.0]]),
    )
    plan = Plan(stamps_ns=stamps, xy=np.zeros((2, 2)), yaws=np.zeros(2))
    _, _, predictions = output_messages(StackOutput(plan=plan, plan_z=0.0, predictions=objects), 0, "map")
    message = codec.decode(predictions, names.ACTOR_TRACK_ARRAY)
    track = message.tracks[0]
    assert (track.actor_id, track.actor_class, track.confidence) == ("7", "cyclist", 1.0)  # clipped into [0, 1]
    assert [stamp_ns(state.stamp) for state in track.states] == stamps.tolist()
    assert (track.states[1].x, track.states[1].z, track.states[1].velocity) == (1.5, 0.9, 5.0)


def test_maps_and_static_transforms_are_read_from_their_messages() -> None:
    road = RoadMap(
        drivable_areas=[Polyline(x=[0.0, 10.0, 10.0], y=[0.0, 0.0, 5.0])],
        lane_centerlines=[Polyline(x=[0.0, 10.0], y=[2.0, 2.0])],
    )
    read = road_map_from_msg(road)
    np.testing.assert_array_equal(read.lane_centerlines[0], [[0.0, 2.0], [10.0, 2.0]])
    assert road_map_from_msg(RoadMap()) is None
    mount = TransformStamped()
    mount.header.frame_id, mount.child_frame_id = "base_link", "velodyne"
    mount.transform.translation.z = 1.73
    mount.transform.rotation.w = 1.0
    broken = TransformStamped()
    broken.header.frame_id, broken.child_frame_id = "a", "b"
    broken.transform.rotation.w = 0.0  # an all-zero quaternion is no rotation: skipped
    transforms = transforms_of(TFMessage(transforms=[mount, broken]))
    assert list(transforms) == [("base_link", "velodyne")]
    assert transforms[("base_link", "velodyne")][2, 3] == 1.73
