"""Fuzz of the PointCloud2 reader: random layouts (any datatypes, byte order, padding, organised rows),
NaN and inf in x, y, z, and one defect per case (a field missing, overlapping, of unknown datatype, of
count 0 or negative, past point_step; sizes the data does not hold, a short row_step, junk attributes).
Each case knows what must happen: a read equal to an independent decoding, or a PointCloudError."""

from __future__ import annotations

import array
from collections.abc import Callable
from types import SimpleNamespace
from typing import Any

import numpy as np

from advsim_ros.contract.pointcloud import PointCloudError, cloud_to_points, cloud_view, finite_points

SEED = 20260  # the fuzz is reproducible: same seed, same cases
CASES = 6500
KINDS = ("i1", "u1", "i2", "u2", "i4", "u4", "f4", "f8")
DATATYPE = {kind: index + 1 for index, kind in enumerate(KINDS)}  # sensor_msgs/PointField constants
XYZ = ("x", "y", "z")


class Cloud:
    """A valid random cloud and, as mutations change it, what reading it must give (None: an error)."""

    def __init__(self, rng: np.random.Generator, wide: bool) -> None:
        self.order = ">" if rng.random() < 0.25 else "<"
        names = [*XYZ, *(f"extra{i}" for i in range(1000 if wide else int(rng.integers(0, 5))))]
        self.spec: dict[str, tuple[str, int, int]] = {}  # name -> (kind, count, offset)
        offset = 0
        for index in rng.permutation(len(names)):
            name = names[index]
            kind = str(rng.choice(KINDS)) if name not in XYZ or rng.random() < 0.15 else str(rng.choice(["f4", "f8"]))
            count = 1 if name in XYZ else int(rng.integers(1, 4))
            offset += int(rng.integers(0, 4))  # padding before the field
            self.spec[name] = (kind, count, offset)
            offset += np.dtype(kind).itemsize * count
        self.point_step = offset + int(rng.integers(0, 5))
        self.height = int(rng.choice([0, 1, 1, 1, 2, 3, 16]))
        self.width = int(rng.integers(0, 40))
        self.row_step = self.width * self.point_step + int(rng.choice([0, 0, 1, 7]))
        rows = rng.integers(0, 256, (self.height, self.row_step), dtype=np.uint8)  # padding bytes random too
        points = rows[:, : self.width * self.point_step].copy().reshape(-1).view(self.dtype())
        bad = rng.random() < 0.5
        for name in XYZ:
            if np.dtype(self.spec[name][0]).kind == "f":
                values = rng.uniform(-80, 80, points.shape[0])
                if bad:  # NaN and inf where organised clouds have no return, sometimes everywhere
                    values[rng.random(points.shape[0]) < rng.choice([0.1, 0.5, 1.0])] = rng.choice([np.nan, np.inf])
                points[name] = values
        rows[:, : self.width * self.point_step] = points.view(np.uint8).reshape(
            self.height, self.width * self.point_step
        )
        self.data: Any = rows.reshape(-1).tobytes()
        self.fields: Any = [
            SimpleNamespace(name=n, offset=self.spec[n][2], datatype=DATATYPE[self.spec[n][0]], count=self.spec[n][1])
            for n in self.spec
        ]
        rng.shuffle(self.fields)
        self.expect_error = False

    def dtype(self, skip: str = "") -> np.dtype:
        names = [name for name in self.spec if name != skip]
        bases = {name: self.order + self.spec[name][0] for name in names}
        formats = [(bases[n], (self.spec[n][1],)) if self.spec[n][1] > 1 else bases[n] for n in names]
        offsets = [self.spec[name][2] for name in names]
        return np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": self.point_step})

    def message(self) -> SimpleNamespace:
        return SimpleNamespace(
            height=self.height, width=self.width, fields=self.fields, is_bigendian=self.order == ">",
            point_step=self.point_step, row_step=self.row_step, data=self.data,
        )  # fmt: skip

    def expected_bytes(self) -> bytes:
        """Each row's first width * point_step bytes, one row after the other (the spec, sliced plainly)."""
        data = bytes(self.data)
        size = self.width * self.point_step
        if size * self.height == 0:
            return b""  # no points, however many rows or columns the message claims
        return b"".join(data[row * self.row_step : row * self.row_step + size] for row in range(self.height))


def _field(cloud: Cloud, name: str) -> SimpleNamespace:
    return next(field for field in cloud.fields if field.name == name)


def _mutate(cloud: Cloud, rng: np.random.Generator) -> tuple[str, np.dtype | None]:
    """Apply one defect (or none); the dtype a read must give, None when it must fail."""
    names = list(cloud.spec)
    extras = [name for name in names if name not in XYZ]
    name = str(rng.choice(names))
    field = _field(cloud, name)
    kind = int(rng.integers(0, 21))
    if kind == 0:
        cloud.fields.remove(_field(cloud, str(rng.choice(XYZ))))
        return "without x, y or z", None
    if kind == 1 and extras:
        dropped = str(rng.choice(extras))
        cloud.fields.remove(_field(cloud, dropped))
        return "an extra field left out", cloud.dtype(skip=dropped)
    if kind == 2:
        field.count = 0  # holds no data: skipped
        return "count 0", None if name in XYZ else cloud.dtype(skip=name)
    if kind == 3:
        field.datatype = int(rng.choice([0, 9, 17, 255, -3]))
        return "unknown datatype", None
    if kind == 4:
        field.count = int(rng.choice([-1, -7, -(2**31)]))
        return "negative count", None
    if kind == 5:
        field.offset = int(rng.choice([-1, -64]))
        return "negative offset", None
    if kind == 6:
        field.offset = cloud.point_step - np.dtype(cloud.spec[name][0]).itemsize + int(rng.integers(1, 100))
        return "offset past point_step", None
    if kind == 7:
        other = str(rng.choice([n for n in names if n != name]))
        field.offset = cloud.spec[other][2] + int(rng.integers(0, np.dtype(cloud.spec[other][0]).itemsize))
        return "overlapping fields", None
    if kind == 8:
        field.name = str(rng.choice(["x", "y", "z", ""])) if name not in XYZ else ""
        return "duplicate or empty name", None
    if kind == 9:
        _field(cloud, str(rng.choice(XYZ))).count = int(rng.integers(2, 4))
        return "x, y or z with count > 1", None
    if kind == 10:
        setattr(cloud, str(rng.choice(["width", "height"])), int(rng.choice([2**31, 2**40, 2**62, 10**30])))
        cloud.row_step = max(cloud.row_step, cloud.width * cloud.point_step)
        return "huge width x height, little data", None if cloud.width * cloud.height else cloud.dtype()
    if kind == 11:
        setattr(cloud, str(rng.choice(["width", "height"])), int(rng.integers(-5, 0)))
        return "negative size", None
    if kind == 12 and cloud.width * cloud.height > 0:
        cloud.row_step = cloud.width * cloud.point_step - int(rng.integers(1, cloud.point_step + 1))
        return "row_step shorter than a row", None
    if kind == 13:
        cloud.point_step = int(rng.choice([0, -4, 2**31, 2**40, 2**63]))
        return "point_step zero, negative or huge", None
    if kind == 14:
        cut = int(rng.integers(1, 64))
        cloud.data = cloud.data[: max(0, len(cloud.data) - cut)]
        needed = cloud.row_step * (cloud.height - 1) + cloud.width * cloud.point_step
        holds = cloud.width * cloud.height == 0 or len(cloud.data) >= needed
        return "truncated data", cloud.dtype() if holds else None
    if kind == 15:
        cloud.order = "<" if cloud.order == ">" else ">"
        return "byte order flipped", cloud.dtype()  # the same bytes, read the other way round
    if kind == 16 and cloud.width * cloud.height > 0:
        cloud.data = _pick(rng, [None, "text", 3.5, [0, 300, 1]])
        return "data that is no bytes", None
    if kind == 17:
        cloud.fields = _pick(rng, [None, 42, [SimpleNamespace(name="x")], [object()]])
        return "fields that are no PointFields", None
    if kind == 18:
        setattr(cloud, str(rng.choice(["height", "width", "point_step", "row_step"])), _pick(rng, ["ten", None]))
        return "a size that is no integer", None
    container: Callable[[bytes], Any] = _pick(rng, [bytes, bytearray, memoryview, _uint8, _array_b])
    cloud.data = container(cloud.data)
    return "valid", cloud.dtype()


def _pick(rng: np.random.Generator, options: list[Any]) -> Any:
    return options[int(rng.integers(len(options)))]


def _uint8(data: bytes) -> np.ndarray:
    return np.frombuffer(data, dtype=np.uint8)


def _array_b(data: bytes) -> array.array:
    return array.array("B", data)


def _check_read(cloud: Cloud, dtype: np.dtype) -> None:
    """The read equals the plain slicing of the spec, viewed as the layout; finite_points agrees with isfinite."""
    message = cloud.message()
    points = cloud_to_points(message)
    expected = np.frombuffer(cloud.expected_bytes(), dtype=dtype)
    assert (points.dtype.fields, points.dtype.itemsize) == (dtype.fields, dtype.itemsize)  # in the message's order
    assert points.tobytes() == expected.tobytes()
    view = cloud_view(message)
    assert view.shape == ((cloud.height, cloud.width) if points.size else (0, 0))
    for name in dtype.names or ():
        assert np.ascontiguousarray(view[name]).reshape(-1).tobytes() == np.ascontiguousarray(points[name]).tobytes()
    keep = np.ones(points.shape[0], dtype=bool)
    for name in XYZ:
        if expected.dtype[name].kind == "f":
            keep &= np.isfinite(expected[name])
    finite, dropped = finite_points(points)
    assert dropped == int((~keep).sum())
    assert finite.tobytes() == expected.view(np.uint8).reshape(len(expected), dtype.itemsize)[keep].tobytes()


def _case(cloud: Cloud, dtype: np.dtype | None) -> Callable[[], None]:
    def run() -> None:
        if dtype is None:
            cloud_to_points(cloud.message())
            raise AssertionError("read a cloud that must be refused")
        _check_read(cloud, dtype)

    return run


def test_every_fuzzed_pointcloud2_reads_correctly_or_is_refused_cleanly(fuzz_cases: Any) -> None:
    rng = np.random.default_rng(SEED)
    cases = fuzz_cases((PointCloudError,), 2.0)
    kinds: dict[str, int] = {}
    for index in range(CASES):
        wide = index % 100 == 0  # a thousand fields now and then: a big layout is checked in linear time
        cloud = Cloud(rng, wide)
        what, dtype = _mutate(cloud, rng)
        kinds[what] = kinds.get(what, 0) + 1
        cases.run(f"case {index} ({what}, seed {SEED})", _case(cloud, dtype))
    assert min(kinds.values()) >= 40, kinds  # every kind of defect ran
    cases.check(minimum=CASES, memory_mb=200)
