"""The outputs of an attack: OUTDIR/adversarial (scenario bag), OUTDIR/summary.json, OUTDIR/bev.png.

The adversarial bag is a scenario bag of the attacked window in log time: the re-simulated sweeps
the stack saw, the perturbed actors (others as logged), the ego's logged (human) trajectory, plus
the stack's plan (/planning/trajectory), the query's score (/advsim/score) and its perturbation
(/advsim/perturbation). `advsim replay` runs a stack on it and scores it again.
"""

from __future__ import annotations

import json
import math
import os
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from rosbags.rosbag2 import Reader

from advsim_ros.core.curation import CurationConfig, crop_scenario, evaluate_window
from advsim_ros.core.episode import EpisodeClock, WindowConfig
from advsim_ros.core.geometry import box_corners
from advsim_ros.core.types import Plan, Scenario, Sweep
from advsim_ros.io.bag import BagConfig, read_scenario_bag, write_scenario_bag
from advsim_ros.io.pointcloud import cloud_to_points
from advsim_ros.ros import topics
from advsim_ros.ros.messages import message_to_dict
from advsim_ros.ros.wire import (
    PATH,
    PERTURBATION,
    QUERY_SCORE,
    STATUS_OK,
    Wire,
    path_msg,
    plan_from_path,
    tracks_from_msg,
)

if TYPE_CHECKING:
    from advsim_ros.attack import AttackOptions
    from advsim_ros.ros.monitor import Recording

STATUS_NAMES = {0: "ok", 1: "stack_timeout", 2: "stack_error", 3: "infeasible"}


def _score_dict(score: Any) -> dict[str, Any]:
    values = message_to_dict(score)
    values["status"] = STATUS_NAMES.get(int(score.status), str(score.status))
    return {key: (None if isinstance(value, float) and math.isnan(value) else value) for key, value in values.items()}


def write_json_atomically(path: Path, document: Any) -> None:
    """Write JSON to a temporary file beside `path`, then rename it into place."""
    handle, temporary = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.")
    with os.fdopen(handle, "w", encoding="utf-8") as stream:
        json.dump(document, stream, indent=2)
        stream.flush()
        os.fsync(stream.fileno())
    os.replace(temporary, path)


def adversarial_scenario(
    source: Scenario, window: WindowConfig, record: Recording, wire: Wire
) -> tuple[Scenario, Plan | None]:
    """The attacked window as the stack saw it (log time), and the stack's plan from the decision frame."""
    cropped = crop_scenario(source, evaluate_window(source, window.window_start_frame, _curation(window)))
    clock = window.clock(source.frame_stamps_ns.tolist())
    moved = {}
    if record.tracks is not None:
        moved = {
            track.actor_id: track
            for track in tracks_from_msg(wire.decode(record.tracks, "advsim_msgs/msg/ActorTrackArray"))
        }
    actors = tuple(moved.get(actor.actor_id, actor) for actor in cropped.actors)
    frame_of = {int(stamp): index for index, stamp in enumerate(cropped.frame_stamps_ns.tolist())}
    sweeps = []
    for sim_stamp in sorted(record.sweeps):
        located = clock.locate(sim_stamp)
        if located.query_id != record.query_id or located.log_time_ns not in frame_of:
            continue
        cloud = wire.decode(record.sweeps[sim_stamp], "sensor_msgs/msg/PointCloud2")
        pose = cropped.ego.poses[frame_of[located.log_time_ns]] @ cropped.ego_T_sensor
        sweeps.append(Sweep(located.log_time_ns, cloud.header.frame_id, cloud_to_points(cloud), pose))
    decision_log = int(cropped.frame_stamps_ns[window.decision_index])
    plan = decision_plan(record.plans, record.query_id, clock, decision_log, wire)
    scenario = Scenario(
        scenario_id=f"{cropped.scenario_id}/adversarial",
        frame_stamps_ns=cropped.frame_stamps_ns,
        ego=cropped.ego,
        actors=actors,
        sweeps=tuple(sweeps),
        ego_T_sensor=cropped.ego_T_sensor,
        sensor=cropped.sensor,
        road_map=cropped.road_map,
        ego_size=cropped.ego_size,
    )
    return scenario, plan


def decision_plan(
    plans: dict[int, bytes], query_id: int, clock: EpisodeClock, decision_log: int, wire: Wire
) -> Plan | None:
    """The stack's plan from the decision frame of a query, in log time (None when it never came)."""
    if query_id < 0:
        return None
    decision_sim = clock.to_sim(query_id, decision_log)
    if decision_sim not in plans:
        return None
    return plan_from_path(wire.decode(plans[decision_sim], PATH), decision_sim - decision_log)


def _curation(window: WindowConfig) -> CurationConfig:
    return CurationConfig(
        history_frames=window.history_frames, future_frames=window.future_frames, frame_period=window.frame_period
    )


def recorded_score(path: Path) -> float | None:
    """L_adv of the score stored in an adversarial bag (None when it has none or the query failed)."""
    wire = Wire()
    with Reader(path) as reader:
        connections = [c for c in reader.connections if c.topic == topics.SCORE]
        for _, _, raw in reader.messages(connections=connections):
            score = wire.decode(raw, QUERY_SCORE)
            return float(score.adversarial_loss) if score.status == STATUS_OK else None
    return None


def write_outputs(
    *,
    out_dir: Path,
    bag: Path,
    options: AttackOptions,
    window_start_frame: int,
    monitor_record: Recording,
    stack_crashes: list[dict[str, Any]],
    wall_time: float,
    domain_id: int,
) -> dict[str, Any]:
    """Write the adversarial bag, summary.json and bev.png; return the summary."""
    wire = Wire()
    record = monitor_record
    bag_config = BagConfig()
    window = WindowConfig(scenario_bag=str(bag), window_start_frame=window_start_frame)
    source = read_scenario_bag(bag, config=bag_config, load_sweeps=False)
    scores = {query: _score_dict(score) for query, score in sorted(record.scores.items())}
    queries = []
    for query_id, score in scores.items():
        perturbation = record.perturbations.get(query_id)
        entry = {"query_id": query_id, "score": score}
        if perturbation is not None:
            entry.update(algorithm=perturbation.algorithm, delta=[float(v) for v in perturbation.delta])
        episode = record.episodes.get(query_id)
        if episode is not None:  # absent for queries that never reached the player (infeasible)
            entry.update(sweeps_delivered=int(episode.sweeps_delivered), plans_received=int(episode.plans_received))
        queries.append(entry)
    searched = [q for q in queries if q.get("algorithm") not in ("original", "replay") and q["query_id"] > 0]
    succeeded = [q for q in searched if q["score"]["status"] == "ok"]
    best = max(succeeded, key=lambda q: q["score"]["adversarial_loss"], default=None)
    replay = queries[-1] if queries and queries[-1].get("algorithm") == "replay" else None
    original = scores.get(0)

    scenario, plan = adversarial_scenario(source, window, record, wire)
    extra = _extra_messages(wire, scenario, plan, window, record, bag_config)
    adversarial_path = out_dir / "adversarial"
    write_scenario_bag(
        scenario, adversarial_path, config=bag_config, source=f"advsim attack of {bag}", overwrite=True, extra=extra
    )
    selection = record.selection
    summary: dict[str, Any] = {
        "scenario": {
            "bag": str(bag),
            "scenario_id": source.scenario_id,
            "window_start_frame": window_start_frame,
            "history_frames": window.history_frames,
            "future_frames": window.future_frames,
        },
        "stack": {"name": options.stack.name, "command": list(options.stack.command)},
        "search": {"algorithm": options.algorithm, "queries": options.queries, "seed": options.seed},
        "perturbed_actors": [] if selection is None else list(selection.actor_ids),
        "feasible_candidates": [] if selection is None else [int(n) for n in selection.feasible_candidates],
        "original": original,
        "best": best,
        "adversarial": None if replay is None else replay["score"],
        "queries": queries,
        "failed_queries": sum(1 for q in searched if q["score"]["status"] != "ok"),
        "stack_crashes": stack_crashes,
        "wall_time_s": wall_time,
        "ros_domain_id": domain_id,
        "outputs": {"adversarial_bag": str(adversarial_path), "bev": str(out_dir / "bev.png")},
    }
    write_json_atomically(out_dir / "summary.json", summary)
    decision_log = int(scenario.frame_stamps_ns[window.decision_index])
    clock = window.clock(source.frame_stamps_ns.tolist())
    original_plan = decision_plan(record.original_plans, 0, clock, decision_log, wire)
    draw_bev(out_dir / "bev.png", source, scenario, (original_plan, plan), window, summary)
    return summary


def _extra_messages(
    wire: Wire, scenario: Scenario, plan: Plan | None, window: WindowConfig, record: Recording, bag: BagConfig
) -> list[tuple[str, str, int, bytes]]:
    """(topic, type, log stamp, CDR) of the plan, score and perturbation of the recorded query."""
    decision = int(scenario.frame_stamps_ns[window.decision_index])
    extra: list[tuple[str, str, int, bytes]] = []
    if plan is not None:
        extra.append((topics.PLAN, PATH, decision, wire.encode(path_msg(wire, plan, decision, bag.world_frame))))
    score = record.scores.get(record.query_id)
    if score is not None:
        extra.append((topics.SCORE, QUERY_SCORE, decision, wire.encode(score)))
    perturbation = record.perturbations.get(record.query_id)
    if perturbation is not None:
        extra.append((topics.PERTURBATION, PERTURBATION, decision, wire.encode(perturbation)))
    return extra


def _number(value: Any) -> str:
    return "n/a" if value is None else f"{value:.3g}"


def draw_bev(
    path: Path,
    source: Scenario,
    adversarial: Scenario,
    plans: tuple[Plan | None, Plan | None],
    window: WindowConfig,
    summary: dict[str, Any],
) -> None:
    """Bird's-eye view, original (left) vs adversarial (right): actors, human trajectory, the stack's plan."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    frames = window.frame_indices(source.num_frames)
    decision = frames.start + window.decision_index
    decision_stamp = int(source.frame_stamps_ns[decision])
    future = source.ego.xy[decision : frames.stop]
    ego_pose = source.ego.poses[decision]
    moved_ids = set(summary["perturbed_actors"])
    figure, axes = plt.subplots(1, 2, figsize=(14, 6.5), sharex=True, sharey=True)
    panels = (
        ("original (logged)", source, summary.get("original"), plans[0]),
        ("adversarial", adversarial, summary.get("adversarial"), plans[1]),
    )
    for axis, (title, scenario, score, plan) in zip(axes, panels, strict=True):
        if scenario is adversarial and adversarial.sweeps:
            sweep = adversarial.sweeps[-1]
            xyz = sweep.xyz[:: max(1, sweep.num_points // 20000)]
            world = xyz @ sweep.sensor_pose[:3, :3].T + sweep.sensor_pose[:3, 3]
            axis.scatter(world[:, 0], world[:, 1], s=0.2, c="0.75", linewidths=0)
        for actor in scenario.actors:
            inside = (actor.stamps_ns >= source.frame_stamps_ns[frames.start]) & (
                actor.stamps_ns <= source.frame_stamps_ns[frames.stop - 1]
            )
            if not np.any(inside):
                continue
            moved = actor.actor_id in moved_ids
            color = "tab:red" if moved else "tab:blue"
            axis.plot(actor.centers[inside, 0], actor.centers[inside, 1], "--", color=color, lw=1)
            at = np.nonzero(actor.stamps_ns == decision_stamp)[0]
            if at.size:
                i = int(at[0])
                box = np.array([*actor.centers[i, :2], actor.yaws[i], actor.length, actor.width])
                corners = box_corners(box)
                axis.fill(corners[:, 0], corners[:, 1], color=color, alpha=0.5 if moved else 0.3)
        ego_box = np.array([*ego_pose[:2, 3], math.atan2(ego_pose[1, 0], ego_pose[0, 0]), *source.ego_size[:2]])
        corners = box_corners(ego_box)
        axis.fill(corners[:, 0], corners[:, 1], color="tab:green", alpha=0.6, label="SDV")
        axis.plot(future[:, 0], future[:, 1], color="tab:green", lw=2, label="human trajectory")
        if plan is not None:
            axis.plot(plan.xy[:, 0], plan.xy[:, 1], color="black", lw=2, label="stack plan")
        text = (
            "no score"
            if score is None
            else f"L_adv {_number(score.get('adversarial_loss'))}   "
            f"collision@5s {_number(score.get('collision_5s'))}   L2@5s {_number(score.get('l2_human_5s'))} m"
        )
        axis.set_title(f"{title}\n{text}", fontsize=10)
        axis.set_aspect("equal")
        axis.set_xlabel("x [m]")
        centre = ego_pose[:2, 3]
        axis.set_xlim(centre[0] - 45, centre[0] + 45)
        axis.set_ylim(centre[1] - 30, centre[1] + 30)
    axes[0].set_ylabel("y [m]")
    axes[1].legend(loc="upper right", fontsize=8)
    figure.suptitle(f"{summary['scenario']['scenario_id']} window @ frame {window.window_start_frame}: red = perturbed")
    figure.tight_layout()
    temporary = path.with_name(f".{path.name}.tmp.png")
    figure.savefig(temporary, dpi=110)
    plt.close(figure)
    os.replace(temporary, path)
