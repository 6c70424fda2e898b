"""From a smoothed track to a labelled actor: class, size, heading, confidence, and the quality gates.

- Class: the majority of the track's detections (vehicles are tracked apart from
  pedestrians and cyclists); its share is a gate.
- Static or moving: the smoothed speed and the net displacement over the span. A static
  track gets one pose for its whole span (the median of its detections, robust to the
  partial views of a parked car as the ego drives by); a moving one the smoothed path.
- Size: for vehicles a high quantile of the detected extents (a box fitted to a partial
  view is too short, never too long), clipped (18 m: trucks, buses, tankers are one track);
  height likewise (long vehicles may be taller); median for the others.
- Heading: from the motion where the track moves, otherwise from the shape (the axial
  mean of the detected box headings, weighted by their points), pointed the way the ego
  drives (parked cars mostly face the traffic of their side; the ambiguity does not
  change the box).
- Confidence in [0, 1]: mean detector score x share of sweeps detected over the span x
  class share.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from advsim_ros.core.geometry import wrap_angle
from advsim_ros.core.types import ActorClass, ActorTrack, FloatArray, IntArray
from advsim_ros.labelling.config import LabellingConfig
from advsim_ros.labelling.detection import Candidates
from advsim_ros.labelling.tracking import rts_smooth
from advsim_ros.stacks.modular.detector import CLASS_ORDER


@dataclass(frozen=True, eq=False)
class LabelledTrack:
    """One auto-labelled track, its confidence and the gates it failed (empty: it became an actor)."""

    track: ActorTrack
    confidence: float  # [0, 1]
    static: bool
    detections: int  # sweeps with a detection
    span: int  # sweeps from first to last detection
    class_share: float  # share of detections of the track's class
    rejected: tuple[str, ...]  # names of the failed gates
    height: float  # top above the ground [m]
    static_spread: float  # static tracks: median distance of the detections from their centre [m]
    rows: IntArray = field(default_factory=lambda: np.zeros(0, np.int64))  # its candidates (pipeline's numbering)
    lift: float = 0.0  # vehicles: median height of its own ground above the lowest ground nearby [m]

    @property
    def accepted(self) -> bool:
        return not self.rejected


def _axial_mean(angles: FloatArray, weights: FloatArray) -> float:
    """Mean orientation modulo pi (box headings are ambiguous by a half turn) [rad]."""
    doubled = np.sum(weights * np.exp(2j * angles))
    return float(np.angle(doubled) / 2.0)


def reanchor(boxes: FloatArray, sensor_xy: FloatArray, length: float, width: float) -> FloatArray:
    """(M, 2) box centres [m] moved so that boxes of the track's size keep each detection's sensor-facing edges.

    A detection of a partly seen object is as long as what the sensor saw (or the prior);
    the far edges are the uncertain ones, so the track's size grows the box away from the sensor.
    """
    cos, sin = np.cos(boxes[:, 2]), np.sin(boxes[:, 2])
    axes = (np.column_stack([cos, sin]), np.column_stack([-sin, cos]))
    centre = boxes[:, :2].copy()
    for axis, extent, size in zip(axes, (boxes[:, 3], boxes[:, 4]), (length, width), strict=True):
        side = np.sign(np.sum((sensor_xy - centre) * axis, axis=1))  # +1: the sensor is on the +axis side
        centre = centre - (side * 0.5 * (size - extent))[:, None] * axis
    return centre


def refine_track(
    track_id: str,
    rows: IntArray,
    candidates: Candidates,
    frame_stamps_ns: IntArray,
    times_s: FloatArray,
    ego_yaws: FloatArray,
    config: LabellingConfig,
) -> LabelledTrack:
    """The labelled actor of one track: its candidate rows (M,) sorted by frame."""
    gates = config.gates
    classes = candidates.classes[rows]
    votes = np.bincount(classes, minlength=len(CLASS_ORDER))
    code = int(np.argmax(votes))
    actor_class = CLASS_ORDER[code]
    class_share = float(votes[code] / rows.shape[0])
    boxes = candidates.boxes[rows]
    weights = candidates.num_points[rows].astype(np.float64)
    if actor_class is ActorClass.VEHICLE:
        quantile = config.vehicle_size_quantile
        length = min(float(np.quantile(boxes[:, 3], quantile)), config.max_vehicle_size[0])
        width = min(float(np.quantile(boxes[:, 4], quantile)), config.max_vehicle_size[1])
        height = float(np.quantile(candidates.heights[rows], quantile))
    else:
        length, width = float(np.median(boxes[:, 3])), float(np.median(boxes[:, 4]))
        height = float(np.median(candidates.heights[rows]))
    centres = reanchor(boxes, candidates.sensor_xy[rows], length, width)
    smoothed = rts_smooth(candidates.frames[rows], centres, times_s, config.tracker)
    frames = smoothed.frames
    span = frames.shape[0]
    speed = np.hypot(smoothed.states[:, 2], smoothed.states[:, 3])
    displacement = float(np.linalg.norm(smoothed.states[-1, :2] - smoothed.states[0, :2]))
    static = bool(np.median(speed) < gates.static_speed and displacement < gates.static_displacement)
    shape_yaw = _axial_mean(boxes[:, 2], weights)
    spread = 0.0
    if static:
        centre = np.median(centres, axis=0)
        spread = float(np.median(np.linalg.norm(centres - centre, axis=1)))
        xy = np.tile(centre, (span, 1))
        direction = float(np.angle(np.mean(np.exp(1j * ego_yaws[frames]))))  # the ego's mean heading meanwhile
        yaw = shape_yaw if abs(float(wrap_angle(shape_yaw - direction))) <= 0.5 * np.pi else shape_yaw + np.pi
        yaws = np.full(span, float(wrap_angle(yaw)))
    else:
        xy = smoothed.states[:, :2]
        motion = np.arctan2(smoothed.states[:, 3], smoothed.states[:, 2])
        # Where the track slows below the static speed its motion heading is noise: hold the nearest good one.
        good = speed >= gates.static_speed
        if np.any(good):
            index = np.arange(span)
            nearest = np.flatnonzero(good)[np.abs(index[:, None] - np.flatnonzero(good)[None, :]).argmin(axis=1)]
            yaws = np.asarray(wrap_angle(motion[nearest]), dtype=np.float64)
        else:
            yaws = np.full(span, shape_yaw)
    z = np.interp(frames, candidates.frames[rows], candidates.z[rows])
    detections = int(np.unique(candidates.frames[rows]).shape[0])
    ratio = detections / span
    confidence = float(np.mean(candidates.confidences[rows]) * ratio * class_share)
    lift = float(np.median(candidates.lifts[rows]))
    rejected: list[str] = []
    if detections < gates.min_detections:
        rejected.append("min_detections")
    if ratio < gates.min_detection_ratio:
        rejected.append("min_detection_ratio")
    if class_share < gates.min_class_share:
        rejected.append("min_class_share")
    if confidence < gates.min_confidence:
        rejected.append("min_confidence")
    if actor_class.value not in gates.classes:
        rejected.append("classes")
    if actor_class in (ActorClass.PEDESTRIAN, ActorClass.CYCLIST) and static and gates.small_must_move:
        rejected.append("small_must_move")
    if actor_class is ActorClass.VEHICLE:
        long = length >= gates.long_vehicle_length
        top = gates.long_vehicle_height if long else gates.vehicle_height[1]
        if not gates.vehicle_height[0] <= height <= top:
            rejected.append("vehicle_height")
        # Its ground 1 m up (the bottom of a hedge seen over parked cars): its top is that much higher too.
        if lift > gates.max_ground_lift and height + lift > top:
            rejected.append("max_ground_lift")
        if long and width < gates.long_vehicle_width:
            rejected.append("long_vehicle_width")
        if static and spread > gates.max_static_spread:
            rejected.append("max_static_spread")
        if not static:
            misalignment = np.abs(np.sin(boxes[:, 2] - yaws[candidates.frames[rows] - frames[0]]))
            limit = np.sin(np.deg2rad(gates.max_heading_misalignment_deg))
            if float(np.median(misalignment)) > limit:
                rejected.append("max_heading_misalignment_deg")
    track = ActorTrack(
        actor_id=track_id,
        actor_class=actor_class,
        size=np.array([max(length, 0.1), max(width, 0.1), max(height, 0.1)]),
        stamps_ns=frame_stamps_ns[frames],
        centers=np.column_stack([xy, z]),
        yaws=yaws,
    )
    return LabelledTrack(
        track=track,
        confidence=confidence,
        static=static,
        detections=detections,
        span=span,
        class_share=class_share,
        rejected=tuple(rejected),
        height=height,
        static_spread=spread,
        rows=np.asarray(rows, dtype=np.int64),
        lift=lift,
    )
