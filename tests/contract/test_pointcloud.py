"""PointCloud2 <-> structured arrays for any field layout, on rosbags messages and rclpy-like ones."""

from __future__ import annotations

import array
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from rosbags.typesys import Stores, get_typestore

from advsim_ros.contract.pointcloud import (
    FLOAT32,
    FLOAT64,
    UINT8,
    UINT16,
    PointCloudError,
    cloud_to_points,
    pointfields_to_dtype,
    points_are_bigendian,
    points_to_cloud_fields,
    xyz_points,
)

STORE = get_typestore(Stores.ROS2_JAZZY)
PointField = STORE.types["sensor_msgs/msg/PointField"]


def _cloud(points: np.ndarray, *, height: int = 1, row_padding: int = 0, as_array_array: bool = False) -> object:
    """A PointCloud2-like object carrying ``points`` exactly as points_to_cloud_fields describes them."""
    fields, point_step = points_to_cloud_fields(points)
    width = points.shape[0] // height
    rows = points.reshape(height, width).view(np.uint8).reshape(height, -1)
    padded = np.concatenate([rows, np.full((height, row_padding), 0xAB, dtype=np.uint8)], axis=1)
    data = padded.reshape(-1)
    return SimpleNamespace(
        height=height,
        width=width,
        fields=[PointField(name=f.name, offset=f.offset, datatype=f.datatype, count=f.count) for f in fields],
        is_bigendian=points_are_bigendian(points),
        point_step=point_step,
        row_step=width * point_step + row_padding,
        data=array.array("B", data.tobytes()) if as_array_array else data,
    )


def _velodyne_like(count: int) -> np.ndarray:
    """x, y, z, intensity float32, ring uint16, time float64, with padding as drivers lay them out."""
    dtype = np.dtype(
        {
            "names": ["x", "y", "z", "intensity", "ring", "time"],
            "formats": ["<f4", "<f4", "<f4", "<f4", "<u2", "<f8"],
            "offsets": [0, 4, 8, 16, 20, 24],
            "itemsize": 32,
        }
    )
    rng = np.random.default_rng(7)
    points = np.zeros(count, dtype=dtype)
    for name in dtype.names or ():
        points[name] = rng.uniform(0, 60, count).astype(dtype[name])
    return points


def test_a_cloud_with_padding_ring_and_time_round_trips_byte_for_byte() -> None:
    points = _velodyne_like(100)
    decoded = cloud_to_points(_cloud(points))
    assert decoded.dtype == points.dtype
    assert decoded.tobytes() == points.tobytes()


def test_rows_padded_beyond_width_times_point_step_are_read_row_by_row() -> None:
    points = _velodyne_like(60)
    decoded = cloud_to_points(_cloud(points, height=4, row_padding=12))
    np.testing.assert_array_equal(decoded, points)


def test_data_as_rclpy_array_array_is_accepted() -> None:
    points = _velodyne_like(10)
    np.testing.assert_array_equal(cloud_to_points(_cloud(points, as_array_array=True)), points)


def test_big_endian_clouds_decode_to_the_same_values() -> None:
    little = _velodyne_like(20)
    big = little.astype(little.dtype.newbyteorder(">"))
    assert points_are_bigendian(big)
    decoded = cloud_to_points(_cloud(big))
    for name in little.dtype.names or ():
        np.testing.assert_array_equal(decoded[name], little[name])


def test_a_rosbags_pointcloud2_message_serialises_and_decodes_unchanged() -> None:
    points = _velodyne_like(50)
    fields, point_step = points_to_cloud_fields(points)
    msg = STORE.types["sensor_msgs/msg/PointCloud2"](
        header=STORE.types["std_msgs/msg/Header"](
            stamp=STORE.types["builtin_interfaces/msg/Time"](sec=1, nanosec=0), frame_id="lidar"
        ),
        height=1,
        width=50,
        fields=[PointField(name=f.name, offset=f.offset, datatype=f.datatype, count=f.count) for f in fields],
        is_bigendian=False,
        point_step=point_step,
        row_step=point_step * 50,
        data=points.view(np.uint8),
        is_dense=True,
    )
    raw = STORE.serialize_cdr(msg, "sensor_msgs/msg/PointCloud2")
    decoded = cloud_to_points(STORE.deserialize_cdr(raw, "sensor_msgs/msg/PointCloud2"))
    assert decoded.tobytes() == points.tobytes()


@pytest.mark.parametrize("missing", ["x", "y", "z"])
def test_a_cloud_without_a_coordinate_field_is_rejected_naming_it(missing: str) -> None:
    points = _velodyne_like(5)
    cloud = _cloud(points)
    cloud.fields = [field for field in cloud.fields if field.name != missing]
    with pytest.raises(PointCloudError, match=f"PointCloud2 without {missing}"):
        cloud_to_points(cloud)


def test_data_shorter_than_the_layout_needs_is_rejected() -> None:
    cloud = _cloud(_velodyne_like(5))
    cloud.data = cloud.data[:-1]
    with pytest.raises(PointCloudError, match="data has 159 bytes"):
        cloud_to_points(cloud)


def test_overlapping_or_overrunning_or_unknown_fields_are_rejected() -> None:
    x, y, z = (PointField(name=n, offset=4 * i, datatype=FLOAT32, count=1) for i, n in enumerate("xyz"))
    with pytest.raises(PointCloudError, match="overlap"):
        pointfields_to_dtype([x, y, z, PointField(name="i", offset=6, datatype=UINT16, count=1)], 16, False)
    with pytest.raises(PointCloudError, match="runs past point_step"):
        pointfields_to_dtype([x, y, z, PointField(name="t", offset=12, datatype=FLOAT64, count=1)], 16, False)
    with pytest.raises(PointCloudError, match="unknown datatype 9"):
        pointfields_to_dtype([x, y, z, PointField(name="q", offset=12, datatype=9, count=1)], 16, False)
    with pytest.raises(PointCloudError, match="appears twice"):
        pointfields_to_dtype([x, y, z, PointField(name="x", offset=12, datatype=FLOAT32, count=1)], 16, False)


def test_fields_with_count_become_sub_arrays() -> None:
    fields = [PointField(name=n, offset=4 * i, datatype=FLOAT32, count=1) for i, n in enumerate("xyz")]
    fields.append(PointField(name="rgb", offset=12, datatype=UINT8, count=3))
    dtype = pointfields_to_dtype(fields, 16, False)
    assert dtype["rgb"].shape == (3,)
    points = np.zeros(4, dtype=dtype)
    points["rgb"] = [[1, 2, 3]] * 4
    decoded = cloud_to_points(_cloud(points))
    np.testing.assert_array_equal(decoded["rgb"], points["rgb"])


def test_arrays_pointcloud2_cannot_carry_are_refused_by_name() -> None:
    half = np.zeros(3, dtype=[("x", "<f2"), ("y", "<f4"), ("z", "<f4")])
    with pytest.raises(PointCloudError, match="field 'x': dtype float16"):
        points_to_cloud_fields(half)
    with pytest.raises(PointCloudError, match="without z"):
        points_to_cloud_fields(np.zeros(3, dtype=[("x", "<f4"), ("y", "<f4")]))
    mixed = np.zeros(3, dtype=[("x", "<f4"), ("y", ">f4"), ("z", "<f4")])
    with pytest.raises(PointCloudError, match="mix byte orders"):
        points_to_cloud_fields(mixed)


def test_xyz_points_builds_float32_coordinates_and_intensity() -> None:
    points = xyz_points(np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]), np.array([0.5, 0.25]))
    assert points.dtype.names == ("x", "y", "z", "intensity")
    np.testing.assert_array_equal(points["z"], np.array([3.0, 6.0], dtype=np.float32))


_DATATYPES = st.sampled_from(["i1", "u1", "i2", "u2", "i4", "u4", "f4", "f8"])


@settings(max_examples=40, deadline=None)
@given(
    extra=st.lists(st.tuples(_DATATYPES, st.integers(1, 3), st.integers(0, 3)), max_size=4),
    order=st.sampled_from(["<", ">"]),
    count=st.integers(0, 9),
)
def test_any_layout_with_x_y_z_round_trips(extra: list[tuple[str, int, int]], order: str, count: int) -> None:
    names, formats, offsets = [], [], []
    offset = 0
    for index, (kind, repeat, gap) in enumerate([("f4", 1, 0), ("f4", 1, 0), ("f8", 1, 1), *extra]):
        offset += gap  # padding before the field
        names.append(["x", "y", "z"][index] if index < 3 else f"extra{index}")
        base = np.dtype(order + kind)
        formats.append(base if repeat == 1 else (base, (repeat,)))
        offsets.append(offset)
        offset += base.itemsize * repeat
    dtype = np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": offset + 2})
    rng = np.random.default_rng(count)
    points = np.frombuffer(rng.integers(0, 256, dtype.itemsize * count, dtype=np.uint8).tobytes(), dtype=dtype)
    decoded = cloud_to_points(_cloud(points))
    assert decoded.dtype == points.dtype
    assert decoded.tobytes() == points.tobytes()
