"""Scoring one query: the stack's plan (and its detections and predictions) against the perturbed world.

What the scorer node computes, as a pure function: the objective L_adv with its terms and every
planning metric, detection AP (BEV IoU) and prediction L2 when the stack gave them.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from advsim_ros.core.futures import actor_futures_at
from advsim_ros.core.metrics import (
    Predictions,
    QueryMetrics,
    average_precision,
    match_detections,
    plan_from_decision,
    query_metrics,
)
from advsim_ros.core.objective import ObjectiveTerms, ScorerSettings, evaluate_objective
from advsim_ros.core.types import ActorTrack, DrivableArea, FloatArray, Plan, Scenario, replace_actors


@dataclass(frozen=True, eq=False)
class Detections:
    """A stack's detections at the decision frame, world frame."""

    boxes: FloatArray  # (M, 5) x, y, yaw, length, width [m, rad]
    scores: FloatArray  # (M,) confidence [1]


@dataclass(frozen=True, eq=False)
class QueryEvaluation:
    terms: ObjectiveTerms
    metrics: QueryMetrics
    detection_ap: float  # NaN without detections (or without ground truth in range) [1]


def evaluate_query(
    plan: Plan,
    scenario: Scenario,
    moved: Sequence[ActorTrack],
    decision_frame: int,
    settings: ScorerSettings,
    drivable: DrivableArea | None,
    detections: Detections | None = None,
    predictions: Predictions | None = None,
) -> QueryEvaluation:
    """Score a plan in log time planned from the sweep of ``decision_frame``, with ``moved`` actors perturbed."""
    decision_ns = int(scenario.frame_stamps_ns[decision_frame])
    decision_pose = scenario.ego.poses[decision_frame]
    full_plan = plan_from_decision(plan, decision_pose, decision_ns)
    actors = replace_actors(scenario.actors, moved)
    reach = settings.metrics.actor_extrapolation
    futures = actor_futures_at(actors, full_plan.stamps_ns, reach)
    terms = evaluate_objective(
        full_plan, scenario.ego, futures, scenario.ego_geometry, settings.objective, settings.metrics, drivable,
        scenario.road_map,
    )  # fmt: skip
    tally = None
    if detections is not None:
        at_decision = actor_futures_at(actors, full_plan.stamps_ns[:1], reach)
        truth = at_decision.boxes()[at_decision.present[:, 0], 0]  # the actors that exist then
        yaw = math.atan2(decision_pose[1, 0], decision_pose[0, 0])
        position = decision_pose[:2, 3]
        tally = match_detections(detections.boxes, detections.scores, truth, position, yaw, settings.metrics)
    metrics = query_metrics(
        full_plan, scenario.ego, futures, scenario.ego_geometry, settings.metrics, tally, predictions
    )
    ap = average_precision([tally]) if tally is not None else math.nan
    return QueryEvaluation(terms, metrics, ap)
