"""Offline multi-object tracking over a whole log: forwards association, fragment linking, RTS smoothing.

1. Forwards: constant-velocity Kalman filters (state x, y, vx, vy in the world frame) and
   Hungarian assignment (scipy.optimize.linear_sum_assignment) of the sweep's candidates to
   the predicted tracks within a gate; a track survives ``max_misses`` sweeps without one.
2. Linking: the whole log is known, so fragments of one object (a track that broke while
   the object was occluded) are joined when each fragment's smoothed motion, carried
   forwards and backwards across the gap, reaches the other within ``link_distance``.
3. Smoothing: a Rauch-Tung-Striebel smoother (Rauch, Tung, Striebel, AIAA J. 1965) over
   the constant-velocity model gives every sweep of the track's span a position and a
   velocity, using the detections before and after it; missed sweeps are filled.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from advsim_ros.core.types import FloatArray, IntArray
from advsim_ros.labelling.config import OfflineTrackerConfig

_NO_MATCH = 1e6  # assignment cost outside the gate


def _transition(dt: float) -> tuple[FloatArray, FloatArray]:
    """Constant-velocity transition (4, 4) and process noise (4, 4) over dt [s], per unit acceleration variance."""
    transition = np.eye(4)
    transition[0, 2] = transition[1, 3] = dt
    block = np.array([[dt**4 / 4.0, dt**3 / 2.0], [dt**3 / 2.0, dt**2]])
    noise = np.zeros((4, 4))
    noise[np.ix_([0, 2], [0, 2])] = block
    noise[np.ix_([1, 3], [1, 3])] = block
    return transition, noise


@dataclass
class _Live:
    rows: list[int]
    state: FloatArray  # (4,)
    covariance: FloatArray  # (4, 4)
    misses: int = 0


def associate_forwards(
    frames: IntArray, xy: FloatArray, times_s: FloatArray, gate: float, config: OfflineTrackerConfig
) -> list[IntArray]:
    """Rows of the candidates (frame index (K,), world xy (K, 2) [m]) grouped into tracks, each sorted by frame.

    ``times_s`` (F,) are the frame times [s].
    """
    by_frame: dict[int, list[int]] = {}
    for row, frame in enumerate(frames.tolist()):
        by_frame.setdefault(frame, []).append(row)
    measurement = np.eye(2) * config.position_noise**2
    live: list[_Live] = []
    done: list[list[int]] = []
    previous_time: float | None = None
    for frame in range(times_s.shape[0]):
        time = float(times_s[frame])
        if previous_time is not None and live:
            transition, noise = _transition(time - previous_time)
            for track in live:
                track.state = transition @ track.state
                track.covariance = transition @ track.covariance @ transition.T + noise * config.acceleration_noise**2
        previous_time = time
        rows = by_frame.get(frame, [])
        matched_tracks: set[int] = set()
        matched_rows: set[int] = set()
        if live and rows:
            predicted = np.array([track.state[:2] for track in live])
            distance = np.linalg.norm(predicted[:, None, :] - xy[rows][None, :, :], axis=-1)
            cost = np.where(distance <= gate, distance, _NO_MATCH)
            track_index, row_index = linear_sum_assignment(cost)
            for t, r in zip(track_index.tolist(), row_index.tolist(), strict=True):
                if cost[t, r] >= _NO_MATCH:
                    continue
                track = live[t]
                innovation = xy[rows[r]] - track.state[:2]
                s = track.covariance[:2, :2] + measurement
                gain = track.covariance[:, :2] @ np.linalg.inv(s)
                track.state = track.state + gain @ innovation
                track.covariance = track.covariance - gain @ track.covariance[:2, :]
                track.rows.append(rows[r])
                track.misses = 0
                matched_tracks.add(t)
                matched_rows.add(r)
        for index, track in enumerate(live):
            if index not in matched_tracks:
                track.misses += 1
        for r, row in enumerate(rows):
            if r not in matched_rows:
                covariance = np.diag([config.position_noise**2] * 2 + [config.initial_speed_noise**2] * 2)
                live.append(_Live(rows=[row], state=np.r_[xy[row], 0.0, 0.0], covariance=covariance))
        done.extend(track.rows for track in live if track.misses > config.max_misses)
        live = [track for track in live if track.misses <= config.max_misses]
    done.extend(track.rows for track in live)
    return [np.array(rows, dtype=np.int64) for rows in done]


@dataclass(frozen=True, eq=False)
class Smoothed:
    """A track's smoothed states over every frame of its span."""

    frames: IntArray  # (T,) consecutive frame indices, first to last detection
    states: FloatArray  # (T, 4) x, y [m], vx, vy [m/s] in the world frame
    covariances: FloatArray  # (T, 4, 4)


def rts_smooth(
    track_frames: IntArray, track_xy: FloatArray, times_s: FloatArray, config: OfflineTrackerConfig
) -> Smoothed:
    """Kalman filter forwards and Rauch-Tung-Striebel smoother backwards over the track's span.

    ``track_frames`` (M,) strictly increasing frame indices with detections at ``track_xy`` (M, 2) [m].
    """
    first, last = int(track_frames[0]), int(track_frames[-1])
    span = np.arange(first, last + 1)
    count = span.shape[0]
    observed = np.full((count, 2), np.nan)
    observed[track_frames - first] = track_xy
    measurement = np.eye(2) * config.position_noise**2
    filtered = np.zeros((count, 4))
    filtered_cov = np.zeros((count, 4, 4))
    predicted = np.zeros((count, 4))
    predicted_cov = np.zeros((count, 4, 4))
    transitions = np.zeros((count, 4, 4))
    state = np.r_[observed[0], 0.0, 0.0]
    covariance = np.diag([config.position_noise**2] * 2 + [config.initial_speed_noise**2] * 2)
    for step in range(count):
        if step > 0:
            transition, noise = _transition(float(times_s[span[step]] - times_s[span[step - 1]]))
            transitions[step] = transition
            state = transition @ state
            covariance = transition @ covariance @ transition.T + noise * config.acceleration_noise**2
        predicted[step], predicted_cov[step] = state, covariance
        if step > 0 and np.all(np.isfinite(observed[step])):
            gain = covariance[:, :2] @ np.linalg.inv(covariance[:2, :2] + measurement)
            state = state + gain @ (observed[step] - state[:2])
            covariance = covariance - gain @ covariance[:2, :]
        filtered[step], filtered_cov[step] = state, covariance
    smoothed = filtered.copy()
    smoothed_cov = filtered_cov.copy()
    for step in range(count - 2, -1, -1):
        transition = transitions[step + 1]
        gain = filtered_cov[step] @ transition.T @ np.linalg.inv(predicted_cov[step + 1])
        smoothed[step] = filtered[step] + gain @ (smoothed[step + 1] - predicted[step + 1])
        smoothed_cov[step] = filtered_cov[step] + gain @ (smoothed_cov[step + 1] - predicted_cov[step + 1]) @ gain.T
    return Smoothed(frames=span, states=smoothed, covariances=smoothed_cov)


def link_fragments(
    tracks: list[IntArray], frames: IntArray, xy: FloatArray, times_s: FloatArray, config: OfflineTrackerConfig
) -> list[IntArray]:
    """Tracks with fragments of one object joined (see the module docstring), each sorted by frame."""
    tracks = [track for track in tracks if track.shape[0]]
    while True:
        smoothed = [rts_smooth(frames[track], xy[track], times_s, config) for track in tracks]
        ends = np.array([s.frames[-1] for s in smoothed])
        starts = np.array([s.frames[0] for s in smoothed])
        cost = np.full((len(tracks), len(tracks)), _NO_MATCH)
        for a, early in enumerate(smoothed):
            for b, late in enumerate(smoothed):
                gap = starts[b] - ends[a]
                if a == b or gap <= 0 or gap > config.link_gap:
                    continue
                dt = float(times_s[starts[b]] - times_s[ends[a]])
                forwards = early.states[-1, :2] + dt * early.states[-1, 2:]
                backwards = late.states[0, :2] - dt * late.states[0, 2:]
                miss = max(
                    float(np.linalg.norm(forwards - late.states[0, :2])),
                    float(np.linalg.norm(backwards - early.states[-1, :2])),
                )
                if miss <= config.link_distance:
                    cost[a, b] = miss
        if not np.any(cost < _NO_MATCH):
            return tracks
        rows, columns = linear_sum_assignment(cost)
        good = cost[rows, columns] < _NO_MATCH
        joined: dict[int, int] = dict(zip(rows[good].tolist(), columns[good].tolist(), strict=True))
        absorbed = set(joined.values())
        merged = []
        for index, track in enumerate(tracks):
            if index in absorbed:
                continue
            parts = [track]
            current = index
            while current in joined:
                current = joined[current]
                parts.append(tracks[current])
            merged.append(np.concatenate(parts))
        tracks = merged
