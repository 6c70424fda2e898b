"""sensor_msgs_py.point_cloud2 in the venv: stacks that import it read what the graph sends, byte for byte.

advsim_ros.ros.point_cloud2 provides the helpers (the ROS 2 wheels lack sensor_msgs_py;
scripts/setup.sh installs a `sensor_msgs_py` that re-exports them). Both directions are checked
against the contract's own converter: a real KITTI sweep sent as the graph sends it (contract
builder, CDR) and read as a stack reads it (rclpy message, read_points), and a cloud a stack makes
with create_cloud read back by the graph; organized clouds with NaNs in padded layouts besides.
"""

from __future__ import annotations

import array
from pathlib import Path

import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import PointCloud2, PointField
from std_msgs.msg import Header

from advsim_ros.contract import codec, names
from advsim_ros.contract.pointcloud import cloud_to_points, finite_points, points_to_cloud_fields
from advsim_ros.contract.scenario import cloud_msg
from advsim_ros.core.types import Sweep
from advsim_ros.io.kitti import kitti_velodyne_dir, read_velodyne_bin
from advsim_ros.ros import point_cloud2 as pc2


@pytest.fixture(scope="module")
def kitti_sweep(kitti_root: Path) -> np.ndarray:
    """The first sweep of KITTI tracking 0000: x, y, z, intensity float32 (16 bytes a point)."""
    return read_velodyne_bin(kitti_velodyne_dir(kitti_root, "0000") / "000000.bin")


def _as_a_stack_receives(points: np.ndarray) -> PointCloud2:
    """A sweep built by the contract (as the graph publishes it) and deserialised by rclpy (as a stack gets it)."""
    sweep = Sweep(stamp_ns=1_500_000_000, frame_id="velodyne", points=points, sensor_pose=np.eye(4))
    raw = codec.typestore().serialize_cdr(cloud_msg(sweep), names.POINTCLOUD2)
    return deserialize_message(bytes(raw), PointCloud2)


def _velodyne_grid(height: int, width: int) -> np.ndarray:
    """An organized (rings x columns) cloud in a padded driver layout, NaN where a beam had no return."""
    dtype = np.dtype(
        {
            "names": ["x", "y", "z", "intensity", "ring", "time"],
            "formats": ["<f4", "<f4", "<f4", "<f4", "<u2", "<f8"],
            "offsets": [0, 4, 8, 16, 20, 24],
            "itemsize": 32,
        }
    )
    rng = np.random.default_rng(5)
    grid = np.zeros((height, width), dtype=dtype)
    for name in ("x", "y", "z", "intensity", "time"):
        grid[name] = rng.uniform(-40.0, 40.0, (height, width))
    grid["ring"] = np.arange(height, dtype=np.uint16)[:, None]
    missing = rng.random((height, width)) < 0.2
    for name in ("x", "y", "z"):
        grid[name][missing] = np.nan
    return grid


def _organized(grid: np.ndarray) -> PointCloud2:
    fields, point_step = points_to_cloud_fields(grid.reshape(-1))
    height, width = grid.shape
    return PointCloud2(
        height=height,
        width=width,
        fields=[PointField(name=f.name, offset=f.offset, datatype=f.datatype, count=f.count) for f in fields],
        is_bigendian=False,
        point_step=point_step,
        row_step=point_step * width,
        data=array.array("B", grid.tobytes()),
        is_dense=False,
    )


def test_a_stack_reads_a_real_kitti_sweep_as_the_graph_sent_it(kitti_sweep: np.ndarray) -> None:
    cloud = _as_a_stack_receives(kitti_sweep)
    points = pc2.read_points(cloud)
    assert points.tobytes() == kitti_sweep.tobytes()
    assert points.dtype == cloud_to_points(cloud).dtype
    xyz = pc2.read_points_numpy(cloud, field_names=("x", "y", "z"))
    assert xyz.shape == (len(kitti_sweep), 3)
    np.testing.assert_array_equal(xyz[:, 2], kitti_sweep["z"])
    first = pc2.read_points_list(cloud, field_names=("x", "intensity"), uvs=[0, 7])
    assert [(p.x, p.intensity) for p in first] == [
        (float(kitti_sweep["x"][i]), float(kitti_sweep["intensity"][i])) for i in (0, 7)
    ]


def test_a_cloud_a_stack_creates_is_read_back_unchanged_by_the_graph(kitti_sweep: np.ndarray) -> None:
    header = Header(frame_id="velodyne")
    fields = pc2.fields_from_dtype(kitti_sweep.dtype)
    made = pc2.create_cloud(header, fields, kitti_sweep)  # a structured array
    listed = pc2.create_cloud(header, fields, kitti_sweep[:500].tolist())  # one tuple per point
    columns = pc2.create_cloud(header, fields, np.column_stack([kitti_sweep[n] for n in ["x", "y", "z", "intensity"]]))
    for cloud, expected in ((made, kitti_sweep), (listed, kitti_sweep[:500]), (columns, kitti_sweep)):
        received = deserialize_message(serialize_message(cloud), PointCloud2)  # over the wire, then the graph's reader
        assert cloud_to_points(codec.decode(serialize_message(received), names.POINTCLOUD2)).tobytes() == (
            expected.tobytes()
        )
    assert (made.height, made.width, made.point_step, made.is_dense) == (1, len(kitti_sweep), 16, True)
    xyz = pc2.create_cloud_xyz32(header, np.column_stack([kitti_sweep[n] for n in "xyz"]))
    assert [f.name for f in xyz.fields] == ["x", "y", "z"]
    assert xyz.point_step == 12
    np.testing.assert_array_equal(cloud_to_points(xyz)["y"], kitti_sweep["y"])


def test_an_organized_cloud_with_nans_keeps_its_grid_or_drops_what_the_graph_drops() -> None:
    grid = _velodyne_grid(16, 64)
    cloud = _organized(grid)
    organized = pc2.read_points(cloud, reshape_organized_cloud=True)
    assert organized.shape == (16, 64)
    assert organized.tobytes() == grid.tobytes()
    kept, dropped = finite_points(cloud_to_points(cloud))
    read = pc2.read_points(cloud, skip_nans=True)
    assert dropped > 0
    assert len(read) == len(kept)
    assert read.tobytes() == kept.tobytes()
    rings = pc2.read_points(cloud, field_names=["ring"], uvs=[(3, 0), (5, 9)])  # (column, row)
    assert rings["ring"].tolist() == [0, 9]
    # ring and time are finite everywhere: skip_nans looks only at the fields read
    assert len(pc2.read_points(cloud, field_names=["ring", "time"], skip_nans=True)) == 16 * 64
    with pytest.raises(ValueError, match="leaves no grid"):
        pc2.read_points(cloud, skip_nans=True, reshape_organized_cloud=True)


def test_mixed_datatypes_and_unknown_fields_are_refused_naming_them() -> None:
    cloud = _organized(_velodyne_grid(2, 4))
    with pytest.raises(ValueError, match="different datatypes"):
        pc2.read_points_numpy(cloud)
    with pytest.raises(ValueError, match=r"no field\(s\) \['rgb'\]"):
        pc2.read_points(cloud, field_names=["x", "rgb"])
    assert pc2.dtype_from_fields(cloud.fields, cloud.point_step) == _velodyne_grid(1, 1).dtype
    assert pc2.dtype_from_fields(cloud.fields).itemsize == 32  # time ends the point: no padding after it


def test_stacks_import_sensor_msgs_py_point_cloud2_from_the_venv(kitti_sweep: np.ndarray) -> None:
    """`scripts/setup.sh` puts advsim's sensor_msgs_py into the venv when none is there (a full ROS has its own)."""
    from sensor_msgs_py import point_cloud2

    cloud = _as_a_stack_receives(kitti_sweep)
    np.testing.assert_array_equal(point_cloud2.read_points_numpy(cloud, ["x", "y", "z"], skip_nans=True)[:, 0],
                                  kitti_sweep["x"])  # fmt: skip
