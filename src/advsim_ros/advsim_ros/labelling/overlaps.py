"""Gates across tracks: one object labelled twice, and a pedestrian or cyclist that is part of a vehicle.

Each track is judged against the tracks that passed every other gate, best observed first (more
detections, then higher confidence). Two tracks *overlap* at a frame when the centre of one lies
inside the other's box grown by ``inside_margin`` (two real objects never do).

- Two tracks of one class that overlap are one object: ``merge_duplicates`` joins their detections
  into one track (per frame the detection with more returns) when the joined track passes every
  gate; otherwise ``gate_overlaps`` drops the weaker one (``duplicate``) when it overlaps in at
  least ``max_share_inside`` of its frames, and else cuts it to its longest run of frames without
  overlap (dropped as ``duplicate`` when that run is shorter than ``min_detections`` frames).
- A pedestrian or cyclist inside a vehicle's box (clusters of a van's or a truck's side read as a
  person) is dropped (``inside_vehicle``) or cut the same way; the vehicle is kept. So no accepted
  pedestrian or cyclist has its centre inside an accepted vehicle's box at any frame.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence

import numpy as np

from advsim_ros.core.types import ActorClass, ActorTrack, BoolArray, IntArray
from advsim_ros.labelling.config import GateConfig
from advsim_ros.labelling.detection import Candidates
from advsim_ros.labelling.evaluation import SMALL, inside_frames, overlap_frames
from advsim_ros.labelling.refine import LabelledTrack

# refine(candidate rows sorted by frame) -> the labelled track of those rows
Refine = Callable[[IntArray], LabelledTrack]


def share_inside(inner: ActorTrack, outer: ActorTrack, margin: float) -> float:
    """The share of inner's frames at which its centre lies inside outer's box (grown by margin [m])."""
    return float(np.count_nonzero(inside_frames(inner, outer, margin))) / float(inner.stamps_ns.shape[0])


def _longest_run(keep: BoolArray) -> tuple[int, int]:
    """First index and length of the longest run of True."""
    best, start = (0, 0), None
    for index, value in enumerate([*keep.tolist(), False]):
        if value and start is None:
            start = index
        elif not value and start is not None:
            best = max(best, (index - start, -start))
            start = None
    return -best[1], best[0]


def _cut(item: LabelledTrack, overlap: BoolArray, min_frames: int) -> LabelledTrack | None:
    """The track cut to its longest run of frames without overlap; None when that is under min_frames."""
    first, count = _longest_run(~overlap)
    if count < min_frames:
        return None
    window = slice(first, first + count)
    track = item.track
    cut = dataclasses.replace(
        track, stamps_ns=track.stamps_ns[window], centers=track.centers[window], yaws=track.yaws[window]
    )
    return dataclasses.replace(item, track=cut, span=count, detections=min(item.detections, count))


def _best_first(tracks: Sequence[LabelledTrack]) -> list[int]:
    return sorted(
        (i for i, item in enumerate(tracks) if item.accepted),
        key=lambda i: (-tracks[i].detections, -tracks[i].confidence, i),
    )


def gate_overlaps(tracks: Sequence[LabelledTrack], gates: GateConfig) -> list[LabelledTrack]:
    """The tracks with ``duplicate`` and ``inside_vehicle`` added to the gates they failed, or cut (order kept)."""
    result = list(tracks)
    margin, limit = gates.inside_margin, gates.max_share_inside

    def judge(index: int, others: list[int], overlap: Callable[[ActorTrack, ActorTrack], BoolArray], gate: str) -> bool:
        """Drop or cut result[index] against result[others]; whether it is kept."""
        item = result[index]
        mask = np.zeros(item.track.stamps_ns.shape[0], dtype=bool)
        for other in others:
            mask |= overlap(item.track, result[other].track)
        if not mask.any():
            return True
        cut = _cut(item, mask, gates.min_detections) if np.mean(mask) < limit else None
        result[index] = cut if cut is not None else dataclasses.replace(item, rejected=(*item.rejected, gate))
        return cut is not None

    kept: list[int] = []
    for index in _best_first(result):
        same = [other for other in kept if result[other].track.actor_class is result[index].track.actor_class]
        if judge(index, same, lambda a, b: overlap_frames(a, b, margin), "duplicate"):
            kept.append(index)
    vehicles = [i for i in kept if result[i].track.actor_class is ActorClass.VEHICLE]
    for index in kept:
        if result[index].track.actor_class in SMALL:
            judge(index, vehicles, lambda a, b: inside_frames(a, b, margin), "inside_vehicle")
    return result


def _joined_rows(first: LabelledTrack, second: LabelledTrack, candidates: Candidates) -> IntArray:
    """Both tracks' candidate rows, one per frame (the one with more returns), sorted by frame."""
    rows = np.concatenate([first.rows, second.rows])
    order = np.lexsort((-candidates.num_points[rows], candidates.frames[rows]))
    rows = rows[order]
    frames = candidates.frames[rows]
    keep = np.r_[True, frames[1:] != frames[:-1]]
    joined: IntArray = rows[keep]
    return joined


def merge_duplicates(
    tracks: Sequence[LabelledTrack], candidates: Candidates, refine: Refine, gates: GateConfig
) -> list[LabelledTrack]:
    """Accepted tracks of one class that overlap, joined into one track where the joined one passes every gate.

    The weaker of a joined pair is marked ``duplicate`` (its detections now belong to the other).
    """
    result = list(tracks)
    merged = True
    while merged:
        merged = False
        order = [i for i in _best_first(result) if result[i].rows.size]
        for position, index in enumerate(order):
            for other in order[position + 1 :]:
                first, second = result[index], result[other]
                if first.track.actor_class is not second.track.actor_class:
                    continue
                if not overlap_frames(first.track, second.track, gates.inside_margin).any():
                    continue
                joined = refine(_joined_rows(first, second, candidates))
                if joined.accepted and joined.track.actor_class is first.track.actor_class:
                    result[index] = joined
                    result[other] = dataclasses.replace(second, rejected=(*second.rejected, "duplicate"))
                    merged = True
                    break
            if merged:
                break
    return result
