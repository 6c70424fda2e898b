"""Spinning-LiDAR geometry: beam rows, ray directions and range images (estimation: sensor_estimation).

Conventions: the sensor frame has x forward, y left, z up. A point's azimuth is
``atan2(y, x)`` in [-pi, pi) [rad], its elevation ``atan2(z, hypot(x, y))`` [rad]. A range
image has one row per beam, row 0 the top beam (``SensorModel.beam_elevations`` is
descending), and one column per azimuth step: column ``c`` covers azimuths
``[c, c + 1) * azimuth_resolution`` counted counter-clockwise from +x in [0, 2 pi).

How points map to rows, in order of preference: a ``ring`` field (as Velodyne/Ouster ROS
drivers publish), the firing order of the points (KITTI ``.bin`` files list beam after
beam, each as one counter-clockwise turn), the nearest beam elevation. The first two are
exact; the last one misplaces near points of sensors whose lasers sit apart (the HDL-64E's
parallax reaches ~1 deg at 5 m), which is why it is only the fallback.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from advsim_ros.core.types import FloatArray, IntArray, ScenarioError, SensorModel

RING_FIELD = "ring"
_MIN_SEGMENT_FRACTION = 0.1  # a last turn smaller than this share of the median turn is a split-off


@dataclass(frozen=True, eq=False)
class SphericalPoints:
    """Per-point spherical coordinates of one sweep in the sensor frame."""

    xyz: FloatArray  # (N, 3) [m]
    ranges: FloatArray  # (N,) distance from the sensor origin [m]
    azimuths: FloatArray  # (N,) [rad] in [-pi, pi)
    elevations: FloatArray  # (N,) [rad]


def xyz_of(points: np.ndarray) -> FloatArray:
    """(N, 3) float64 x, y, z of a structured point array [m]."""
    return np.stack([points["x"], points["y"], points["z"]], axis=-1).astype(np.float64)


def spherical(xyz: FloatArray) -> SphericalPoints:
    """Range, azimuth and elevation of points (N, 3) in the sensor frame."""
    planar = np.hypot(xyz[:, 0], xyz[:, 1])
    return SphericalPoints(
        xyz=xyz,
        ranges=np.sqrt(planar * planar + xyz[:, 2] * xyz[:, 2]),
        azimuths=np.arctan2(xyz[:, 1], xyz[:, 0]),
        elevations=np.arctan2(xyz[:, 2], planar),
    )


def rotate(vectors: npt.ArrayLike, rotation: FloatArray) -> FloatArray:
    """vectors (N, 3) @ rotation.T, without BLAS (whose threads stall on a busy machine for (N, 3) products)."""
    result: FloatArray = np.einsum("ij,kj->ik", np.asarray(vectors, dtype=np.float64).reshape(-1, 3), rotation)
    return result


def unit_directions(elevations: npt.ArrayLike, azimuths: npt.ArrayLike) -> FloatArray:
    """(..., 3) unit ray directions in the sensor frame for elevations and azimuths [rad]."""
    elevation = np.asarray(elevations, dtype=np.float64)
    azimuth = np.asarray(azimuths, dtype=np.float64)
    cos_el = np.cos(elevation)
    return np.stack([cos_el * np.cos(azimuth), cos_el * np.sin(azimuth), np.sin(elevation)], axis=-1)


def azimuth_columns(azimuths: npt.ArrayLike, sensor: SensorModel) -> IntArray:
    """Range-image column of each azimuth [rad]."""
    turn = np.mod(np.asarray(azimuths, dtype=np.float64), 2.0 * np.pi)
    columns: IntArray = np.floor(turn / sensor.azimuth_resolution).astype(np.int64) % sensor.num_azimuths
    return columns


def column_azimuths(columns: npt.ArrayLike, sensor: SensorModel) -> FloatArray:
    """Centre azimuth [rad] in [-pi, pi) of range-image columns."""
    centre = (np.asarray(columns, dtype=np.float64) + 0.5) * sensor.azimuth_resolution
    wrapped: FloatArray = np.mod(centre + np.pi, 2.0 * np.pi) - np.pi
    return wrapped


def nearest_beam_rows(elevations: npt.ArrayLike, beam_elevations: FloatArray) -> IntArray:
    """Row of the beam whose elevation is nearest to each elevation [rad] (rows top to bottom)."""
    # Boundaries half-way between neighbouring beams; searchsorted needs ascending values.
    boundaries = 0.5 * (beam_elevations[:-1] + beam_elevations[1:])
    ascending = -boundaries
    rows: IntArray = np.searchsorted(ascending, -np.asarray(elevations, dtype=np.float64)).astype(np.int64)
    return rows


def scan_order_segments(
    azimuths: FloatArray, scan_start: float, valid: npt.NDArray[np.bool_] | None = None
) -> IntArray | None:
    """Beam index of each point from the firing order, or None when the order shows no turns.

    The points are taken to sweep counter-clockwise, one full turn per beam, each turn
    starting at `scan_start` [rad]: the azimuth is unwrapped along the point order and
    every full turn past the start is a new beam. A few stray points of a last, barely
    begun turn join the turn before.
    """
    if valid is not None and not np.all(valid):
        # Placeholders for missing returns have no azimuth: they take the beam of the return before them.
        kept = np.flatnonzero(valid)
        inner = scan_order_segments(azimuths[kept], scan_start)
        if inner is None or kept.size == 0:
            return None
        position = np.clip(np.searchsorted(kept, np.arange(azimuths.shape[0]), side="right") - 1, 0, None)
        placed: IntArray = inner[position]
        return placed
    if azimuths.shape[0] < 2:
        return None
    # Signed steps: firing jitter may step back a little; a gap without returns is less than half a turn.
    steps = np.mod(np.diff(azimuths) + np.pi, 2.0 * np.pi) - np.pi
    unwrapped = azimuths[0] + np.concatenate([[0.0], np.cumsum(steps)])
    base = scan_start + 2.0 * np.pi * np.floor((unwrapped[0] - scan_start) / (2.0 * np.pi))
    labels: IntArray = np.maximum(np.floor((unwrapped - base) / (2.0 * np.pi)).astype(np.int64), 0)
    last = int(labels.max())
    if last == 0:
        return None
    sizes = np.bincount(labels)
    if sizes[last] < _MIN_SEGMENT_FRACTION * np.median(sizes):
        labels[labels == last] = last - 1
    return labels


@dataclass(frozen=True, eq=False)
class BeamRows:
    """How the points of this log's sweeps map to range-image rows of its sensor model."""

    sensor: SensorModel
    source: str  # "ring_field", "scan_order" or "elevation": where the rows come from
    ring_to_row: IntArray  # (R,) row of each ring value / scan-order segment; -1 for a ring never seen
    beam_heights: FloatArray  # (B,) height of each beam's origin above the sensor origin [m] (zeros: one origin)
    scan_start: float = 0.0  # azimuth where each turn starts when rows come from the firing order [rad]

    def __post_init__(self) -> None:
        if self.source not in ("ring_field", "scan_order", "elevation"):
            raise ScenarioError(f"BeamRows: unknown source {self.source!r}")
        heights = np.asarray(self.beam_heights, dtype=np.float64)
        if heights.shape != (self.sensor.num_beams,):
            raise ScenarioError(
                f"BeamRows beam_heights: expected shape ({self.sensor.num_beams},), got {heights.shape}"
            )
        object.__setattr__(self, "beam_heights", heights)

    def origins(self, rows: IntArray) -> FloatArray:
        """(N, 3) origin of each row's beam in the sensor frame [m]."""
        origins = np.zeros((rows.shape[0], 3))
        origins[:, 2] = self.beam_heights[rows]
        return origins

    def cell_rays(self, rows: IntArray, columns: IntArray) -> tuple[FloatArray, FloatArray]:
        """Origins (N, 3) [m] and unit directions (N, 3) of range-image cells' centre rays."""
        directions = unit_directions(self.sensor.beam_elevations[rows], column_azimuths(columns, self.sensor))
        return self.origins(rows), directions

    def nearest_rows(self, xyz: FloatArray) -> IntArray:
        """(N,) row of the beam that passes nearest to each point (N, 3), counting each beam from its own origin."""
        planar = np.hypot(xyz[:, 0], xyz[:, 1])
        first_guess = nearest_beam_rows(np.arctan2(xyz[:, 2], planar), self.sensor.beam_elevations)
        # The beam's origin height depends on the row: one correction from the first guess settles it.
        corrected = np.arctan2(xyz[:, 2] - self.beam_heights[first_guess], planar)
        return nearest_beam_rows(corrected, self.sensor.beam_elevations)

    def point_rays(self, xyz: FloatArray, rows: IntArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Origins (N, 3), unit directions (N, 3) and ranges (N,) [m] of the rays that measured points (N, 3)."""
        origins = self.origins(rows)
        offsets = xyz - origins
        ranges = np.linalg.norm(offsets, axis=1)
        directions = offsets / np.maximum(ranges, 1e-9)[:, None]
        return origins, directions, ranges

    def rows(self, points: np.ndarray, geometry: SphericalPoints) -> IntArray:
        """(N,) row of every point of a sweep of this log (nearest elevation when the order breaks)."""
        labels: IntArray | None = None
        if self.source == "ring_field" and RING_FIELD in (points.dtype.names or ()):
            labels = points[RING_FIELD].astype(np.int64)
        elif self.source == "scan_order":
            segments = scan_order_segments(geometry.azimuths, self.scan_start, geometry.ranges > 1e-3)
            if segments is not None and int(segments[-1]) + 1 == self.ring_to_row.shape[0]:
                labels = segments
        nearest = nearest_beam_rows(geometry.elevations, self.sensor.beam_elevations)
        if labels is None:
            return nearest
        known = (labels >= 0) & (labels < self.ring_to_row.shape[0])
        rows = np.where(known, self.ring_to_row[np.clip(labels, 0, self.ring_to_row.shape[0] - 1)], -1)
        result: IntArray = np.where(rows >= 0, rows, nearest)
        return result


@dataclass(frozen=True, eq=False)
class RangeImage:
    """A sweep as a (beams x azimuth steps) image that still holds every point of the sweep.

    Each cell keeps its nearest point; points that lose their cell to a nearer one (two
    firings in one column, or a multi-return sensor) are listed in ``overflow`` so that
    ``source_indices`` always covers the whole sweep.
    """

    sensor: SensorModel
    ranges: FloatArray  # (B, A) range of the cell's point [m]; inf where the cell has no return
    intensities: FloatArray  # (B, A) intensity of the cell's point; nan where empty or unknown
    point_index: IntArray  # (B, A) index of the cell's point in the source sweep; -1 where empty
    overflow: IntArray  # (K,) indices of points that share a cell with a nearer point

    @classmethod
    def from_points(cls, points: np.ndarray, beam_rows: BeamRows) -> RangeImage:
        """Project a sweep's structured points (N,) into a range image."""
        sensor = beam_rows.sensor
        geometry = spherical(xyz_of(points))
        rows = beam_rows.rows(points, geometry)
        columns = azimuth_columns(geometry.azimuths, sensor)
        flat = rows * sensor.num_azimuths + columns
        # Nearest point wins its cell: sort by range and keep the first point of each cell.
        order = np.lexsort((geometry.ranges, flat))
        first = np.ones(order.shape[0], dtype=bool)
        first[1:] = flat[order][1:] != flat[order][:-1]
        winners = order[first]
        shape = (sensor.num_beams, sensor.num_azimuths)
        point_index = np.full(shape[0] * shape[1], -1, dtype=np.int64)
        point_index[flat[winners]] = winners
        ranges = np.full(shape[0] * shape[1], np.inf)
        ranges[flat[winners]] = geometry.ranges[winners]
        intensities = np.full(shape[0] * shape[1], np.nan)
        if "intensity" in (points.dtype.names or ()):
            intensities[flat[winners]] = points["intensity"][winners]
        return cls(
            sensor=sensor,
            ranges=ranges.reshape(shape),
            intensities=intensities.reshape(shape),
            point_index=point_index.reshape(shape),
            overflow=np.sort(order[~first]),
        )

    @property
    def source_indices(self) -> IntArray:
        """Indices of every source point: the cells' points, then the overflow."""
        cells = self.point_index[self.point_index >= 0]
        result: IntArray = np.concatenate([cells, self.overflow])
        return result

    def back_project(self) -> tuple[FloatArray, IntArray, IntArray]:
        """Cell-centre points of the filled cells: xyz (M, 3) [m], rows (M,), columns (M,)."""
        rows, columns = np.nonzero(np.isfinite(self.ranges))
        directions = unit_directions(self.sensor.beam_elevations[rows], column_azimuths(columns, self.sensor))
        xyz: FloatArray = directions * self.ranges[rows, columns][:, None]
        return xyz, rows.astype(np.int64), columns.astype(np.int64)

    def to_points(self, source: np.ndarray) -> np.ndarray:
        """The source sweep rebuilt from the image: every point with all its fields.

        Points whose cell range was changed in ``ranges`` move along their own ray (their
        direction is the measured one, not the cell centre), and take the cell intensity
        when the source has an intensity field; a cell set to inf drops its point.
        """
        kept = (self.point_index.ravel() >= 0) & np.isfinite(self.ranges.ravel())
        cells = np.flatnonzero(kept)
        cell_points = self.point_index.ravel()[cells]
        result = source[np.concatenate([cell_points, self.overflow])].copy()
        head = result[: cells.shape[0]]
        xyz = xyz_of(head)
        old_range = np.linalg.norm(xyz, axis=1)
        new_range = self.ranges.ravel()[cells]
        scale = np.divide(new_range, old_range, out=np.ones_like(old_range), where=old_range > 0)
        scale = np.where(np.isfinite(scale), scale, 1.0)
        for axis, name in enumerate(("x", "y", "z")):
            head[name] = (xyz[:, axis] * scale).astype(head.dtype[name])
        if "intensity" in (source.dtype.names or ()):
            intensity = self.intensities.ravel()[cells]
            keep = np.isnan(intensity)
            head["intensity"] = np.where(keep, head["intensity"], intensity).astype(head.dtype["intensity"])
        result[: cells.shape[0]] = head
        rebuilt: np.ndarray = result
        return rebuilt


def point_normals(geometry: SphericalPoints, rows: IntArray, sensor: SensorModel, valid: npt.ArrayLike) -> FloatArray:
    """(N, 3) unit surface normals from range-image neighbours, facing the sensor; zero where unknown.

    The tangents are the differences to the neighbouring returns on the same beam and on
    the beams above and below; a neighbour across a depth jump (range differing by more
    than 10 % + 0.2 m) does not count, so edges of objects get no normal rather than a wrong one.
    Points sharing a cell share its normal.
    """
    count = geometry.ranges.shape[0]
    usable = np.flatnonzero(np.asarray(valid, dtype=bool) & (rows >= 0) & (rows < sensor.num_beams))
    columns = azimuth_columns(geometry.azimuths[usable], sensor)
    beams, steps = sensor.num_beams, sensor.num_azimuths
    points = np.zeros((beams + 2, steps, 3), dtype=np.float32)  # an empty row above and below
    ranges = np.zeros((beams + 2, steps), dtype=np.float32)
    cell_rows = rows[usable] + 1
    points[cell_rows, columns] = geometry.xyz[usable]
    ranges[cell_rows, columns] = geometry.ranges[usable]
    centre_points, centre_ranges = points[1:-1], ranges[1:-1]
    tolerance = 0.1 * centre_ranges + 0.2

    def difference(neighbour_points: np.ndarray, neighbour_ranges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        usable_pair = (neighbour_ranges > 0) & (centre_ranges > 0)
        usable_pair &= np.abs(neighbour_ranges - centre_ranges) <= tolerance
        return neighbour_points - centre_points, usable_pair

    def tangent(
        ahead: tuple[np.ndarray, np.ndarray], behind: tuple[np.ndarray, np.ndarray]
    ) -> tuple[np.ndarray, np.ndarray]:
        (forward, forward_ok), (backward, backward_ok) = ahead, behind
        chosen = np.where(forward_ok[..., None], forward, -backward)
        chosen = np.where((forward_ok & backward_ok)[..., None], forward - backward, chosen)
        return chosen, forward_ok | backward_ok

    along, along_ok = tangent(
        difference(np.roll(centre_points, -1, axis=1), np.roll(centre_ranges, -1, axis=1)),
        difference(np.roll(centre_points, 1, axis=1), np.roll(centre_ranges, 1, axis=1)),
    )
    across, across_ok = tangent(difference(points[2:], ranges[2:]), difference(points[:-2], ranges[:-2]))
    normal = np.cross(along, across)
    length = np.linalg.norm(normal, axis=-1)
    good = along_ok & across_ok & (length > 1e-9)
    normal /= np.where(good, length, 1.0)[..., None]
    normal[np.einsum("ijk,ijk->ij", normal, centre_points) > 0.0] *= -1.0  # face the sensor
    normal[~good] = 0.0
    result = np.zeros((count, 3))
    result[usable] = normal[cell_rows - 1, columns]
    return result
