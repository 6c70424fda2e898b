"""The auto-labeller end to end: a log's sweeps and ego poses in, labelled actor tracks out."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from advsim_ros.core.types import ActorClass, ActorTrack, FloatArray, IntArray, ScenarioError
from advsim_ros.labelling.config import LabellingConfig
from advsim_ros.labelling.detection import Candidates, concatenate, detect_sweep
from advsim_ros.labelling.extend import extend_static
from advsim_ros.labelling.overlaps import gate_overlaps, merge_duplicates
from advsim_ros.labelling.refine import LabelledTrack, refine_track
from advsim_ros.labelling.tracking import associate_forwards, link_fragments
from advsim_ros.stacks.modular.detector import CLASS_ORDER

_TRACKED_GROUPS = (  # tracked apart: (classes, gate and fewest returns: attributes of the tracker config)
    ((ActorClass.VEHICLE,), "gate", "min_points"),
    ((ActorClass.PEDESTRIAN, ActorClass.CYCLIST), "small_gate", "min_small_points"),
)


@dataclass(frozen=True, eq=False)
class LabellingResult:
    """Every track the labeller built; ``actors`` are those that passed the gates."""

    tracks: tuple[LabelledTrack, ...]
    num_candidates: int  # per-sweep candidate boxes, all classes

    @property
    def actors(self) -> tuple[ActorTrack, ...]:
        return tuple(labelled.track for labelled in self.tracks if labelled.accepted)

    def summary(self) -> dict[str, object]:
        rejected: dict[str, int] = {}
        for labelled in self.tracks:
            for gate in labelled.rejected:
                rejected[gate] = rejected.get(gate, 0) + 1
        classes: dict[str, int] = {}
        for actor in self.actors:
            classes[actor.actor_class.value] = classes.get(actor.actor_class.value, 0) + 1
        return {
            "candidates": self.num_candidates,
            "tracks": len(self.tracks),
            "actors": len(self.actors),
            "actors_by_class": classes,
            "rejected_by_gate": rejected,
        }


def label_candidates(
    candidates: Candidates, frame_stamps_ns: IntArray, ego_poses: FloatArray, config: LabellingConfig
) -> LabellingResult:
    """Track, smooth, refine and gate the candidates of a whole log (frames (F,), ego poses (F, 4, 4))."""
    times_s = (frame_stamps_ns - frame_stamps_ns[0]) * 1e-9
    ego_yaws = np.arctan2(ego_poses[:, 1, 0], ego_poses[:, 0, 0])
    labelled: list[LabelledTrack] = []

    def refine(rows: IntArray) -> LabelledTrack:
        return refine_track("pending", rows, candidates, frame_stamps_ns, times_s, ego_yaws, config)

    for group, gate_name, points_name in _TRACKED_GROUPS:
        codes = [CLASS_ORDER.index(actor_class) for actor_class in group]
        # Candidates with too few returns take no part: no track is started or continued from them.
        enough = candidates.num_points >= int(getattr(config.tracker, points_name))
        rows = np.flatnonzero(np.isin(candidates.classes, codes) & enough)
        if rows.shape[0] == 0:
            continue
        part = candidates.take(rows)
        xy = part.boxes[:, :2]
        gate = float(getattr(config.tracker, gate_name))
        tracks = associate_forwards(part.frames, xy, times_s, gate, config.tracker)
        tracks = link_fragments(tracks, part.frames, xy, times_s, config.tracker)
        for track_rows in sorted(tracks, key=lambda track: (int(part.frames[track[0]]), int(track[0]))):
            labelled.append(refine(rows[track_rows]))
    labelled.sort(key=lambda item: (int(item.track.stamps_ns[0]), item.track.actor_class.value))
    labelled = gate_overlaps(merge_duplicates(labelled, candidates, refine, config.gates), config.gates)
    if config.tracker.extend_static:
        labelled = extend_static(labelled, candidates, frame_stamps_ns, config)
    numbered = []
    for index, item in enumerate(labelled, start=1):
        track = item.track
        renamed = ActorTrack(
            actor_id=f"auto_{index}", actor_class=track.actor_class, size=track.size, stamps_ns=track.stamps_ns,
            centers=track.centers, yaws=track.yaws,
        )  # fmt: skip
        numbered.append(dataclasses.replace(item, track=renamed))
    return LabellingResult(tracks=tuple(numbered), num_candidates=candidates.count)


def label_sweeps(
    sweeps: Iterable[tuple[int, FloatArray]],
    frame_stamps_ns: IntArray,
    ego_poses: FloatArray,
    ego_T_sensor: FloatArray,
    config: LabellingConfig | None = None,
) -> LabellingResult:
    """Label a log from its sweeps ((frame index, (N, 3) points in the sensor frame [m]), one at a time).

    ``ego_poses`` (F, 4, 4) are T_world_ego at the frames ``frame_stamps_ns`` (F,).
    """
    config = config or LabellingConfig()
    stamps = np.asarray(frame_stamps_ns, dtype=np.int64)
    if ego_poses.shape != (stamps.shape[0], 4, 4):
        raise ScenarioError(f"label_sweeps: need one ego pose per frame, got {ego_poses.shape} for {stamps.shape[0]}")
    parts = [detect_sweep(xyz, ego_poses[frame], ego_T_sensor, frame, config) for frame, xyz in sweeps]
    return label_candidates(concatenate(parts), stamps, ego_poses, config)
