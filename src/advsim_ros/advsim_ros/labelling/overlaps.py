"""Gates across tracks: one object labelled twice, and a pedestrian or cyclist that is part of a vehicle.

Each track is judged against the tracks that passed every other gate. A track whose centre lies
inside another's box (grown by ``inside_margin``) at ``max_share_inside`` or more of its own frames is

- ``duplicate`` when both are of one class: of the two, the one with fewer detections (then lower
  confidence) is dropped, so the object keeps its best-observed track;
- ``inside_vehicle`` when it is a pedestrian or cyclist inside a vehicle: clusters of a van's or a
  truck's side read as a person (the vehicle is kept).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from advsim_ros.core.metrics import to_ego_frame
from advsim_ros.core.types import ActorClass, ActorTrack, BoolArray
from advsim_ros.labelling.config import GateConfig
from advsim_ros.labelling.refine import LabelledTrack

SMALL = (ActorClass.PEDESTRIAN, ActorClass.CYCLIST)


def share_inside(inner: ActorTrack, outer: ActorTrack, margin: float) -> float:
    """The share of inner's frames at which its centre lies inside outer's box (grown by margin [m])."""
    _, mine, theirs = np.intersect1d(inner.stamps_ns, outer.stamps_ns, assume_unique=True, return_indices=True)
    if mine.size == 0:
        return 0.0
    local = to_ego_frame(inner.centers[mine, :2], outer.centers[theirs, :2], outer.yaws[theirs])
    half = outer.size[:2] / 2.0 + margin
    inside: BoolArray = np.all(np.abs(local) <= half, axis=1)
    return float(np.count_nonzero(inside)) / float(inner.stamps_ns.shape[0])


def gate_overlaps(tracks: Sequence[LabelledTrack], gates: GateConfig) -> list[LabelledTrack]:
    """The tracks with ``duplicate`` and ``inside_vehicle`` added to the gates they failed (order kept)."""
    failed: dict[int, str] = {}
    kept: list[int] = []

    def overlapping(index: int, other: int) -> bool:
        inner, outer = tracks[index].track, tracks[other].track
        limit, margin = gates.max_share_inside, gates.inside_margin
        return share_inside(inner, outer, margin) >= limit or share_inside(outer, inner, margin) >= limit

    best_first = sorted(
        (i for i, item in enumerate(tracks) if item.accepted),
        key=lambda i: (-tracks[i].detections, -tracks[i].confidence, i),
    )
    for index in best_first:
        actor_class = tracks[index].track.actor_class
        if any(tracks[other].track.actor_class is actor_class and overlapping(index, other) for other in kept):
            failed[index] = "duplicate"
        else:
            kept.append(index)
    vehicles = [i for i in kept if tracks[i].track.actor_class is ActorClass.VEHICLE]
    for index in kept:
        small = tracks[index].track
        if small.actor_class in SMALL and any(
            share_inside(small, tracks[vehicle].track, gates.inside_margin) >= gates.max_share_inside
            for vehicle in vehicles
        ):
            failed[index] = "inside_vehicle"
    return [
        dataclasses.replace(item, rejected=(*item.rejected, failed[i])) if i in failed else item
        for i, item in enumerate(tracks)
    ]
