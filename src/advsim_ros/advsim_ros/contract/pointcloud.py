"""PointCloud2 <-> structured numpy arrays, for any field layout.

Duck-typed on the attributes of sensor_msgs/msg/PointCloud2 (height, width, fields,
is_bigendian, point_step, row_step, data) and PointField (name, offset, datatype,
count), so the same code serves rosbags messages and rclpy messages. The structured
array keeps the source layout byte for byte: field offsets, padding and point_step
survive, so intensity, ring, time or any other field round-trips unchanged.
"""

from __future__ import annotations

import array
import itertools
import logging
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from advsim_ros.core.types import POINT_XYZ_FIELDS, ScenarioError


class PointCloudError(ScenarioError):
    """A PointCloud2 whose layout or data cannot be read; the message names the problem."""


_MAX_POINT_STEP = 2**31 - 1  # the largest itemsize numpy takes


# sensor_msgs/msg/PointField datatype constants and their numpy equivalents.
INT8, UINT8, INT16, UINT16, INT32, UINT32, FLOAT32, FLOAT64 = range(1, 9)
_DATATYPE_TO_NUMPY: dict[int, str] = {
    INT8: "i1",
    UINT8: "u1",
    INT16: "i2",
    UINT16: "u2",
    INT32: "i4",
    UINT32: "u4",
    FLOAT32: "f4",
    FLOAT64: "f8",
}
_NUMPY_TO_DATATYPE: dict[tuple[str, int], int] = {
    ("i", 1): INT8,
    ("u", 1): UINT8,
    ("i", 2): INT16,
    ("u", 2): UINT16,
    ("i", 4): INT32,
    ("u", 4): UINT32,
    ("f", 4): FLOAT32,
    ("f", 8): FLOAT64,
}


class PointFieldLike(Protocol):
    """What we read from a sensor_msgs/msg/PointField (rosbags or rclpy)."""

    @property
    def name(self) -> str: ...
    @property
    def offset(self) -> int: ...
    @property
    def datatype(self) -> int: ...
    @property
    def count(self) -> int: ...


class PointCloud2Like(Protocol):
    """What we read from a sensor_msgs/msg/PointCloud2 (rosbags or rclpy)."""

    @property
    def height(self) -> int: ...
    @property
    def width(self) -> int: ...
    @property
    def fields(self) -> Sequence[PointFieldLike]: ...
    @property
    def is_bigendian(self) -> bool: ...
    @property
    def point_step(self) -> int: ...
    @property
    def row_step(self) -> int: ...
    @property
    def data(self) -> object: ...  # bytes, array.array('B') or a uint8 numpy array


@dataclass(frozen=True)
class PointFieldSpec:
    """One sensor_msgs/msg/PointField, independent of any ROS message class."""

    name: str
    offset: int  # byte offset of the field inside one point [bytes]
    datatype: int  # PointField datatype constant (INT8 .. FLOAT64)
    count: int  # number of consecutive elements of this datatype


def packed_point_step(fields: Sequence[PointFieldLike]) -> int:
    """The smallest point_step that holds every field (the end of the one that ends last)."""
    ends = [0]
    for field in fields:
        if int(field.datatype) not in _DATATYPE_TO_NUMPY:
            raise PointCloudError(f"PointCloud2: field {field.name!r} has unknown datatype {field.datatype}")
        ends.append(int(field.offset) + np.dtype(_DATATYPE_TO_NUMPY[int(field.datatype)]).itemsize * int(field.count))
    return max(ends)


def pointfields_to_dtype(fields: Sequence[PointFieldLike], point_step: int, is_bigendian: bool) -> np.dtype:
    """The structured dtype (itemsize = point_step) that one point of this layout has.

    Raises PointCloudError for unknown datatypes, duplicate or empty names, and fields
    that overlap each other or run past point_step.
    """
    if point_step <= 0:
        raise PointCloudError(f"PointCloud2: point_step must be positive, got {point_step}")
    byte_order = ">" if is_bigendian else "<"
    names: list[str] = []
    formats: list[str | tuple[str, tuple[int]]] = []
    offsets: list[int] = []
    occupied: list[tuple[int, int, str]] = []
    try:
        fields = list(fields)
    except TypeError as error:
        raise PointCloudError(f"PointCloud2: fields is not a list of PointFields ({error})") from None
    for field in fields:
        try:
            name, offset, datatype, count = str(field.name), int(field.offset), int(field.datatype), int(field.count)
        except (AttributeError, TypeError, ValueError) as error:
            raise PointCloudError(f"PointCloud2: a field is not a PointField ({error})") from None
        if count == 0:
            continue  # a zero-count field holds no data (seen in some drivers' padding entries)
        if not name:
            raise PointCloudError("PointCloud2: a field has an empty name")
        if datatype not in _DATATYPE_TO_NUMPY:
            raise PointCloudError(f"PointCloud2: field {name!r} has unknown datatype {datatype}")
        if count < 0 or offset < 0:
            raise PointCloudError(f"PointCloud2: field {name!r} has negative offset or count")
        base = np.dtype(byte_order + _DATATYPE_TO_NUMPY[datatype])
        end = offset + base.itemsize * count
        if end > point_step:
            raise PointCloudError(
                f"PointCloud2: field {name!r} (bytes {offset}..{end}) runs past point_step {point_step}"
            )
        occupied.append((offset, end, name))
        names.append(name)
        formats.append(base.str if count == 1 else (base.str, (count,)))
        offsets.append(offset)
    # sorted, not pairwise: a corrupt message may list a hundred thousand fields
    seen: set[str] = set()
    for name in names:
        if name in seen:
            raise PointCloudError(f"PointCloud2: field {name!r} appears twice")
        seen.add(name)
    occupied.sort()
    for (_, previous_end, previous), (start, _, name) in itertools.pairwise(occupied):
        if start < previous_end:
            raise PointCloudError(f"PointCloud2: fields {previous!r} and {name!r} overlap")
    return np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": point_step})


def _data_bytes(data: object) -> memoryview:
    if isinstance(data, np.ndarray):
        return memoryview(np.ascontiguousarray(data, dtype=np.uint8).tobytes())
    if isinstance(data, bytes | bytearray | memoryview | array.array):  # array.array('B') from rclpy: no copy
        return memoryview(data).cast("B")
    try:
        return memoryview(bytes(data))  # type: ignore[call-overload]  # any other sequence of bytes
    except (TypeError, ValueError) as error:
        raise PointCloudError(f"PointCloud2: data is not a sequence of bytes ({error})") from None


def _integer(msg: PointCloud2Like, name: str) -> int:
    try:
        return int(getattr(msg, name))
    except (AttributeError, TypeError, ValueError) as error:
        raise PointCloudError(f"PointCloud2: {name} is not an integer ({error})") from None


def _checked_layout(msg: PointCloud2Like, require_xyz: bool = True) -> tuple[np.dtype, int, int]:
    """The dtype of one point, height and width, with x, y and z present as single numbers of any datatype
    (unless ``require_xyz`` is false: any layout)."""
    point_step = _integer(msg, "point_step")
    if point_step > _MAX_POINT_STEP:  # numpy's itemsize is a C int
        raise PointCloudError(f"PointCloud2: point_step {point_step} is larger than any point layout")
    dtype = pointfields_to_dtype(msg.fields, point_step, bool(msg.is_bigendian))
    names = dtype.names or ()
    missing = [name for name in POINT_XYZ_FIELDS if name not in names]
    if missing and require_xyz:
        raise PointCloudError(f"PointCloud2 without {', '.join(missing)} field(s): has fields {list(names)}")
    arrays = [name for name in POINT_XYZ_FIELDS if name in names and dtype[name].shape]
    if arrays and require_xyz:
        raise PointCloudError(f"PointCloud2: field(s) {', '.join(arrays)} have count > 1; x, y, z are single numbers")
    height, width = _integer(msg, "height"), _integer(msg, "width")
    if height < 0 or width < 0:
        raise PointCloudError(f"PointCloud2: negative size {height} x {width}")
    return dtype, height, width


def _cloud_rows(msg: PointCloud2Like, require_xyz: bool = True) -> tuple[np.dtype, np.ndarray]:
    """The point dtype and a (height, width * point_step) uint8 view of the message's bytes, sizes checked;
    for a cloud without points, a (0, 0) array of points (the other dimension may be any number)."""
    dtype, height, width = _checked_layout(msg, require_xyz)
    point_step, row_step = dtype.itemsize, _integer(msg, "row_step")
    if height * width == 0:
        return dtype, np.zeros((0, 0), dtype=dtype)
    if row_step < width * point_step:
        raise PointCloudError(f"PointCloud2: row_step {row_step} is less than width {width} x point_step {point_step}")
    data = _data_bytes(msg.data)
    # Python ints: a declared size of any magnitude is compared with the bytes there before anything is allocated
    needed = row_step * (height - 1) + width * point_step
    if len(data) < needed:
        raise PointCloudError(
            f"PointCloud2: data has {len(data)} bytes, {height} x {width} points need at least {needed}"
        )
    raw = np.frombuffer(data, dtype=np.uint8, count=needed)
    if row_step == width * point_step:
        return dtype, raw.reshape(height, width * point_step)
    # rows padded beyond width * point_step: a strided view skips the padding
    return dtype, np.lib.stride_tricks.as_strided(raw, shape=(height, width * point_step), strides=(row_step, 1))


def cloud_view(msg: PointCloud2Like, require_xyz: bool = True) -> np.ndarray:
    """The cloud's points as a (height, width) structured view of the message's bytes, without a copy
    ((0, 0) when it has no points).

    Checks everything cloud_to_points checks (x, y and z only with ``require_xyz``); for looking at
    clouds (layout, finite points) without decoding them.
    """
    dtype, rows = _cloud_rows(msg, require_xyz)
    return rows if rows.dtype == dtype else rows.view(dtype)


def cloud_to_points(msg: PointCloud2Like, require_xyz: bool = True) -> np.ndarray:
    """The cloud's points as a 1-D structured array (height x width points, row-major).

    Every field of the source is kept with its datatype and offset; x, y and z are
    required (any numeric datatype, count 1) unless ``require_xyz`` is false. Raises
    PointCloudError naming the problem.
    """
    dtype, rows = _cloud_rows(msg, require_xyz)
    if rows.dtype == dtype:
        return rows.reshape(-1)  # no points
    # One copy of the bytes, viewed as points: padding between fields survives (a structured .copy() leaves
    # it undefined), and the points own their memory, writable, apart from the message's buffer.
    return rows.copy().reshape(-1).view(dtype)


def finite_mask(points: np.ndarray) -> np.ndarray:
    """Which points have finite x, y and z (integer coordinates always are)."""
    mask = np.ones(points.shape, dtype=bool)
    for name in POINT_XYZ_FIELDS:
        values = points[name]
        if values.dtype.kind == "f":
            mask &= np.isfinite(values)
    return mask


def finite_points(points: np.ndarray) -> tuple[np.ndarray, int]:
    """The 1-D points whose x, y and z are finite, every field and padding byte kept, and how many were dropped."""
    mask = finite_mask(points)
    dropped = int(mask.size - np.count_nonzero(mask))
    if not dropped:
        return points, 0
    if points.flags.c_contiguous:  # whole records, bytes as they are (structured indexing may lose padding)
        rows = points.view(np.uint8).reshape(points.shape[0], points.dtype.itemsize)
        return rows[mask].reshape(-1).view(points.dtype), dropped
    return points[mask], dropped


@dataclass
class DroppedPoints:
    """Non-finite points dropped from a log's sweeps at ingestion, tallied for one line in the log."""

    points: int = 0  # points dropped in all
    sweeps: int = 0  # sweeps that lost at least one

    def keep_finite(self, points: np.ndarray) -> np.ndarray:
        kept, dropped = finite_points(points)
        if dropped:
            self.points += dropped
            self.sweeps += 1
        return kept

    def report(self, log: logging.Logger, source: str, topic: str = "") -> None:
        """One warning, e.g. ``bag X: dropped 12034 non-finite points in 154 sweeps of /sensor/lidar/points``."""
        if self.points:
            of = f" of {topic}" if topic else ""
            log.warning("%s: dropped %d non-finite points in %d sweeps%s", source, self.points, self.sweeps, of)


def points_to_cloud_fields(points: np.ndarray) -> tuple[tuple[PointFieldSpec, ...], int]:
    """The PointField list and point_step that describe ``points.tobytes()`` exactly.

    Raises PointCloudError for arrays without x, y, z and for field types PointCloud2
    cannot carry (e.g. float16, int64, nested records); convert those first.
    """
    names = points.dtype.names or ()
    missing = [name for name in POINT_XYZ_FIELDS if name not in names]
    if missing:
        raise PointCloudError(f"points without {', '.join(missing)} field(s): has fields {list(names)}")
    return dtype_to_cloud_fields(points.dtype)


def dtype_to_cloud_fields(dtype: np.dtype) -> tuple[tuple[PointFieldSpec, ...], int]:
    """The PointField list and point_step of a structured dtype, whatever its fields (see points_to_cloud_fields)."""
    names = dtype.names or ()
    dtype_is_bigendian(dtype)  # rejects mixed byte orders
    specs: list[PointFieldSpec] = []
    assert dtype.fields is not None
    for name in names:
        field_dtype, offset = dtype.fields[name][0], int(dtype.fields[name][1])
        base, shape = field_dtype.base, field_dtype.shape
        if len(shape) > 1:
            raise PointCloudError(f"points field {name!r}: multi-dimensional sub-arrays are not supported")
        key = (base.kind, base.itemsize)
        if key not in _NUMPY_TO_DATATYPE:
            raise PointCloudError(f"points field {name!r}: dtype {base} has no PointField datatype")
        count = int(shape[0]) if shape else 1
        specs.append(PointFieldSpec(name=name, offset=offset, datatype=_NUMPY_TO_DATATYPE[key], count=count))
    return tuple(specs), int(dtype.itemsize)


def points_are_bigendian(points: np.ndarray) -> bool:
    """The is_bigendian flag for ``points.tobytes()``; raises PointCloudError when fields mix byte orders."""
    return dtype_is_bigendian(points.dtype)


def dtype_is_bigendian(dtype: np.dtype) -> bool:
    """The is_bigendian flag of a structured dtype's bytes; raises PointCloudError when fields mix byte orders."""
    fields: dict[str, tuple[np.dtype, int]] = dict(dtype.fields or {})  # type: ignore[arg-type]  # numpy types a field as (dtype, offset[, title])
    native = "<" if np.little_endian else ">"
    orders = {
        native if fields[name][0].base.byteorder == "=" else fields[name][0].base.byteorder
        for name in dtype.names or ()
        if fields[name][0].base.itemsize > 1
    }
    if len(orders) > 1:
        raise PointCloudError("points: fields mix byte orders; PointCloud2 has one is_bigendian flag")
    return orders == {">"}


def xyz_points(xyz: np.ndarray, intensity: np.ndarray | None = None) -> np.ndarray:
    """A float32 x, y, z (, intensity) structured array from an (N, 3) array [m] (and (N,) intensities)."""
    xyz = np.asarray(xyz)
    if xyz.ndim != 2 or xyz.shape[1] != 3:
        raise PointCloudError(f"xyz_points: expected an (N, 3) array, got shape {xyz.shape}")
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    if intensity is not None:
        fields.append(("intensity", "<f4"))
    points = np.empty(xyz.shape[0], dtype=fields)
    points["x"], points["y"], points["z"] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    if intensity is not None:
        points["intensity"] = np.asarray(intensity).reshape(-1)
    return points
