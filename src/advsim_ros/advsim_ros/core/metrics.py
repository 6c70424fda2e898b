"""Planning metrics of one query and their aggregate over scenarios (AdvSim's evaluation, open loop).

One query is judged on the stack's plan (the SDV follows it), the human trajectory (the
logged ego poses) and the perturbed actors' futures, all in the world frame:
- collision up to 3 s and 5 s: the SDV's box on its plan overlaps an actor's box
  (oriented boxes, separating-axis test) at some plan time within the horizon;
- L2 to human at 3 s and 5 s: distance between the plan and the human trajectory at that
  time (both interpolated linearly in time) [m];
- lateral acceleration and jerk: the largest |v * yaw rate| [m/s^2] and the largest
  |d(longitudinal acceleration)/dt| [m/s^3] along the plan, by finite differences;
- detection AP at BEV IoU 0.7 and prediction L2 at 3 s and 5 s, when the stack publishes
  detections and predictions.
Horizons count from the plan's first stamp (the decision time). Only actors, detections and
ground truth inside x in [-72, 72] m, y in [-40, 40] m of the ego frame at the decision time
(the plan's first pose) count; actors outside never collide in these metrics. An actor counts
only at the plan stamps where it exists (``ActorFutures.present``: its observed span, see
core.futures); an actor that appears after the decision is judged in range where it appears.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from advsim_ros.core.futures import (
    ACTOR_EXTRAPOLATION,
    MAX_ACTOR_EXTRAPOLATION,
    ActorFutures,
    BoolArray,
    interpolate_trajectory,
)
from advsim_ros.core.futures import NS_PER_S as NS_PER_S  # re-exported: the modules that time plans take it here
from advsim_ros.core.geometry import bev_iou, boxes_overlap, wrap_angle
from advsim_ros.core.types import EgoGeometry, EgoTrajectory, FloatArray, Plan, ScenarioError


@dataclass(frozen=True)
class MetricsConfig:
    """Metric horizons, evaluation range and matching thresholds (params/scorer.yaml)."""

    horizons: tuple[float, ...] = (3.0, 5.0)  # times after the decision for collision and L2 metrics [s]
    x_range: tuple[float, float] = (-72.0, 72.0)  # evaluation range along the ego's heading [m]
    y_range: tuple[float, float] = (-40.0, 40.0)  # evaluation range to the ego's left [m]
    iou_threshold: float = 0.7  # BEV IoU for a detection to match a ground-truth box [1]
    prediction_match_radius: float = 2.0  # a prediction belongs to the nearest actor within this at its start [m]
    actor_extrapolation: float = ACTOR_EXTRAPOLATION  # an actor exists this long beyond its first/last observation [s]

    def __post_init__(self) -> None:
        name = type(self).__name__
        if not self.horizons or any(not np.isfinite(h) or h <= 0.0 for h in self.horizons):
            raise ScenarioError(f"{name}.horizons: need one or more positive times [s], got {self.horizons}")
        for key in ("x_range", "y_range"):
            low, high = getattr(self, key)
            if not (np.isfinite(low) and np.isfinite(high) and low < high):
                raise ScenarioError(f"{name}.{key}: need finite (low, high) with low < high, got {(low, high)}")
        if not 0.0 < self.iou_threshold <= 1.0:
            raise ScenarioError(f"{name}.iou_threshold: must be in (0, 1], got {self.iou_threshold}")
        if not self.prediction_match_radius > 0.0:
            raise ScenarioError(f"{name}.prediction_match_radius: must be positive, got {self.prediction_match_radius}")
        if not 0.0 <= self.actor_extrapolation <= MAX_ACTOR_EXTRAPOLATION:
            reach = self.actor_extrapolation
            raise ScenarioError(f"{name}.actor_extrapolation: must be in [0, {MAX_ACTOR_EXTRAPOLATION}] s, got {reach}")


@dataclass(frozen=True, eq=False)
class Kinematics:
    """Finite-difference kinematics of a planned trajectory."""

    lateral_acceleration: FloatArray  # (H-1,) v * yaw rate between consecutive poses [m/s^2]
    longitudinal_acceleration: FloatArray  # (H-2,) at the interior poses [m/s^2]
    jerk: FloatArray  # (H-3,) d(longitudinal acceleration)/dt between interior poses [m/s^3]


def plan_from_decision(plan: Plan, world_T_ego: FloatArray, decision_ns: int) -> Plan:
    """The plan with the SDV's pose at the decision time in front, as the metrics count horizons from it.

    Plans per the topic contract start one step after the decision; a plan that already
    starts at (or before) the decision time is returned as it is.
    """
    if int(plan.stamps_ns[0]) <= decision_ns:
        return plan
    yaw = float(np.arctan2(world_T_ego[1, 0], world_T_ego[0, 0]))
    return Plan(
        stamps_ns=np.concatenate([[decision_ns], plan.stamps_ns]),
        xy=np.vstack([world_T_ego[None, :2, 3], plan.xy]),
        yaws=np.unwrap(np.concatenate([[yaw], plan.yaws])),
    )


def plan_times(plan: Plan) -> FloatArray:
    """(H,) plan stamps relative to the first one [s]."""
    times: FloatArray = (plan.stamps_ns - plan.stamps_ns[0]).astype(np.float64) / NS_PER_S
    return times


def trajectory_kinematics(times: FloatArray, xy: FloatArray, yaws: FloatArray) -> Kinematics:
    """Speed, lateral acceleration, longitudinal acceleration and jerk by divided differences.

    The speed between poses k and k+1 is the displacement over the time step, signed by the
    mean heading (negative when reversing); the yaw rate is the wrapped heading change over
    the step. Divided differences are exact for polynomial motion of matching degree (a
    cubic position profile has exactly constant jerk).
    """
    if times.shape[0] < 2:
        empty = np.empty(0)
        return Kinematics(empty, empty, empty)
    step = np.diff(times)
    heading_change = wrap_angle(np.diff(yaws))
    mid_heading = yaws[:-1] + 0.5 * heading_change
    displacement = np.diff(xy, axis=0)
    speed = (displacement[:, 0] * np.cos(mid_heading) + displacement[:, 1] * np.sin(mid_heading)) / step
    lateral = speed * heading_change / step
    mid_times = times[:-1] + 0.5 * step
    longitudinal = np.diff(speed) / np.diff(mid_times)
    jerk = np.diff(longitudinal) / np.diff(times[1:-1]) if longitudinal.shape[0] >= 2 else np.empty(0)
    return Kinematics(lateral, longitudinal, jerk)


def human_at(human: EgoTrajectory, query_ns: npt.NDArray[np.int64]) -> tuple[FloatArray, FloatArray, BoolArray]:
    """The human (logged) ego poses at query stamps, with the mask of stamps the log covers."""
    return interpolate_trajectory(human.stamps_ns, human.xy, human.yaws, query_ns)


def to_ego_frame(points_xy: FloatArray, ego_xy: FloatArray, ego_yaw: float | FloatArray) -> FloatArray:
    """(..., 2) world points in the frame of an ego pose (x forward, y left) [m]; poses may be one per point."""
    offset = points_xy - ego_xy
    cos, sin = np.cos(ego_yaw), np.sin(ego_yaw)
    return np.stack([cos * offset[..., 0] + sin * offset[..., 1], -sin * offset[..., 0] + cos * offset[..., 1]], -1)


def in_range(points_xy: FloatArray, ego_xy: FloatArray, ego_yaw: float, config: MetricsConfig) -> BoolArray:
    """(...,) whether world points lie inside the evaluation range around the ego pose."""
    local = to_ego_frame(points_xy, ego_xy, ego_yaw)
    inside: BoolArray = (
        (local[..., 0] >= config.x_range[0])
        & (local[..., 0] <= config.x_range[1])
        & (local[..., 1] >= config.y_range[0])
        & (local[..., 1] <= config.y_range[1])
    )
    return inside


def require_aligned(plan: Plan, actors: ActorFutures) -> None:
    """ScenarioError unless the actors' futures have one state per plan stamp."""
    if actors.states.shape[1] != plan.stamps_ns.shape[0]:
        raise ScenarioError(
            f"actor futures have {actors.states.shape[1]} states per actor but the plan has "
            f"{plan.stamps_ns.shape[0]} poses: sample the futures at the plan's stamps",
        )


def actors_in_range(plan: Plan, actors: ActorFutures, config: MetricsConfig) -> BoolArray:
    """(N,) actors inside the evaluation range around the decision pose (the plan's first).

    Each is judged where it is at the decision or, if it appears later, where it first appears; an
    actor absent at every plan stamp never counts.
    """
    present = actors.present
    first_xy = actors.states[np.arange(actors.num_actors), np.argmax(present, axis=1), :2]
    inside = in_range(np.nan_to_num(first_xy), plan.xy[0], float(plan.yaws[0]), config)
    return present.any(axis=1) & inside


def collision_steps(plan: Plan, actors: ActorFutures, ego: EgoGeometry, config: MetricsConfig) -> BoolArray:
    """(H,) whether the SDV's plan box overlaps any in-range actor's box at each plan stamp."""
    require_aligned(plan, actors)
    boxes = ego.boxes(plan.xy, plan.yaws)
    active = actors_in_range(plan, actors, config)
    if not np.any(active):
        return np.zeros(plan.stamps_ns.shape[0], dtype=bool)
    overlapping = boxes_overlap(actors.finite_boxes()[active], boxes[None]) & actors.present[active]
    return np.asarray(overlapping.any(axis=0), dtype=bool)


@dataclass(frozen=True, eq=False)
class DetectionTally:
    """Detections of one sweep matched to ground truth, for pooling into an AP."""

    scores: FloatArray  # (M,) confidence of each in-range detection [1]
    true_positive: BoolArray  # (M,) whether it matched a ground-truth box
    num_ground_truth: int  # in-range ground-truth boxes [1]


def match_detections(
    detections: FloatArray,
    scores: FloatArray,
    ground_truth: FloatArray,
    ego_xy: FloatArray,
    ego_yaw: float,
    config: MetricsConfig,
) -> DetectionTally:
    """Greedy matching by descending score: a detection takes the unmatched box of highest IoU >= threshold.

    Boxes (M, 5) and (G, 5) in the world frame; only those whose centre is inside the
    evaluation range around the ego pose count.
    """
    detections = np.asarray(detections, dtype=np.float64).reshape(-1, 5)
    scores = np.asarray(scores, dtype=np.float64).reshape(-1)
    ground_truth = np.asarray(ground_truth, dtype=np.float64).reshape(-1, 5)
    if scores.shape[0] != detections.shape[0]:
        raise ScenarioError(f"detections: {detections.shape[0]} boxes but {scores.shape[0]} scores")
    keep = in_range(detections[:, :2], ego_xy, ego_yaw, config)
    detections, scores = detections[keep], scores[keep]
    ground_truth = ground_truth[in_range(ground_truth[:, :2], ego_xy, ego_yaw, config)]
    order = np.argsort(-scores, kind="stable")
    detections, scores = detections[order], scores[order]
    true_positive = np.zeros(detections.shape[0], dtype=bool)
    if detections.shape[0] and ground_truth.shape[0]:
        iou = bev_iou(detections[:, None, :], ground_truth[None, :, :])  # (M, G)
        taken = np.zeros(ground_truth.shape[0], dtype=bool)
        for index in range(detections.shape[0]):
            candidates = np.where(taken, -1.0, iou[index])
            best = int(np.argmax(candidates))
            if candidates[best] >= config.iou_threshold:
                taken[best] = True
                true_positive[index] = True
    return DetectionTally(scores, true_positive, int(ground_truth.shape[0]))


def average_precision(tallies: Sequence[DetectionTally]) -> float:
    """AP of pooled detections: area under the precision-recall curve with the precision envelope (all points).

    NaN when there is no ground truth at all.
    """
    total = sum(tally.num_ground_truth for tally in tallies)
    if total == 0:
        return float("nan")
    scores = np.concatenate([tally.scores for tally in tallies]) if tallies else np.empty(0)
    hits = np.concatenate([tally.true_positive for tally in tallies]) if tallies else np.empty(0, dtype=bool)
    if scores.size == 0:
        return 0.0
    order = np.argsort(-scores, kind="stable")
    true_positives = np.cumsum(hits[order])
    precision = true_positives / np.arange(1, order.size + 1)
    recall = true_positives / total
    envelope = np.maximum.accumulate(precision[::-1])[::-1]
    recall_steps = np.diff(np.concatenate([[0.0], recall]))
    return float(np.sum(recall_steps * envelope))


@dataclass(frozen=True, eq=False)
class Predictions:
    """Predicted actor trajectories published by the stack, in the world frame."""

    stamps_ns: npt.NDArray[np.int64]  # (T,) prediction times [ns], strictly increasing
    xy: FloatArray  # (K, T, 2) predicted box centres [m]

    def __post_init__(self) -> None:
        stamps = np.asarray(self.stamps_ns, dtype=np.int64)
        xy = np.asarray(self.xy, dtype=np.float64)
        if stamps.ndim != 1 or stamps.shape[0] < 1 or np.any(np.diff(stamps) <= 0):
            raise ScenarioError("Predictions stamps_ns: need a strictly increasing 1-D array")
        if xy.ndim != 3 or xy.shape[1:] != (stamps.shape[0], 2):
            raise ScenarioError(f"Predictions xy: expected shape (K, {stamps.shape[0]}, 2), got {xy.shape}")
        if not np.all(np.isfinite(xy)):
            raise ScenarioError("Predictions xy: contains NaN or infinite values")
        object.__setattr__(self, "stamps_ns", stamps)
        object.__setattr__(self, "xy", xy)


def _true_positions(
    plan: Plan, actors: ActorFutures, index: int, query_ns: npt.NDArray[np.int64]
) -> tuple[FloatArray, BoolArray]:
    """An actor's positions at query stamps, linear between the plan stamps it exists at; covered: within those."""
    present = actors.present[index]
    states = actors.states[index, present]
    xy, _, covered = interpolate_trajectory(plan.stamps_ns[present], states[:, :2], states[:, 2], query_ns)
    return xy, covered


def prediction_errors(plan: Plan, actors: ActorFutures, predictions: Predictions, config: MetricsConfig) -> FloatArray:
    """(len(horizons),) mean L2 [m] between predictions and the actors' true futures at each horizon.

    Each prediction is matched to the nearest unmatched in-range actor at the prediction's
    first stamp (within prediction_match_radius); unmatched predictions are false tracks and
    do not count. NaN at a horizon no matched pair covers.
    """
    require_aligned(plan, actors)
    active = np.flatnonzero(actors_in_range(plan, actors, config))
    errors = np.full(len(config.horizons), np.nan)
    if active.size == 0 or predictions.xy.shape[0] == 0:
        return errors
    truth = [_true_positions(plan, actors, int(index), predictions.stamps_ns) for index in active]
    truth_xy = np.stack([item[0] for item in truth])  # (A, T, 2)
    covered = np.stack([item[1] for item in truth])  # (A, T)
    start_distance = np.linalg.norm(predictions.xy[:, None, 0, :] - truth_xy[None, :, 0, :], axis=-1)  # (K, A)
    start_distance[:, ~covered[:, 0]] = np.inf
    pairs: list[tuple[int, int]] = []
    for flat in np.argsort(start_distance, axis=None, kind="stable"):
        prediction, actor = divmod(int(flat), start_distance.shape[1])
        if start_distance[prediction, actor] > config.prediction_match_radius:
            break
        if all(prediction != p and actor != a for p, a in pairs):
            pairs.append((prediction, actor))
    decision_ns = int(plan.stamps_ns[0])
    for slot, horizon in enumerate(config.horizons):
        query = np.array([decision_ns + round(horizon * NS_PER_S)], dtype=np.int64)
        distances = []
        for prediction, actor in pairs:
            predicted, _, inside = interpolate_trajectory(
                predictions.stamps_ns, predictions.xy[prediction], np.zeros(predictions.stamps_ns.shape[0]), query
            )
            true_xy, true_inside = _true_positions(plan, actors, int(active[actor]), query)
            if inside[0] and true_inside[0]:
                distances.append(float(np.linalg.norm(predicted[0] - true_xy[0])))
        if distances:
            errors[slot] = float(np.mean(distances))
    return errors


@dataclass(frozen=True, eq=False)
class QueryMetrics:
    """Metrics of one query; NaN where the inputs do not allow one."""

    horizons: tuple[float, ...]  # the metric horizons [s]
    collision: FloatArray  # (len(horizons),) 1 if the SDV collides within each horizon, else 0 [1]
    l2_human: FloatArray  # (len(horizons),) plan-to-human distance at each horizon [m]
    lateral_acceleration: float  # max |lateral acceleration| along the plan [m/s^2]
    jerk: float  # max |longitudinal jerk| along the plan [m/s^3]
    first_collision_time: float  # seconds after the decision of the first overlap; NaN when none [s]
    detection: DetectionTally | None = None  # when the stack published detections
    prediction_l2: FloatArray = field(default_factory=lambda: np.empty(0))  # (len(horizons),) or empty [m]

    def at(self, name: str, horizon: float) -> float:
        """A per-horizon metric ("collision", "l2_human", "prediction_l2") at one horizon [s]."""
        values: FloatArray = getattr(self, name)
        if horizon not in self.horizons or values.size == 0:
            return float("nan")
        return float(values[self.horizons.index(horizon)])


def query_metrics(
    plan: Plan,
    human: EgoTrajectory,
    actors: ActorFutures,
    ego: EgoGeometry,
    config: MetricsConfig,
    detection: DetectionTally | None = None,
    predictions: Predictions | None = None,
) -> QueryMetrics:
    """Every planning metric of one query (see the module docstring for the definitions)."""
    times = plan_times(plan)
    colliding = collision_steps(plan, actors, ego, config)
    first = float(times[np.argmax(colliding)]) if np.any(colliding) else float("nan")
    collision = np.array([float(np.isfinite(first) and first <= horizon + 1e-9) for horizon in config.horizons])
    decision_ns = int(plan.stamps_ns[0])
    queries = np.array([decision_ns + round(h * NS_PER_S) for h in config.horizons], dtype=np.int64)
    planned_xy, _, plan_covers = interpolate_trajectory(plan.stamps_ns, plan.xy, plan.yaws, queries)
    human_xy, _, human_covers = human_at(human, queries)
    l2 = np.where(plan_covers & human_covers, np.linalg.norm(planned_xy - human_xy, axis=-1), np.nan)
    kinematics = trajectory_kinematics(times, plan.xy, plan.yaws)
    lateral = float(np.max(np.abs(kinematics.lateral_acceleration))) if kinematics.lateral_acceleration.size else np.nan
    jerk = float(np.max(np.abs(kinematics.jerk))) if kinematics.jerk.size else float("nan")
    prediction = prediction_errors(plan, actors, predictions, config) if predictions is not None else np.empty(0)
    return QueryMetrics(
        horizons=tuple(config.horizons),
        collision=collision,
        l2_human=l2,
        lateral_acceleration=lateral,
        jerk=jerk,
        first_collision_time=first,
        detection=detection,
        prediction_l2=prediction,
    )


@dataclass(frozen=True, eq=False)
class AggregateMetrics:
    """Metrics over scenarios: means over the queries given (NaN entries skipped), AP pooled."""

    horizons: tuple[float, ...]  # [s]
    count: int  # queries aggregated [1]
    collision_rate: FloatArray  # (len(horizons),) share of queries that collide within each horizon [1]
    l2_human: FloatArray  # (len(horizons),) mean plan-to-human distance [m]
    lateral_acceleration: float  # mean of the per-query maxima [m/s^2]
    jerk: float  # mean of the per-query maxima [m/s^3]
    detection_ap: float  # AP at the IoU threshold over every tally; NaN without detections [1]
    prediction_l2: FloatArray  # (len(horizons),) mean prediction error; NaN without predictions [m]


def _nanmean(values: FloatArray, axis: int = 0) -> FloatArray:
    """Mean ignoring NaN; NaN (without a warning) where every entry is NaN."""
    finite = np.isfinite(values)
    counts = finite.sum(axis=axis)
    totals = np.where(finite, values, 0.0).sum(axis=axis)
    result: FloatArray = np.where(counts > 0, totals / np.maximum(counts, 1), np.nan)
    return result


def aggregate_metrics(metrics: Sequence[QueryMetrics]) -> AggregateMetrics:
    """Aggregate per-query metrics (typically the worst query found per scenario) over scenarios."""
    if not metrics:
        raise ScenarioError("aggregate_metrics: no query metrics to aggregate")
    horizons = metrics[0].horizons
    if any(item.horizons != horizons for item in metrics):
        raise ScenarioError("aggregate_metrics: every query must use the same horizons")
    tallies = [item.detection for item in metrics if item.detection is not None]
    predictions = [item.prediction_l2 for item in metrics if item.prediction_l2.size]
    return AggregateMetrics(
        horizons=horizons,
        count=len(metrics),
        collision_rate=_nanmean(np.stack([item.collision for item in metrics])),
        l2_human=_nanmean(np.stack([item.l2_human for item in metrics])),
        lateral_acceleration=float(_nanmean(np.array([item.lateral_acceleration for item in metrics]))),
        jerk=float(_nanmean(np.array([item.jerk for item in metrics]))),
        detection_ap=average_precision(tallies) if tallies else float("nan"),
        prediction_l2=_nanmean(np.stack(predictions)) if predictions else np.full(len(horizons), np.nan),
    )
