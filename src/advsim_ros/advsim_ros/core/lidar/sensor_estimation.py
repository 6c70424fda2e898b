"""The sensor model of a log estimated from its own sweeps: beam elevations and origins, azimuth step, range limits.

Which beam measured each point comes, in order of preference, from a ``ring`` field, the
firing order of the points (each beam one counter-clockwise turn, from a start angle found
here) or the peaks of the elevation histogram (see core.lidar.sensor for the conventions).
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence

import numpy as np

from advsim_ros.core.lidar.sensor import (
    RING_FIELD,
    BeamRows,
    nearest_beam_rows,
    scan_order_segments,
    spherical,
    xyz_of,
)
from advsim_ros.core.types import FloatArray, IntArray, ScenarioError, SensorModel, Sweep

ESTIMATION_NEAREST = 2.0  # returns nearer than this (planar) are left out of the beam fits [m]
ESTIMATION_MAX_HEIGHT = 0.5  # a fitted beam origin farther than this from the sensor origin is not believed [m]
_ORDER_AGREEMENT = 0.75  # share of sampled sweeps that must show the same number of scan-order turns
_HISTOGRAM_BIN = np.deg2rad(0.01)  # elevation histogram bin for sweeps without ring or order [rad]
_MIN_BEAM_SEPARATION = np.deg2rad(0.15)  # closest two beams may be when found from the histogram [rad]


class SensorEstimationError(ScenarioError):
    """The sweeps do not show a spinning LiDAR's structure; the message says what is missing."""


def estimate_scan_start(azimuths: FloatArray, elevations: FloatArray) -> float:
    """The start angle [rad] of the sensor's turns: the one that keeps each turn's elevations tightest.

    A wrong start lends the first points of every turn to the turn before, whose beam
    points elsewhere; the within-turn spread of elevations is smallest at the true start.
    """

    def spread(start: float) -> float:
        labels = scan_order_segments(azimuths, start)
        if labels is None:
            return np.inf
        count = np.bincount(labels).astype(np.float64)
        total = np.bincount(labels, weights=elevations)
        squares = np.bincount(labels, weights=elevations * elevations)
        return float(np.sum(squares - total * total / np.maximum(count, 1.0)))

    coarse = np.deg2rad(np.arange(-180.0, 180.0, 10.0))
    best = float(coarse[int(np.argmin([spread(float(start)) for start in coarse]))])
    fine = best + np.deg2rad(np.arange(-10.0, 10.0, 0.25))
    return float(fine[int(np.argmin([spread(float(start)) for start in fine]))])


def _label_sweeps(sweeps: Sequence[Sweep]) -> tuple[str, list[IntArray | None] | None, float]:
    """Where beam labels come from, each sweep's labels (None where its order breaks), and the scan start [rad]."""
    names = sweeps[0].points.dtype.names or ()
    if RING_FIELD in names:
        return "ring_field", [sweep.points[RING_FIELD].astype(np.int64) for sweep in sweeps], 0.0
    geometries = [spherical(xyz_of(sweep.points)) for sweep in sweeps]
    first = geometries[0]
    usable = first.ranges > 1e-3
    scan_start = estimate_scan_start(first.azimuths[usable], first.elevations[usable]) if np.sum(usable) > 1 else 0.0
    segments = [scan_order_segments(g.azimuths, scan_start, g.ranges > 1e-3) for g in geometries]
    counts = np.array([0 if labels is None else int(labels[-1]) + 1 for labels in segments])
    values, votes = np.unique(counts, return_counts=True)
    typical = int(values[np.argmax(votes)])
    # The order is trusted when most sweeps show the same number of turns (a cut-off last sweep may not).
    if typical >= 2 and votes.max() >= _ORDER_AGREEMENT * len(sweeps):
        found = [labels if count == typical else None for labels, count in zip(segments, counts, strict=True)]
        return "scan_order", found, scan_start
    return "elevation", None, 0.0


def _histogram_beams(elevations: FloatArray) -> FloatArray:
    """Beam elevations (descending) as the peaks of the elevation histogram."""
    from scipy.signal import find_peaks

    low, high = (
        float(elevations.min()) - 2 * _HISTOGRAM_BIN,
        float(elevations.max()) + 2 * _HISTOGRAM_BIN,
    )  # room for edge peaks
    bins = max(int(np.ceil((high - low) / _HISTOGRAM_BIN)), 1)
    counts, edges = np.histogram(elevations, bins=bins, range=(low, high + _HISTOGRAM_BIN))
    centres = 0.5 * (edges[:-1] + edges[1:])
    distance = max(int(_MIN_BEAM_SEPARATION / _HISTOGRAM_BIN), 1)
    peaks, _ = find_peaks(counts, distance=distance, height=max(5.0, 1e-4 * elevations.shape[0]))
    if peaks.size < 2:
        raise SensorEstimationError("the elevation histogram shows fewer than two beams")
    # Refine each peak to the mean elevation of the points nearest to it.
    guesses = centres[peaks][::-1]
    rows = nearest_beam_rows(elevations, guesses)
    sums = np.bincount(rows, weights=elevations, minlength=guesses.shape[0])
    sizes = np.bincount(rows, minlength=guesses.shape[0])
    refined: FloatArray = np.where(sizes > 0, sums / np.maximum(sizes, 1), guesses)
    return refined


def _azimuth_step(per_sweep: Sequence[tuple[FloatArray, IntArray]]) -> float:
    """The firing step [rad]: median spacing of sorted azimuths within each well-filled row of each sweep."""
    steps: list[float] = []
    for azimuths, rows in per_sweep:
        order = np.lexsort((azimuths, rows))
        sorted_rows, sorted_azimuths = rows[order], azimuths[order]
        same_row = sorted_rows[1:] == sorted_rows[:-1]
        gaps = np.diff(sorted_azimuths)
        row_sizes = np.bincount(sorted_rows[1:][same_row])
        for row in np.flatnonzero(row_sizes >= 100):
            row_gaps = gaps[same_row & (sorted_rows[1:] == row)]
            row_gaps = row_gaps[row_gaps > 1e-6]
            if row_gaps.size:
                steps.append(float(np.median(row_gaps)))
    if not steps:
        raise SensorEstimationError("no beam holds 100 points: cannot estimate the azimuth resolution")
    return float(np.median(steps))


def _fit_beam(planar: FloatArray, height: FloatArray) -> tuple[float, float]:
    """Elevation [rad] and origin height [m] of one beam: the line height = origin + planar * tan(elevation).

    A spinning LiDAR's lasers sit at different heights, so near returns of one beam do not
    share one elevation seen from the sensor origin (about 1 deg at 10 m on the HDL-64E);
    a line through (planar distance, height) fits both. Two passes drop the returns that
    miss the line by more than three robust deviations.
    """
    keep = planar > ESTIMATION_NEAREST
    if np.count_nonzero(keep) < 10:
        keep = np.ones(planar.shape[0], dtype=bool)
    slope, offset = 0.0, 0.0
    for _ in range(2):
        design = np.stack([planar[keep], np.ones(np.count_nonzero(keep))], axis=1)
        solution, *_ = np.linalg.lstsq(design, height[keep], rcond=None)
        slope, offset = float(solution[0]), float(solution[1])
        residual = height - (slope * planar + offset)
        spread = 1.4826 * float(np.median(np.abs(residual[keep]))) + 1e-3
        keep &= np.abs(residual) <= 3.0 * spread
    if abs(offset) > ESTIMATION_MAX_HEIGHT:  # not a laser offset: fall back to one origin
        return float(np.median(np.arctan2(height, planar))), 0.0
    return float(np.arctan(slope)), offset


def estimate_sensor_model(sweeps: Sequence[Sweep], max_sweeps: int = 8) -> BeamRows:
    """The sensor model (beam elevations, azimuth step, range limits) estimated from sweeps.

    Uses up to `max_sweeps` sweeps spread over the log. Where the points' beams are known
    (ring field or firing order) each beam's elevation and origin height come from a line
    fit (see ``_fit_beam``); otherwise beams are the peaks of the elevation histogram,
    all from the sensor origin.
    """
    if not sweeps:
        raise SensorEstimationError("no sweeps to estimate the sensor model from")
    if max_sweeps < 1:
        raise SensorEstimationError(f"max_sweeps must be >= 1, got {max_sweeps}")
    picks = np.unique(np.linspace(0, len(sweeps) - 1, min(max_sweeps, len(sweeps))).round().astype(int))
    chosen = [sweeps[int(index)] for index in picks]
    source, found, scan_start = _label_sweeps(chosen)
    labels: list[IntArray] | None = None
    if found is not None:  # sweeps whose order breaks do not take part
        chosen = [sweep for sweep, label in zip(chosen, found, strict=True) if label is not None]
        labels = [label for label in found if label is not None]
    geometries = [spherical(xyz_of(sweep.points)) for sweep in chosen]
    valid = [geometry.ranges > 1e-3 for geometry in geometries]  # (0, 0, 0) marks a missing return
    sizes = [int(np.count_nonzero(v)) for v in valid]
    ranges = np.concatenate([g.ranges[v] for g, v in zip(geometries, valid, strict=True)])
    elevations = np.concatenate([g.elevations[v] for g, v in zip(geometries, valid, strict=True)])
    azimuths = np.concatenate([g.azimuths[v] for g, v in zip(geometries, valid, strict=True)])
    if ranges.shape[0] < 1000:
        raise SensorEstimationError(f"only {ranges.shape[0]} valid points in the sampled sweeps")
    if labels is not None:
        ring = np.concatenate([label[v] for label, v in zip(labels, valid, strict=True)])
        if ring.min() < 0:
            raise SensorEstimationError(f"negative {RING_FIELD} values in the sweeps")
        count = int(ring.max()) + 1
        ring_elevation = np.full(count, np.nan)
        ring_height = np.zeros(count)
        planar = ranges * np.cos(elevations)
        height = ranges * np.sin(elevations)
        for value in range(count):
            members = ring == value
            if np.count_nonzero(members) >= 10:
                ring_elevation[value], ring_height[value] = _fit_beam(planar[members], height[members])
        seen = np.flatnonzero(np.isfinite(ring_elevation))
        order = seen[np.argsort(-ring_elevation[seen])]
        beam_elevations = ring_elevation[order]
        beam_heights = ring_height[order]
        if np.any(np.diff(beam_elevations) >= 0):
            raise SensorEstimationError("two beams share one elevation: the ring labels do not separate beams")
        ring_to_row = np.full(count, -1, dtype=np.int64)
        ring_to_row[order] = np.arange(order.shape[0])
        rows = ring_to_row[ring]
    else:
        beam_elevations = _histogram_beams(elevations)
        beam_heights = np.zeros(beam_elevations.shape[0])
        ring_to_row = np.zeros(0, dtype=np.int64)
        rows = nearest_beam_rows(elevations, beam_elevations)
    bounds = np.cumsum([0, *sizes])
    step = _azimuth_step([(azimuths[start:stop], rows[start:stop]) for start, stop in itertools.pairwise(bounds)])
    sensor = SensorModel(
        beam_elevations=beam_elevations,
        azimuth_resolution=step,
        min_range=float(np.floor(ranges.min() * 10.0) / 10.0),
        max_range=float(np.ceil(ranges.max())),
    )
    return BeamRows(
        sensor=sensor, source=source, ring_to_row=ring_to_row, beam_heights=beam_heights, scan_start=scan_start
    )
