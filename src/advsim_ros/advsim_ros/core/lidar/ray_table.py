"""The rays of one sweep being rewritten, and the rewritten sweep assembled from them.

Logged points' rays come first, then rays added for cells with no logged return inside an
actor's angular window (footprint). Each ray keeps where it ends (its range) and whether it
returns; a re-cast ray keeps the nearer of its current end and the new hit (the merge).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from advsim_ros.core.lidar.boxes import AngularWindow, BoolArray
from advsim_ros.core.lidar.raycast import RayHits
from advsim_ros.core.lidar.sensor import BeamRows, SphericalPoints, column_azimuths
from advsim_ros.core.types import FloatArray, IntArray, SensorModel

_MERGE_EPSILON = 1e-3  # an inserted hit must be nearer than the current return by this much [m]


@dataclass(frozen=True, eq=False)
class SweepGeometry:
    """Per-point geometry of one logged sweep (cached between calls)."""

    spherical: SphericalPoints
    rows: IntArray  # (N,) beam row of every point
    valid: BoolArray  # (N,) the point is a return (not the (0, 0, 0) placeholder)
    beam_ranges: FloatArray  # (N,) distance of every point from its beam's origin [m]


def covered_cells(rows: IntArray, azimuths: FloatArray, sensor: SensorModel, tolerance: float) -> BoolArray:
    """(B, A) image of the cells whose centre lies within `tolerance` azimuth steps of a ray on the same row."""
    covered = np.zeros((sensor.num_beams, sensor.num_azimuths), dtype=bool)
    fractional = np.mod(azimuths, 2.0 * np.pi) / sensor.azimuth_resolution
    first = np.ceil(fractional - tolerance - 0.5).astype(np.int64)
    last = np.floor(fractional + tolerance - 0.5).astype(np.int64)
    for offset in range(int(np.ceil(2.0 * tolerance)) + 1):
        column = first + offset
        mask = column <= last
        covered[rows[mask], np.mod(column[mask], sensor.num_azimuths)] = True
    return covered


def _nearest_on_row(rows: IntArray, azimuths: FloatArray, candidates: IntArray, geometry: SweepGeometry) -> IntArray:
    """Per query (row, azimuth), the candidate logged point on the same row nearest in azimuth; -1 if none."""
    result = np.full(rows.shape[0], -1, dtype=np.int64)
    if candidates.size == 0 or rows.size == 0:
        return result
    span = 2.0 * np.pi + 1.0  # keys of different rows never mix
    keys = geometry.rows[candidates] * span + (geometry.spherical.azimuths[candidates] + np.pi)
    order = np.argsort(keys)
    sorted_keys, sorted_candidates = keys[order], candidates[order]
    queries = rows * span + (azimuths + np.pi)
    position = np.searchsorted(sorted_keys, queries)
    best_gap = np.full(rows.shape[0], np.inf)
    for offset in (-1, 0):
        index = np.clip(position + offset, 0, sorted_keys.shape[0] - 1)
        same_row = geometry.rows[sorted_candidates[index]] == rows
        gap = np.where(same_row, np.abs(sorted_keys[index] - queries), np.inf)
        better = gap < best_gap
        result[better] = sorted_candidates[index][better]
        best_gap = np.minimum(best_gap, gap)
    return result


class RayTable:
    """Every ray of one sweep being rewritten: the logged points' rays, then added cell rays."""

    def __init__(self, points: np.ndarray, geometry: SweepGeometry, beam_rows: BeamRows) -> None:
        self.points = points
        self.geometry = geometry
        self.beam_rows = beam_rows
        self.sensor = beam_rows.sensor
        count = points.shape[0]
        self.count = count
        self.stop = geometry.beam_ranges.copy()  # distance from the beam's origin where the ray ends [m]; inf: none
        self.returned = geometry.valid.copy()  # the ray gives a point
        self.intensity = np.zeros(count)  # intensity of changed rays
        self.changed = np.zeros(count, dtype=bool)
        # Added rays (cells with no logged return), as lists of chunks joined on demand.
        self.added_origins = np.zeros((0, 3))
        self.added_directions = np.zeros((0, 3))
        self.added_rows = np.zeros(0, dtype=np.int64)
        self.added_azimuths = np.zeros(0)
        self.added_elevations = np.zeros(0)
        self.added_stop = np.zeros(0)
        self.added_returned = np.zeros(0, dtype=bool)
        self.added_intensity = np.zeros(0)
        self.added_template = np.zeros(0, dtype=np.int64)  # logged point whose fields a new point copies; -1: none

    def logged_rays(self, indices: IntArray) -> tuple[FloatArray, FloatArray]:
        """Origins and unit directions of logged points' rays."""
        origins = self.beam_rows.origins(self.geometry.rows[indices])
        directions: FloatArray = (self.geometry.spherical.xyz[indices] - origins) / self.geometry.beam_ranges[
            indices, None
        ]
        return origins, directions

    def window_candidates(self, window: AngularWindow) -> tuple[IntArray, IntArray]:
        """Logged and added rays seen under the window (by direction, or by beam row for coverage)."""
        geometry = self.geometry
        rows_in = np.zeros(self.sensor.num_beams, dtype=bool)
        rows_in[window.rows(self.sensor)] = True
        relaxed = AngularWindow(
            window.center_azimuth, window.azimuth_low, window.azimuth_high, -np.pi, np.pi, window.full_turn
        )
        az_ok = relaxed.contains(geometry.spherical.azimuths, geometry.spherical.elevations)
        el = geometry.spherical.elevations
        el_ok = (el >= window.elevation_low) & (el <= window.elevation_high)
        logged = np.flatnonzero(az_ok & (el_ok | rows_in[geometry.rows]) & geometry.valid)
        added_az_ok = relaxed.contains(self.added_azimuths, self.added_elevations)
        added = np.flatnonzero(added_az_ok & rows_in[self.added_rows])
        return logged, added

    def uncovered_cells(
        self, window: AngularWindow, logged: IntArray, added: IntArray, tolerance: float
    ) -> tuple[IntArray, IntArray]:
        """Rows and columns of window cells that no ray within `tolerance` azimuth steps serves."""
        sensor = self.sensor
        rows = window.rows(sensor)
        columns = window.columns(sensor)
        if rows.size == 0 or columns.size == 0:
            return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
        covered = covered_cells(
            np.concatenate([self.geometry.rows[logged], self.added_rows[added]]),
            np.concatenate([self.geometry.spherical.azimuths[logged], self.added_azimuths[added]]),
            sensor,
            tolerance,
        )
        grid_rows = np.repeat(rows, columns.shape[0])
        grid_columns = np.tile(columns, rows.shape[0])
        open_cells = ~covered[grid_rows, grid_columns]
        return grid_rows[open_cells], grid_columns[open_cells]

    def add_rays(self, rows: IntArray, columns: IntArray, nearby: IntArray) -> IntArray:
        """Append cell rays (no return yet); their indices among the added rays.

        `nearby` are logged rays near the cells, where new points look for the fields to copy.
        """
        elevations = self.sensor.beam_elevations[rows]
        azimuths = column_azimuths(columns, self.sensor)
        origins, directions = self.beam_rows.cell_rays(rows, columns)
        start = self.added_rows.shape[0]
        self.added_origins = np.concatenate([self.added_origins, origins])
        self.added_directions = np.concatenate([self.added_directions, directions])
        self.added_rows = np.concatenate([self.added_rows, rows])
        self.added_azimuths = np.concatenate([self.added_azimuths, azimuths])
        self.added_elevations = np.concatenate([self.added_elevations, elevations])
        self.added_stop = np.concatenate([self.added_stop, np.full(rows.shape[0], np.inf)])
        self.added_returned = np.concatenate([self.added_returned, np.zeros(rows.shape[0], dtype=bool)])
        self.added_intensity = np.concatenate([self.added_intensity, np.zeros(rows.shape[0])])
        self.added_template = np.concatenate([self.added_template, self._templates(rows, azimuths, nearby)])
        return np.arange(start, self.added_rows.shape[0], dtype=np.int64)

    def _templates(self, rows: IntArray, azimuths: FloatArray, nearby: IntArray) -> IntArray:
        """For each new cell, the logged point of its row nearest in azimuth (-1 when the row has none).

        Searched among `nearby` logged points first (the window's), then the whole row.
        """
        geometry = self.geometry
        templates = _nearest_on_row(rows, azimuths, nearby, geometry)
        missing = np.flatnonzero(templates < 0)
        if missing.size:
            everyone = np.flatnonzero(np.isin(geometry.rows, np.unique(rows[missing])) & geometry.valid)
            templates[missing] = _nearest_on_row(rows[missing], azimuths[missing], everyone, geometry)
        return templates

    def update(
        self, logged: IntArray, added: IntArray, hits: RayHits, returns: BoolArray, displaced: BoolArray | None = None
    ) -> BoolArray:
        """Keep the nearer of the current end and the hit per ray; True where the hit won.

        hits/returns are ordered as logged rays then added rays. Where `displaced` is set the
        current end cannot be there any more (it lies inside the inserted actor), so any hit wins.
        """
        count = logged.shape[0]
        current = np.concatenate([self.stop[logged], self.added_stop[added]])
        nearer = hits.ranges < current - _MERGE_EPSILON
        if displaced is not None:
            nearer |= displaced & np.isfinite(hits.ranges)
        logged_win, added_win = nearer[:count], nearer[count:]
        chosen = logged[logged_win]
        self.stop[chosen] = hits.ranges[:count][logged_win]
        self.returned[chosen] = returns[:count][logged_win]
        self.intensity[chosen] = hits.intensity[:count][logged_win]
        self.changed[chosen] = True
        chosen_added = added[added_win]
        self.added_stop[chosen_added] = hits.ranges[count:][added_win]
        self.added_returned[chosen_added] = returns[count:][added_win]
        self.added_intensity[chosen_added] = hits.intensity[count:][added_win]
        result: BoolArray = nearer
        return result

    def rays(self, logged: IntArray, added: IntArray) -> tuple[FloatArray, FloatArray]:
        """Origins (N, 3) and unit directions (N, 3) of logged rays then added rays."""
        origins, directions = self.logged_rays(logged)
        return (
            np.concatenate([origins, self.added_origins[added]]).reshape(-1, 3),
            np.concatenate([directions, self.added_directions[added]]).reshape(-1, 3),
        )

    def assemble(self) -> np.ndarray:
        """The rewritten sweep: logged points that still return (changed ones moved along their ray), then new ones."""
        points = self.points
        names = points.dtype.names or ()
        keep = self.returned | ~self.geometry.valid  # (0, 0, 0) placeholders pass through as they came
        result = points[keep].copy()
        changed = np.flatnonzero(self.changed[keep])
        if changed.size:
            source = np.flatnonzero(keep)[changed]
            origins, directions = self.logged_rays(source)
            xyz = origins + directions * self.stop[source, None]
            _write_points(result, changed, xyz, self.intensity[source], names)
        new = np.flatnonzero(self.added_returned)
        if new.size == 0:
            return result
        extra = np.zeros(new.shape[0], dtype=points.dtype)
        templates = self.added_template[new]
        has_template = templates >= 0
        extra[has_template] = points[templates[has_template]]
        xyz = self.added_origins[new] + self.added_directions[new] * self.added_stop[new, None]
        _write_points(extra, np.arange(new.shape[0]), xyz, self.added_intensity[new], names)
        return np.concatenate([result, extra])


def _write_points(
    target: np.ndarray, indices: IntArray, xyz: FloatArray, intensity: FloatArray, names: Sequence[str]
) -> None:
    """Set x, y, z and (when the layout has it) intensity of target[indices], in each field's own type."""
    for axis, name in enumerate(("x", "y", "z")):
        target[name][indices] = xyz[:, axis].astype(target.dtype[name])
    if "intensity" in names:
        kind = target.dtype["intensity"]
        values = intensity
        if np.issubdtype(kind, np.integer):
            info = np.iinfo(kind)
            values = np.clip(np.rint(values), info.min, info.max)
        target["intensity"][indices] = values.astype(kind)
