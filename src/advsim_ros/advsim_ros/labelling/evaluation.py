"""How well auto-labelled tracks agree with ground-truth tracks (bird's-eye view).

Per frame, the ground-truth boxes in scope (the wanted classes, within ``max_range`` of the
sensor) and the labelled boxes are paired by maximum total BEV IoU (Hungarian,
scipy.optimize.linear_sum_assignment); a pair with IoU >= ``iou_threshold`` is a match.
Labelled boxes outside the region the ground truth covers (``region``: for KITTI the
camera's field of view less its DontCare areas) are left out of precision unless matched.
A ground-truth track is *found* when at least ``track_fraction`` of its in-scope frames
match; a labelled track is *correct* when at least that share of its evaluated frames match.
Centre and heading errors are medians over matched pairs.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt
from scipy.optimize import linear_sum_assignment

from advsim_ros.core.geometry import bev_iou, wrap_angle
from advsim_ros.core.metrics import to_ego_frame
from advsim_ros.core.types import ActorClass, ActorTrack, FloatArray, IntArray, ScenarioError

BoolArray = npt.NDArray[np.bool_]
# region(frame index, (N, 2) world xy) -> (N,) whether a labelled box there can be checked against the truth
Region = Callable[[int, FloatArray], BoolArray]


@dataclass(frozen=True)
class EvaluationConfig:
    """What counts as a match; units beside each field."""

    iou_threshold: float = 0.5  # BEV IoU of a matched pair [1]
    track_fraction: float = 0.6  # share of a track's frames that must match [1]
    max_range: float = 40.0  # boxes farther than this from the sensor (planar) are out of scope [m]
    classes: tuple[str, ...] = ("vehicle",)  # actor classes evaluated

    def __post_init__(self) -> None:
        if not 0.0 < self.iou_threshold <= 1.0 or not 0.0 < self.track_fraction <= 1.0:
            raise ScenarioError("EvaluationConfig: iou_threshold and track_fraction must lie in (0, 1]")
        if not self.max_range > 0.0:
            raise ScenarioError(f"EvaluationConfig max_range: must be positive, got {self.max_range}")
        for name in self.classes:
            ActorClass(name)


@dataclass(frozen=True)
class LabellingScores:
    """Agreement of labelled tracks with the truth; NaN where nothing was there to measure."""

    frame_precision: float  # matched labelled boxes / evaluated labelled boxes
    frame_recall: float  # matched truth boxes / truth boxes in scope
    track_precision: float  # correct labelled tracks / labelled tracks with evaluated frames
    track_recall: float  # found truth tracks / truth tracks with frames in scope
    median_center_error: float  # over matched pairs [m]
    median_heading_error_deg: float  # over matched pairs, |wrapped difference| [deg]
    truth_tracks: int
    labelled_tracks: int
    truth_boxes: int
    labelled_boxes: int
    matched_boxes: int
    missed_truth_tracks: tuple[str, ...]  # ids of truth tracks not found
    wrong_labelled_tracks: tuple[str, ...]  # ids of labelled tracks not correct


def _boxes_at(tracks: Sequence[ActorTrack], stamp: int) -> tuple[list[int], FloatArray]:
    rows, boxes = [], []
    for index, track in enumerate(tracks):
        found = int(np.searchsorted(track.stamps_ns, stamp))
        if found < track.stamps_ns.shape[0] and int(track.stamps_ns[found]) == stamp:
            rows.append(index)
            center = track.centers[found]
            boxes.append([center[0], center[1], track.yaws[found], track.length, track.width])
    return rows, np.array(boxes, dtype=np.float64).reshape(-1, 5)


def _ratio(numerator: float, denominator: float) -> float:
    return float(numerator / denominator) if denominator > 0 else float("nan")


def evaluate_tracks(
    truth: Sequence[ActorTrack],
    labelled: Sequence[ActorTrack],
    frame_stamps_ns: IntArray,
    sensor_xy: FloatArray,
    config: EvaluationConfig | None = None,
    region: Region | None = None,
) -> LabellingScores:
    """Scores of `labelled` against `truth` over the frames (F,) with the sensor's world xy (F, 2) [m]."""
    config = config or EvaluationConfig()
    wanted = {ActorClass(name) for name in config.classes}
    truth = [track for track in truth if track.actor_class in wanted]
    labelled = [track for track in labelled if track.actor_class in wanted]
    truth_scope = np.zeros(len(truth), dtype=np.int64)
    truth_hits = np.zeros(len(truth), dtype=np.int64)
    label_scope = np.zeros(len(labelled), dtype=np.int64)
    label_hits = np.zeros(len(labelled), dtype=np.int64)
    centre_errors: list[float] = []
    heading_errors: list[float] = []
    for frame, stamp in enumerate(np.asarray(frame_stamps_ns).tolist()):
        truth_rows, truth_boxes = _boxes_at(truth, stamp)
        label_rows, label_boxes = _boxes_at(labelled, stamp)
        origin = sensor_xy[frame]
        truth_in = np.hypot(*(truth_boxes[:, :2] - origin).T) <= config.max_range
        label_in = np.hypot(*(label_boxes[:, :2] - origin).T) <= config.max_range
        if region is not None and label_boxes.shape[0]:
            label_in &= region(frame, label_boxes[:, :2])
        matched_truth = np.zeros(len(truth_rows), dtype=bool)
        matched_label = np.zeros(len(label_rows), dtype=bool)
        if truth_rows and label_rows:
            iou = bev_iou(truth_boxes[:, None, :], label_boxes[None, :, :])
            rows, columns = linear_sum_assignment(-iou)
            good = iou[rows, columns] >= config.iou_threshold
            for row, column in zip(rows[good].tolist(), columns[good].tolist(), strict=True):
                matched_truth[row] = matched_label[column] = True
                if truth_in[row]:
                    centre_errors.append(float(np.hypot(*(truth_boxes[row, :2] - label_boxes[column, :2]))))
                    heading_errors.append(abs(float(wrap_angle(truth_boxes[row, 2] - label_boxes[column, 2]))))
        # A labelled box matched to an in-scope truth box is evaluated even where the region says no.
        label_eval = label_in.copy()
        if truth_rows and label_rows:
            for row, column in zip(rows[good].tolist(), columns[good].tolist(), strict=True):
                label_eval[column] |= bool(truth_in[row])
        for position, row in enumerate(truth_rows):
            if truth_in[position]:
                truth_scope[row] += 1
                truth_hits[row] += int(matched_truth[position])
        for position, row in enumerate(label_rows):
            if label_eval[position]:
                label_scope[row] += 1
                label_hits[row] += int(matched_label[position])
    truth_seen = truth_scope > 0
    label_seen = label_scope > 0
    found = truth_seen & (truth_hits >= config.track_fraction * truth_scope)
    correct = label_seen & (label_hits >= config.track_fraction * label_scope)
    return LabellingScores(
        frame_precision=_ratio(label_hits.sum(), label_scope.sum()),
        frame_recall=_ratio(truth_hits.sum(), truth_scope.sum()),
        track_precision=_ratio(correct.sum(), label_seen.sum()),
        track_recall=_ratio(found.sum(), truth_seen.sum()),
        median_center_error=float(np.median(centre_errors)) if centre_errors else float("nan"),
        median_heading_error_deg=float(np.rad2deg(np.median(heading_errors))) if heading_errors else float("nan"),
        truth_tracks=int(truth_seen.sum()),
        labelled_tracks=int(label_seen.sum()),
        truth_boxes=int(truth_scope.sum()),
        labelled_boxes=int(label_scope.sum()),
        matched_boxes=int(truth_hits.sum()),
        missed_truth_tracks=tuple(truth[i].actor_id for i in np.flatnonzero(truth_seen & ~found).tolist()),
        wrong_labelled_tracks=tuple(labelled[i].actor_id for i in np.flatnonzero(label_seen & ~correct).tolist()),
    )


KITTI_IMAGE_WIDTH = 1242  # left colour camera image width of KITTI tracking sequences [px]
KITTI_IMAGE_HEIGHT = 375  # [px]
_KITTI_PROBE_HEIGHT = -0.9  # a box centre of a car sits about this far below the Velodyne [m]


def _kitti_projection(calib: str) -> FloatArray:
    for line in calib.splitlines():
        key, _, values = line.partition(":")
        if key.strip() == "P2":
            return np.array(values.split(), dtype=np.float64).reshape(3, 4)
    raise ScenarioError("KITTI calibration has no P2 (left colour camera) row")


def _kitti_dontcare(labels: str) -> dict[int, FloatArray]:
    boxes: dict[int, list[list[float]]] = {}
    for line in labels.splitlines():
        columns = line.split()
        if len(columns) >= 10 and columns[2] == "DontCare":
            boxes.setdefault(int(columns[0]), []).append([float(value) for value in columns[6:10]])
    return {frame: np.array(rows) for frame, rows in boxes.items()}


def kitti_label_region(calib_text: str, labels_text: str, T_rect_velo: FloatArray, world_T_velo: FloatArray) -> Region:
    """Where KITTI tracking labels exist: inside the left colour camera's image and outside its DontCare boxes.

    ``world_T_velo`` (F, 4, 4) are the Velodyne poses of the frames the region is asked about.
    """
    projection = _kitti_projection(calib_text)
    dontcare = _kitti_dontcare(labels_text)
    velo_T_world = np.linalg.inv(world_T_velo)

    def region(frame: int, xy: FloatArray) -> BoolArray:
        world = np.column_stack([xy, np.zeros(xy.shape[0]), np.ones(xy.shape[0])])
        velo = world @ velo_T_world[frame].T
        velo[:, 2] = _KITTI_PROBE_HEIGHT
        camera = velo @ T_rect_velo.T
        pixels = camera @ projection.T
        depth = pixels[:, 2]
        u = pixels[:, 0] / np.where(depth > 0, depth, 1.0)
        v = pixels[:, 1] / np.where(depth > 0, depth, 1.0)
        inside: BoolArray = (depth > 0.5) & (u >= 0.0) & (u < KITTI_IMAGE_WIDTH)
        for u1, v1, u2, v2 in dontcare.get(frame, np.zeros((0, 4))).tolist():
            inside &= ~((u >= u1) & (u <= u2) & (v >= v1) & (v <= v2))
        return inside

    return region


def kitti_sequence_region(root: Path, seq: str, world_T_velo: FloatArray) -> Region:
    """``kitti_label_region`` for a KITTI tracking folder (calib/<seq>.txt, label_02/<seq>.txt)."""
    from advsim_ros.io.kitti import read_kitti_calibration

    calib = Path(root) / "calib" / f"{seq}.txt"
    labels = Path(root) / "label_02" / f"{seq}.txt"
    return kitti_label_region(
        calib.read_text(encoding="utf-8"),
        labels.read_text(encoding="utf-8"),
        read_kitti_calibration(calib),
        world_T_velo,
    )


SMALL = (ActorClass.PEDESTRIAN, ActorClass.CYCLIST)


def inside_frames(inner: ActorTrack, outer: ActorTrack, margin: float) -> BoolArray:
    """(T,) per frame of inner: its centre lies inside outer's box (grown by margin [m]) at that stamp."""
    _, mine, theirs = np.intersect1d(inner.stamps_ns, outer.stamps_ns, assume_unique=True, return_indices=True)
    result = np.zeros(inner.stamps_ns.shape[0], dtype=bool)
    if mine.size:
        local = to_ego_frame(inner.centers[mine, :2], outer.centers[theirs, :2], outer.yaws[theirs])
        result[mine] = np.all(np.abs(local) <= outer.size[:2] / 2.0 + margin, axis=1)
    return result


def overlap_frames(first: ActorTrack, second: ActorTrack, margin: float) -> BoolArray:
    """(T,) per frame of first: either centre lies inside the other's box at that stamp."""
    result = inside_frames(first, second, margin)
    back = inside_frames(second, first, margin)
    if back.any():
        result[np.isin(first.stamps_ns, second.stamps_ns[back])] = True
    return result


def duplicate_tracks(actors: Sequence[ActorTrack], margin: float = 0.0) -> int:
    """Tracks that are a second track of an object: of each pair of one class where, at some common frame, the
    centre of one lies inside the other's box (grown by margin [m]; two real objects never do), the later one."""
    duplicates = set()
    for index, track in enumerate(actors):
        for other in actors[:index]:
            if other.actor_class is track.actor_class and overlap_frames(track, other, margin).any():
                duplicates.add(index)
    return len(duplicates)


def small_inside_vehicles(actors: Sequence[ActorTrack], margin: float = 0.0) -> int:
    """Pedestrian and cyclist tracks whose centre lies inside a vehicle's box (grown by margin [m]) at some frame."""

    vehicles = [track for track in actors if track.actor_class is ActorClass.VEHICLE]
    return sum(
        1
        for track in actors
        if track.actor_class in SMALL and any(inside_frames(track, vehicle, margin).any() for vehicle in vehicles)
    )


def visible_frames(
    track: ActorTrack, frame_stamps_ns: IntArray, world_points: Callable[[int], FloatArray], min_points: int
) -> ActorTrack | None:
    """The track at the frames where at least min_points returns lie in its box (world_points: frame -> (N, 3) [m])."""
    keep = np.zeros(track.stamps_ns.shape[0], dtype=bool)
    index = {int(stamp): row for row, stamp in enumerate(np.asarray(frame_stamps_ns).tolist())}
    for row, stamp in enumerate(track.stamps_ns.tolist()):
        points = world_points(index[int(stamp)])
        local = points[:, :2] - track.centers[row, :2]
        cos, sin = np.cos(track.yaws[row]), np.sin(track.yaws[row])
        along, across = local[:, 0] * cos + local[:, 1] * sin, -local[:, 0] * sin + local[:, 1] * cos
        height = np.abs(points[:, 2] - track.centers[row, 2])
        inside = (np.abs(along) <= track.length / 2) & (np.abs(across) <= track.width / 2)
        inside &= height <= track.height / 2 + 0.2
        keep[row] = int(np.count_nonzero(inside)) >= min_points
    if not keep.any():
        return None
    return ActorTrack(track.actor_id, track.actor_class, track.size, track.stamps_ns[keep], track.centers[keep],
                      track.yaws[keep])  # fmt: skip


def static_track_scale(
    estimate: FloatArray, logged: FloatArray, frame_stamps_ns: IntArray, tracks: Sequence[ActorTrack]
) -> tuple[float, int]:
    """The scale of an odometry's translations that keeps labelled parked vehicles in one place, and their number.

    ``estimate`` and ``logged`` (F, 4, 4) are T_world_sensor at the frames; ``tracks`` are labelled in the
    logged world. Each vehicle seen at >= 20 frames that moves less than 1 m there is taken as parked; its
    centre in the sensor frame (from the logged poses: what the labels measured) is put in the world with
    the estimated rotations and s times the estimated translations; s minimises the spread of every parked
    vehicle's positions about its mean (least squares, closed form). 1: the odometry's scale agrees with the
    labels' (metric LiDAR measurements); 0.97: the odometry's path is 3 % too long. NaN without parked vehicles.
    """
    index = {int(stamp): row for row, stamp in enumerate(np.asarray(frame_stamps_ns).tolist())}
    numerator = denominator = 0.0
    used = 0
    for track in tracks:
        if track.actor_class is not ActorClass.VEHICLE or track.stamps_ns.shape[0] < 20:
            continue
        if float(np.linalg.norm(np.ptp(track.centers[:, :2], axis=0))) >= 1.0:
            continue
        frames = np.array([index[int(stamp)] for stamp in track.stamps_ns.tolist()])
        world = np.column_stack([track.centers, np.ones(frames.shape[0])])
        local = np.einsum("nij,nj->ni", np.linalg.inv(logged[frames]), world)[:, :3]
        rotated = np.einsum("nij,nj->ni", estimate[frames, :3, :3], local)[:, :2]
        moved = estimate[frames, :2, 3]
        rotated, moved = rotated - rotated.mean(axis=0), moved - moved.mean(axis=0)
        numerator -= float(np.sum(rotated * moved))
        denominator += float(np.sum(moved * moved))
        used += 1
    return (numerator / denominator if denominator > 0 else float("nan")), used
