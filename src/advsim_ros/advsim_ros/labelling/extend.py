"""A parked vehicle was there before it was first seen whole: its track extended over the sweeps that show pieces of it.

Far away or behind other parked cars a vehicle's returns break into clusters too small or too
thin to be a car (pieces classed pedestrian or other, or under ``tracker.min_points``), so its
track starts only when it comes close. A static track has one box for its whole span; before its
first and after its last sweep, every sweep whose candidates of any class (not those of another
accepted track) have their centres in that box and at least ``tracker.min_points`` returns
between them supports the box there. The track grows over supported sweeps while the gaps
between them are at most ``tracker.max_misses`` sweeps, by at most its own span each way (the
pieces confirm a box its own detections found), and stops where another accepted track (a
second vehicle, a pedestrian or cyclist) would overlap it.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from advsim_ros.core.metrics import to_ego_frame
from advsim_ros.core.types import ActorClass, IntArray
from advsim_ros.labelling.config import LabellingConfig
from advsim_ros.labelling.detection import Candidates
from advsim_ros.labelling.evaluation import overlap_frames
from advsim_ros.labelling.refine import LabelledTrack


def _support(item: LabelledTrack, candidates: Candidates, free: IntArray, frames: int, margin: float) -> IntArray:
    """(F,) returns per frame of the free candidates whose centres lie in the track's box (grown by margin)."""
    track = item.track
    boxes = candidates.boxes[free]
    centre = np.broadcast_to(track.centers[0, :2], (free.shape[0], 2))
    local = to_ego_frame(boxes[:, :2], centre, np.full(free.shape[0], track.yaws[0]))
    inside = np.all(np.abs(local) <= track.size[:2] / 2.0 + margin, axis=1)
    rows = free[inside]
    support: IntArray = np.bincount(candidates.frames[rows], weights=candidates.num_points[rows], minlength=frames)
    return support.astype(np.int64)


def _reach(supported: np.ndarray, start: int, step: int, max_gap: int) -> int:
    """The farthest supported frame from start in direction step with gaps of at most max_gap frames."""
    reached, gap, frame = start, 0, start + step
    while 0 <= frame < supported.shape[0] and gap <= max_gap:
        if supported[frame]:
            reached, gap = frame, 0
        else:
            gap += 1
        frame += step
    return reached


def extend_static(
    tracks: Sequence[LabelledTrack], candidates: Candidates, frame_stamps_ns: IntArray, config: LabellingConfig
) -> list[LabelledTrack]:
    """The tracks, accepted static vehicles extended over the sweeps that show pieces of them (order kept)."""
    result = list(tracks)
    accepted = [index for index, item in enumerate(result) if item.accepted]
    taken = np.zeros(candidates.count, dtype=bool)
    for index in accepted:
        taken[result[index].rows] = True
    free = np.flatnonzero(~taken)
    stamps = np.asarray(frame_stamps_ns)
    margin = config.gates.inside_margin
    for index in accepted:
        item = result[index]
        if not item.static or item.track.actor_class is not ActorClass.VEHICLE:
            continue
        track = item.track
        supported = _support(item, candidates, free, stamps.shape[0], margin) >= config.tracker.min_points
        first, last = np.searchsorted(stamps, track.stamps_ns[[0, -1]])
        supported[first : last + 1] = True
        # Pieces confirm a box its own detections found; they never more than double its span.
        length = int(last - first) + 1
        start = max(_reach(supported, int(first), -1, config.tracker.max_misses), int(first) - length)
        end = min(_reach(supported, int(last), 1, config.tracker.max_misses), int(last) + length)
        if (start, end) == (first, last):
            continue
        span = end - start + 1
        nearest = np.clip(np.arange(start, end + 1) - first, 0, track.stamps_ns.shape[0] - 1)  # edge poses outside
        grown = dataclasses.replace(
            track, stamps_ns=stamps[start : end + 1], centers=track.centers[nearest], yaws=track.yaws[nearest]
        )
        # Never into frames where another accepted track overlaps it (a second vehicle, a pedestrian inside it).
        clash = np.zeros(span, dtype=bool)
        for other in accepted:
            if other != index:
                clash |= overlap_frames(grown, result[other].track, margin)
        own = np.arange(start, end + 1)
        before = np.flatnonzero(clash & (own < first))
        after = np.flatnonzero(clash & (own > last))
        low = start + (int(before.max()) + 1 if before.size else 0)
        high = start + (int(after.min()) - 1 if after.size else span - 1)
        keep = slice(low - start, high - start + 1)
        grown = dataclasses.replace(
            grown, stamps_ns=grown.stamps_ns[keep], centers=grown.centers[keep], yaws=grown.yaws[keep]
        )
        result[index] = dataclasses.replace(item, track=grown, span=high - low + 1)
    return result
