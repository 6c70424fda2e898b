"""The scorer's step from a finished episode to its QueryScore record (core.scoring does the maths)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TypedDict, Unpack

import numpy as np

from advsim_ros.contract.codec import ContractError, Msg, stamp_ns
from advsim_ros.contract.enums import Outcome, Status
from advsim_ros.contract.plan import PLAN_STEP_NS, plan_from_path
from advsim_ros.contract.protocol import EpisodeRecord, ScoreRecord
from advsim_ros.contract.tracks import TrackArrayRecord
from advsim_ros.core.closed_loop import ControllerConfig, executed_as_plan, executed_metrics
from advsim_ros.core.episode import EpisodeClock
from advsim_ros.core.futures import actor_futures_at
from advsim_ros.core.metrics import Predictions
from advsim_ros.core.objective import ScorerSettings
from advsim_ros.core.reactive import with_reactions
from advsim_ros.core.scoring import Detections, QueryEvaluation, evaluate_query
from advsim_ros.core.types import ActorTrack, DrivableArea, Plan, Scenario, ScenarioError, replace_actors


class _Common(TypedDict):
    """What every QueryScore of an episode carries, whatever its status."""

    wall_time: float  # [s]
    sweeps_delivered: int
    plans_received: int
    input_digest: str
    plan_digest: str


class _ClosedLoop(TypedDict, total=False):
    """A closed-loop QueryScore's figures beside the driven trajectory's."""

    loop: str
    open_loop_adversarial_loss: float  # [1]
    open_loop_collision_5s: float  # [1]
    min_distance: float  # [m]
    min_time_to_collision: float  # [s]
    progress: float  # [m]


def _detections(record: TrackArrayRecord | None) -> Detections | None:
    if record is None:
        return None
    boxes = np.array(
        [[t.xyz[0, 0], t.xyz[0, 1], t.yaw[0], t.size[0], t.size[1]] for t in record.tracks], dtype=np.float64
    ).reshape(-1, 5)
    return Detections(boxes, np.array([t.confidence for t in record.tracks], dtype=np.float64))


def _predictions(record: TrackArrayRecord | None, sim_offset_ns: int) -> Predictions | None:
    """Predictions in log time; tracks whose stamps differ from the first one's are left out (one time base)."""
    if record is None or not record.tracks:
        return None
    stamps = record.tracks[0].stamps_ns
    same = [t for t in record.tracks if np.array_equal(t.stamps_ns, stamps)]
    return Predictions(stamps - sim_offset_ns, np.stack([t.xyz[:, :2] for t in same]))


def usable_plan(path: Msg, world_frame: str, time_offset_ns: int = 0) -> Plan:
    """The contract's plan in a nav_msgs/Path: in the world frame, finite, non-empty, increasing stamps.

    ContractError naming what is wrong. A plan in another frame is refused, not scored as if it
    were in the world frame (a stack profile converts frames: docs/stacks.md).
    """
    frame = str(path.header.frame_id)
    if frame != world_frame:
        raise ContractError(
            f"the plan is in frame {frame!r}, the contract's plans are in the world frame {world_frame!r} "
            "(publish it there, or describe the stack's frame in a stack profile: docs/stacks.md)"
        )
    return plan_from_path(path, time_offset_ns)


def score_episode(
    episode: EpisodeRecord,
    moved: Sequence[ActorTrack],
    scenario: Scenario,
    clock: EpisodeClock,
    decision_frame: int,
    settings: ScorerSettings,
    drivable: DrivableArea | None,
    wall_time: float,
    world_frame: str,
) -> ScoreRecord:
    """The QueryScore of a finished query: a failure status from the outcome, else the evaluated plan."""
    common: _Common = {
        "wall_time": wall_time,
        "sweeps_delivered": episode.sweeps_delivered,
        "plans_received": episode.plans_received,
        "input_digest": episode.input_digest,
        "plan_digest": episode.plan_digest,
    }
    query_id = episode.query_id
    if episode.outcome == Outcome.FOREIGN_PUBLISHER:
        return ScoreRecord(query_id, Status.FOREIGN_PUBLISHER, episode.outcome_detail, **common)
    if episode.outcome == Outcome.STACK_LOST:
        reason = "the stack stopped during the query (its plan publisher vanished or was replaced: crash, restart)"
        return ScoreRecord(query_id, Status.STACK_ERROR, reason, **common)
    if episode.outcome == Outcome.PLANS_MISSING or episode.decision_plan is None:
        reason = (
            f"the stack answered {episode.plans_received} of the frames it was waited for "
            f"({episode.sweeps_delivered} of {episode.num_frames} sweeps delivered)"
        )
        return ScoreRecord(query_id, Status.STACK_TIMEOUT, reason, **common)
    decision_log = int(scenario.frame_stamps_ns[decision_frame])
    offset = clock.to_sim(query_id, decision_log) - decision_log
    detections, predictions = _detections(episode.detections), _predictions(episode.predictions, offset)
    try:
        if stamp_ns(episode.decision_plan.header.stamp) != decision_log + offset:
            raise ContractError("the decision plan is not stamped with the decision sweep's stamp")
        plan = usable_plan(episode.decision_plan, world_frame, offset)
        evaluation = evaluate_query(plan, scenario, moved, decision_frame, settings, drivable, detections, predictions)
    except ScenarioError as error:
        return ScoreRecord(query_id, Status.STACK_ERROR, f"unusable plan: {error}", **common)
    if episode.executed is None:
        return _score(query_id, evaluation, common)
    # closed loop: what the ego drove is scored like a plan; the decision plan's open-loop figures beside it
    executed = episode.executed.to_executed(ControllerConfig().wheelbase, offset)
    horizon_ns = int(executed.stamps_ns[-1] - decision_log)
    driven = executed_as_plan(executed, decision_log, PLAN_STEP_NS, horizon_ns)
    # reactive actors: scored where they drove, not where their tracks went
    actors = with_reactions(
        replace_actors(scenario.actors, moved),
        [track.shifted(-offset).to_actor_track() for track in episode.reacted_actors],
    )
    drove = evaluate_query(driven, scenario, actors, decision_frame, settings, drivable, detections, predictions)
    futures = actor_futures_at(actors, executed.stamps_ns, settings.metrics.actor_extrapolation)
    loop = executed_metrics(executed, futures, scenario.ego_geometry)
    return _score(
        query_id, drove, common, loop="closed",
        open_loop_adversarial_loss=evaluation.terms.value,
        open_loop_collision_5s=evaluation.metrics.at("collision", 5.0),
        min_distance=loop.min_distance, min_time_to_collision=loop.min_time_to_collision, progress=loop.progress,
    )  # fmt: skip


def _score(query_id: int, evaluation: QueryEvaluation, common: _Common, **extra: Unpack[_ClosedLoop]) -> ScoreRecord:
    terms, metrics = evaluation.terms, evaluation.metrics
    return ScoreRecord(
        query_id,
        Status.OK,
        adversarial_loss=terms.value,
        imitation_loss=terms.imitation,
        collision_loss=terms.collision,
        comfort_loss=terms.comfort,
        collision_3s=metrics.at("collision", 3.0),
        collision_5s=metrics.at("collision", 5.0),
        l2_human_3s=metrics.at("l2_human", 3.0),
        l2_human_5s=metrics.at("l2_human", 5.0),
        lateral_acceleration=metrics.lateral_acceleration,
        jerk=metrics.jerk,
        detection_ap=evaluation.detection_ap,
        prediction_l2_3s=metrics.at("prediction_l2", 3.0),
        prediction_l2_5s=metrics.at("prediction_l2", 5.0),
        **common,
        **extra,
    )
