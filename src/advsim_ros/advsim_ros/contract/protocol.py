"""The attack protocol's messages: Perturbation, ActorSelection, FrameRequest, Episode, QueryScore.

Each message has a typed record (what it carries, in core types), one builder (record and run
id -> typestore message) and one parser (message -> record). Every protocol message carries
the attack's run id; ``advsim_ros.ros.graph_node`` drops messages of other runs before a
parser sees them.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, TypeAlias

import numpy as np

from advsim_ros.contract import names
from advsim_ros.contract.codec import Msg, header_msg, message, stamp_ns, time_msg
from advsim_ros.contract.enums import Outcome, Phase, Status
from advsim_ros.contract.spatial import pose_matrix, pose_msg
from advsim_ros.contract.tracks import TrackArrayRecord, TrackRecord, track_array_from_msg, track_from_msg, track_msg
from advsim_ros.core.types import FloatArray, Perturbation

ScoreValue: TypeAlias = str | int | float | None  # a ScoreRecord field as JSON holds it (as_dict, from_dict)

# ----------------------------------------------------------------------------- Perturbation


def perturbation_msg(perturbation: Perturbation, run_id: int) -> Msg:
    return message(
        names.PERTURBATION,
        run_id=int(run_id),
        query_id=perturbation.query_id,
        scenario_id=perturbation.scenario_id,
        actor_ids=list(perturbation.actor_ids),
        delta=np.asarray(perturbation.delta, dtype=np.float64),
        algorithm=perturbation.algorithm,
    )


def perturbation_from_msg(perturbation: Msg) -> Perturbation:
    return Perturbation(
        query_id=int(perturbation.query_id),
        scenario_id=str(perturbation.scenario_id),
        actor_ids=tuple(str(actor_id) for actor_id in perturbation.actor_ids),
        delta=np.asarray(perturbation.delta, dtype=np.float64),
        algorithm=str(perturbation.algorithm),
    )


# ----------------------------------------------------------------------------- ActorSelection


@dataclass(frozen=True, eq=False)
class SelectionRecord:
    """The actors the search may perturb and the layout of its delta."""

    scenario_id: str
    actor_ids: tuple[str, ...]  # in the order of their blocks in the delta
    dimension: int  # length of the delta
    delta_names: tuple[str, ...]  # entries of one actor's block
    logged_tracks: tuple[TrackRecord, ...]  # the selected actors' logged tracks
    feasible_candidates: tuple[int, ...]  # survivors of pruning, per selected actor


def selection_msg(selection: SelectionRecord, stamp: int, frame_id: str, run_id: int) -> Msg:
    return message(
        names.ACTOR_SELECTION,
        header=header_msg(stamp, frame_id),
        run_id=int(run_id),
        scenario_id=selection.scenario_id,
        actor_ids=list(selection.actor_ids),
        dimension=int(selection.dimension),
        delta_names=list(selection.delta_names),
        logged_tracks=[track_msg(track) for track in selection.logged_tracks],
        feasible_candidates=np.array(selection.feasible_candidates, dtype=np.uint32),
    )


def selection_from_msg(selection: Msg) -> SelectionRecord:
    return SelectionRecord(
        scenario_id=str(selection.scenario_id),
        actor_ids=tuple(str(a) for a in selection.actor_ids),
        dimension=int(selection.dimension),
        delta_names=tuple(str(n) for n in selection.delta_names),
        logged_tracks=tuple(track_from_msg(track) for track in selection.logged_tracks),
        feasible_candidates=tuple(int(n) for n in selection.feasible_candidates),
    )


# ----------------------------------------------------------------------------- FrameRequest


@dataclass(frozen=True, eq=False)
class FrameRequestRecord:
    """The player asks lidar_resim for one frame's sweep of one query, seen from this ego pose."""

    query_id: int
    frame_index: int  # within the window
    log_frame: int  # index in the log
    sim_stamp_ns: int  # the frame's sim time; the sweep is published with it [ns]
    world_T_ego: FloatArray  # (4, 4)
    reacted_actors: tuple[TrackRecord, ...] = ()  # reactive actors off their tracks: one state each (sim time)


def frame_request_msg(request: FrameRequestRecord, world_frame: str, run_id: int) -> Msg:
    return message(
        names.FRAME_REQUEST,
        header=header_msg(request.sim_stamp_ns, world_frame),
        run_id=int(run_id),
        query_id=request.query_id,
        frame_index=request.frame_index,
        log_frame=request.log_frame,
        ego_pose=pose_msg(request.world_T_ego),
        reacted_actors=[track_msg(track) for track in request.reacted_actors],
    )


def frame_request_from_msg(request: Msg) -> FrameRequestRecord:
    pose = request.ego_pose
    return FrameRequestRecord(
        query_id=int(request.query_id),
        frame_index=int(request.frame_index),
        log_frame=int(request.log_frame),
        sim_stamp_ns=stamp_ns(request.header.stamp),
        world_T_ego=pose_matrix(pose.position, pose.orientation, f"frame request of query {request.query_id}"),
        reacted_actors=tuple(track_from_msg(track) for track in request.reacted_actors),
    )


# ----------------------------------------------------------------------------- Episode


@dataclass(frozen=True, eq=False)
class EpisodeRecord:
    """One phase change of a query's replay; DONE carries what the stack answered."""

    query_id: int
    phase: Phase
    frame_index: int
    num_frames: int
    segment: tuple[int, int]  # the query's sim-time segment [ns], end exclusive
    sweeps_delivered: int = 0
    plans_received: int = 0
    outcome: Outcome = Outcome.COMPLETE
    input_digest: str = ""
    plan_digest: str = ""
    decision_plan: Msg | None = None  # nav_msgs/Path of the decision frame (sim time), None when it never came
    detections: TrackArrayRecord | None = None
    predictions: TrackArrayRecord | None = None
    executed: TrackRecord | None = None  # closed loop: what the ego drove from the decision on (sim time)
    reacted_actors: tuple[TrackRecord, ...] = ()  # closed loop: the reactive actors that left their tracks (sim time)
    outcome_detail: str = ""  # what went wrong, when the outcome is not COMPLETE


def _no_track() -> Msg:
    """An empty ActorTrack (the Episode's executed field in open loop)."""
    return message(
        names.ACTOR_TRACK, actor_id="", actor_class="", length=0.0, width=0.0, height=0.0, confidence=0.0, states=[]
    )


def episode_msg(episode: EpisodeRecord, run_id: int, detections: Msg = None, predictions: Msg = None) -> Msg:
    """Episode message; ``detections``/``predictions`` are the ActorTrackArray messages as the stack sent them."""
    empty_tracks = message(names.ACTOR_TRACK_ARRAY, header=header_msg(0, ""), run_id=0, query_id=0, tracks=[])
    return message(
        names.EPISODE,
        run_id=int(run_id),
        query_id=episode.query_id,
        phase=int(episode.phase),
        frame_index=episode.frame_index,
        num_frames=episode.num_frames,
        segment_start=time_msg(episode.segment[0]),
        segment_end=time_msg(episode.segment[1]),
        sweeps_delivered=episode.sweeps_delivered,
        plans_received=episode.plans_received,
        outcome=int(episode.outcome),
        outcome_detail=episode.outcome_detail,
        input_digest=episode.input_digest,
        plan_digest=episode.plan_digest,
        has_plan=episode.decision_plan is not None,
        decision_plan=episode.decision_plan
        if episode.decision_plan is not None
        else message(names.PATH, header=header_msg(0, ""), poses=[]),
        has_detections=detections is not None,
        detections=detections if detections is not None else empty_tracks,
        has_predictions=predictions is not None,
        predictions=predictions if predictions is not None else empty_tracks,
        has_executed=episode.executed is not None,
        executed=track_msg(episode.executed) if episode.executed is not None else _no_track(),
        reacted_actors=[track_msg(track) for track in episode.reacted_actors],
    )


def episode_from_msg(episode: Msg) -> EpisodeRecord:
    return EpisodeRecord(
        query_id=int(episode.query_id),
        phase=Phase(int(episode.phase)),
        frame_index=int(episode.frame_index),
        num_frames=int(episode.num_frames),
        segment=(stamp_ns(episode.segment_start), stamp_ns(episode.segment_end)),
        sweeps_delivered=int(episode.sweeps_delivered),
        plans_received=int(episode.plans_received),
        outcome=Outcome(int(episode.outcome)),
        outcome_detail=str(episode.outcome_detail),
        input_digest=str(episode.input_digest),
        plan_digest=str(episode.plan_digest),
        decision_plan=episode.decision_plan if episode.has_plan else None,
        detections=track_array_from_msg(episode.detections) if episode.has_detections else None,
        predictions=track_array_from_msg(episode.predictions) if episode.has_predictions else None,
        executed=track_from_msg(episode.executed) if episode.has_executed else None,
        reacted_actors=tuple(track_from_msg(track) for track in episode.reacted_actors),
    )


# ----------------------------------------------------------------------------- SearchStatus


@dataclass(frozen=True)
class SearchStatusRecord:
    queries_asked: int  # perturbations sent so far; once finished, all the search's queries (journal replays included)
    finished: bool  # no further perturbation will come


def search_status_msg(status: SearchStatusRecord, run_id: int) -> Msg:
    return message(
        names.SEARCH_STATUS, run_id=int(run_id), queries_asked=status.queries_asked, finished=status.finished
    )


def search_status_from_msg(status: Msg) -> SearchStatusRecord:
    return SearchStatusRecord(queries_asked=int(status.queries_asked), finished=bool(status.finished))


# ----------------------------------------------------------------------------- QueryScore


@dataclass(frozen=True)
class ScoreRecord:
    """The objective and metrics of one query (advsim_msgs/QueryScore); NaN where not computed."""

    query_id: int
    status: Status
    message: str = ""  # why, when status is not OK
    adversarial_loss: float = math.nan  # L_adv [1]
    imitation_loss: float = math.nan  # [m]
    collision_loss: float = math.nan  # [1]
    comfort_loss: float = math.nan  # [1]
    collision_3s: float = math.nan  # [1]
    collision_5s: float = math.nan  # [1]
    l2_human_3s: float = math.nan  # [m]
    l2_human_5s: float = math.nan  # [m]
    lateral_acceleration: float = math.nan  # [m/s^2]
    jerk: float = math.nan  # [m/s^3]
    wall_time: float = math.nan  # [s]
    sweeps_delivered: int = 0
    plans_received: int = 0
    input_digest: str = ""
    plan_digest: str = ""
    detection_ap: float = math.nan  # [1]
    prediction_l2_3s: float = math.nan  # [m]
    prediction_l2_5s: float = math.nan  # [m]
    loop: str = "open"  # what the objective and metrics above are of: the decision plan, or what the ego drove
    open_loop_adversarial_loss: float = math.nan  # closed loop: L_adv of the decision plan [1]
    open_loop_collision_5s: float = math.nan  # closed loop: the decision plan's collision within 5 s [1]
    min_distance: float = math.nan  # closed loop: smallest ego-actor box gap [m]
    min_time_to_collision: float = math.nan  # closed loop [s]
    progress: float = math.nan  # closed loop: path length driven [m]

    @property
    def ok(self) -> bool:
        return self.status == Status.OK

    def as_dict(self) -> dict[str, ScoreValue]:
        """For JSON: the status by name, NaN and infinities (no time to collision, no actor) as None."""
        values = dataclasses.asdict(self)
        values["status"] = self.status.label
        return {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in values.items()}

    @staticmethod
    def from_dict(values: Mapping[str, ScoreValue]) -> ScoreRecord:
        """The inverse of as_dict (journals, summaries)."""
        fields = {f.name: f for f in dataclasses.fields(ScoreRecord)}
        # ScoreRecord's keyword arguments, each converted to its field's type just below (checked by the field's
        # annotation at run time, which no static type can follow)
        converted: dict[str, Any] = {}
        for key, value in values.items():
            if key not in fields:
                continue
            if key == "status":
                converted[key] = Status[str(value).upper()]
            elif fields[key].type == "float":
                converted[key] = math.nan if value is None else float(value)
            else:
                converted[key] = value
        return ScoreRecord(**converted)


SCORE_FIELDS = tuple(f.name for f in dataclasses.fields(ScoreRecord))


def score_msg(score: ScoreRecord, run_id: int) -> Msg:
    values = {name: getattr(score, name) for name in SCORE_FIELDS}
    values["status"] = int(score.status)
    return message(names.QUERY_SCORE, run_id=int(run_id), **values)


def score_from_msg(score: Msg) -> ScoreRecord:
    values = {name: getattr(score, name) for name in SCORE_FIELDS}
    values["status"] = Status(int(score.status))
    values["message"] = str(values["message"])
    values["loop"] = str(values["loop"])
    return ScoreRecord(**values)
