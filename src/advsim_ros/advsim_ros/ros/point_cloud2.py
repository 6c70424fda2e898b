"""The point-cloud helpers of ROS 2's ``sensor_msgs_py.point_cloud2``, over the contract's PointCloud2 reader.

The ROS 2 wheels advsim runs on lack ``sensor_msgs_py``, and LiDAR stacks written with plain rclpy
import it. ``scripts/setup.sh`` installs a ``sensor_msgs_py`` package that re-exports these functions
(src/sensor_msgs_py_compat) when ``import sensor_msgs_py`` fails, so such stacks run unchanged; a
full ROS install keeps its own. Names, arguments and results follow sensor_msgs_py's documented API;
the layout work (offsets, padding, row padding, byte order, size checks) is ``contract.pointcloud``,
so a stack reads a sweep exactly as the graph's own nodes do.

Where the documentation leaves a choice open: ``uvs`` are indices into the cloud as sent (flat
indices, or (u, v) = (column, row) pairs), taken before ``skip_nans``; fields with count > 1 are
numpy sub-arrays; results are copies, apart from the message's buffer.
"""

from __future__ import annotations

import array
import collections
from collections.abc import Iterable, Sequence
from typing import NamedTuple

import numpy as np
import numpy.typing as npt
from numpy.lib import recfunctions
from sensor_msgs.msg import PointCloud2, PointField
from std_msgs.msg import Header

from advsim_ros.contract.pointcloud import (
    FLOAT32,
    cloud_to_points,
    dtype_to_cloud_fields,
    packed_point_step,
    pointfields_to_dtype,
)

__all__ = [
    "create_cloud",
    "create_cloud_xyz32",
    "dtype_from_fields",
    "fields_from_dtype",
    "read_points",
    "read_points_list",
    "read_points_numpy",
]


def dtype_from_fields(fields: Iterable[PointField], point_step: int | None = None) -> np.dtype:
    """The structured dtype of one point (little-endian); ``point_step`` defaults to the end of the last field."""
    fields = list(fields)
    step = packed_point_step(fields) if point_step is None else point_step
    return pointfields_to_dtype(fields, step, is_bigendian=False)


def fields_from_dtype(dtype: npt.DTypeLike) -> list[PointField]:
    """The PointFields that describe a structured dtype (offsets kept)."""
    specs, _ = dtype_to_cloud_fields(np.dtype(dtype))
    return [PointField(name=s.name, offset=s.offset, datatype=s.datatype, count=s.count) for s in specs]


def _indices(uvs: Iterable[int | Sequence[int]], height: int, width: int) -> np.ndarray:
    """Flat indices of the points ``uvs`` names (flat indices, or (u, v) = (column, row) pairs)."""
    items = np.asarray(list(uvs), dtype=np.int64)
    if items.ndim == 2 and items.shape[1] == 2:
        if np.any((items[:, 0] < 0) | (items[:, 0] >= width) | (items[:, 1] < 0) | (items[:, 1] >= height)):
            raise IndexError(f"uvs: a (u, v) outside the {width} x {height} cloud")
        return items[:, 1] * width + items[:, 0]
    if items.ndim > 1:
        raise ValueError(f"uvs: flat indices or (u, v) pairs, got an array of shape {items.shape}")
    return items


def _take(points: np.ndarray, index: np.ndarray) -> np.ndarray:
    """points[index] with whole records copied, padding included (structured indexing leaves it undefined)."""
    records = np.ascontiguousarray(points.view(np.uint8).reshape(len(points), points.dtype.itemsize))
    taken: np.ndarray = records[index].reshape(-1).view(points.dtype)
    return taken


def read_points(
    cloud: PointCloud2,
    field_names: Sequence[str] | None = None,
    skip_nans: bool = False,
    uvs: Iterable[int | Sequence[int]] | None = None,
    reshape_organized_cloud: bool = False,
) -> np.ndarray:
    """The cloud's points as a structured array: all fields or ``field_names``; without points that have a NaN
    in a read field (``skip_nans``); only those ``uvs`` names; (height, width) for an organized cloud when
    ``reshape_organized_cloud`` (not with ``skip_nans`` or ``uvs``, which leave no grid)."""
    points = cloud_to_points(cloud, require_xyz=False)  # a copy of the bytes, padding and all
    height, width = int(cloud.height), int(cloud.width)
    if field_names is not None:
        names, present = list(field_names), list(points.dtype.names or ())
        missing = [name for name in names if name not in present]
        if missing:
            raise ValueError(f"read_points: no field(s) {missing} in the cloud (it has {present})")
        points = points[names]
    if uvs is not None:
        points = _take(points, _indices(uvs, height, width))
    if skip_nans:
        keep = np.ones(points.shape, dtype=bool)
        for name in points.dtype.names or ():
            values = points[name]
            if values.dtype.kind == "f":
                keep &= ~np.isnan(values).reshape(len(values), -1).any(axis=1)
        points = _take(points, keep)
    if reshape_organized_cloud and height > 1:
        if skip_nans or uvs is not None:
            raise ValueError("read_points: reshape_organized_cloud leaves no grid with skip_nans or uvs")
        points = points.reshape(height, width)
    return points


def read_points_numpy(
    cloud: PointCloud2,
    field_names: Sequence[str] | None = None,
    skip_nans: bool = False,
    uvs: Iterable[int | Sequence[int]] | None = None,
    reshape_organized_cloud: bool = False,
) -> np.ndarray:
    """read_points as a plain array, one column per field value; every read field must have the same datatype."""
    points = read_points(cloud, field_names, skip_nans, uvs, reshape_organized_cloud)
    fields = dict(points.dtype.fields or {})
    bases = {fields[name][0].base.newbyteorder("=") for name in points.dtype.names or ()}
    if len(bases) != 1:
        raise ValueError(
            f"read_points_numpy: the fields have different datatypes ({sorted(str(b) for b in bases)}); "
            "read them with field_names of one datatype, or as a structured array with read_points"
        )
    return recfunctions.structured_to_unstructured(points)


def read_points_list(
    cloud: PointCloud2,
    field_names: Sequence[str] | None = None,
    skip_nans: bool = False,
    uvs: Iterable[int | Sequence[int]] | None = None,
) -> list[NamedTuple]:
    """read_points as a list of namedtuples ``Point`` with the field names as attributes (Python numbers)."""
    points = read_points(cloud, field_names, skip_nans, uvs)
    point = collections.namedtuple("Point", points.dtype.names or (), rename=True)  # type: ignore[misc]  # field names known at run time only
    return [point._make(values) for values in points.tolist()]


def create_cloud(
    header: Header,
    fields: Iterable[PointField],
    points: np.ndarray | Iterable[Iterable[float]],
    point_step: int | None = None,
) -> PointCloud2:
    """A PointCloud2 of ``points``: a structured array (fields by name; 2-D: an organized cloud), a 2-D array
    (one column per field value, in the order of ``fields``) or one iterable of values per point."""
    fields = list(fields)
    dtype = dtype_from_fields(fields, point_step)
    if isinstance(points, np.ndarray) and points.dtype.names:
        cloud = np.zeros(points.shape, dtype=dtype)  # padding bytes zero, not whatever memory held
        for name in dtype.names or ():
            cloud[name] = points[name]
    elif isinstance(points, np.ndarray):
        values = np.atleast_2d(points) if points.size else points.reshape(0, len(fields))
        cloud = np.zeros(values.shape[0], dtype=dtype)
        cloud[...] = recfunctions.unstructured_to_structured(values, dtype=recfunctions.repack_fields(dtype))
    else:
        rows = [tuple(point) for point in points]
        cloud = np.zeros(len(rows), dtype=dtype)
        if rows:
            cloud[...] = rows
    grid = cloud.reshape(1, -1) if cloud.ndim == 1 else cloud
    floats = [name for name in dtype.names or () if dtype[name].base.kind == "f"]
    dense = not any(np.isnan(grid[name]).any() for name in floats)
    return PointCloud2(
        header=header,
        height=grid.shape[0],
        width=grid.shape[1],
        fields=fields,
        is_bigendian=False,
        point_step=dtype.itemsize,
        row_step=dtype.itemsize * grid.shape[1],
        is_dense=dense,
        data=array.array("B", grid.tobytes()),
    )


def create_cloud_xyz32(header: Header, points: np.ndarray | Iterable[Iterable[float]]) -> PointCloud2:
    """A PointCloud2 with float32 x, y, z fields from one (x, y, z) per point."""
    fields = [PointField(name=name, offset=4 * index, datatype=FLOAT32, count=1) for index, name in enumerate("xyz")]
    return create_cloud(header, fields, points)
