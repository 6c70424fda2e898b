"""The outputs of an attack, written from its journal: OUTDIR/adversarial, OUTDIR/summary.json, OUTDIR/bev.png.

The adversarial bag is a scenario bag of the attacked window in log time: the LiDAR the stack saw
in the recorded query (the last re-run of the best), the perturbed actors (others as logged),
the ego's logged (human) trajectory, the stack's plan (/planning/trajectory), the query's score
(/advsim/score), its perturbation (/advsim/perturbation) and the drivable area the scorer used
(/map/drivable), so that `advsim replay` scores it exactly as the attack did. The sweeps are
re-simulated again here from the journaled tracks (re-simulation is a function of the perturbed
world); their digest is compared with the one the scenario player took of what the stack
received, and summary.json says whether they agree. Every file is written atomically.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from advsim_ros import graph
from advsim_ros.attack.checks import Preflight
from advsim_ros.attack.controls import controls, finding, query_faults
from advsim_ros.attack.options import AttackOptions
from advsim_ros.attack.params import section
from advsim_ros.attack.summary import attack_summary, recorded_query
from advsim_ros.attack.verdict import attack_verdict
from advsim_ros.contract import codec, names, topics
from advsim_ros.contract.digests import InputDigest
from advsim_ros.contract.plan import path_msg
from advsim_ros.contract.protocol import (
    ScoreRecord,
    perturbation_from_msg,
    perturbation_msg,
    score_from_msg,
    score_msg,
)
from advsim_ros.contract.scenario import cloud_msg
from advsim_ros.contract.spatial import odometry_msgs
from advsim_ros.contract.topics import TopicSpec
from advsim_ros.core.atomic import write_json_atomically
from advsim_ros.core.attack_summary import AttackSummary, ReplayRecord, Resources, StackCrash
from advsim_ros.core.drivable import DrivableConfig
from advsim_ros.core.journal import QueryRecord
from advsim_ros.core.lidar.config import ResimConfig
from advsim_ros.core.lidar.query import query_sweep, tracks_digest
from advsim_ros.core.lidar.resim import ResimModel
from advsim_ros.core.metrics import MetricsConfig
from advsim_ros.core.types import ActorTrack, DrivableArea, Perturbation, Scenario, Sweep, replace_actors
from advsim_ros.io.bag import BagReader, bag_layout_json, read_scenario_bag, write_scenario_bag
from advsim_ros.io.cache import cache_root
from advsim_ros.io.drivable_cache import bag_drivable_area

ADVERSARIAL_BAG = "adversarial"
T = TypeVar("T")


@dataclass
class OutputsInputs:
    """What the outputs are made from besides the journal, read once (ahead of time by attack.outputs_worker):
    the log with the window's sweeps, the drivable area as scored, and the adversarial sweeps already made
    (by the digest of the perturbed tracks they show) with the model they were made from."""

    scenario: Scenario
    drivable: DrivableArea
    model: ResimModel | None = None
    made: dict[str, tuple[Sweep, ...]] = field(default_factory=dict)  # by tracks_digest of the perturbed tracks


def read_outputs_inputs(checked: Preflight) -> OutputsInputs:
    """The log with the window's sweeps (the only ones re-simulated and drawn) and the drivable area as scored."""
    drivable_config = section(checked.parameters[graph.SCORER.name], graph.DRIVABLE.key, DrivableConfig, "drivable")
    frames = checked.window.frame_indices(checked.scenario.num_frames)
    stamps = checked.scenario.frame_stamps_ns
    scenario = read_scenario_bag(
        checked.bag, config=checked.bag_config, sweeps_between=(int(stamps[frames.start]), int(stamps[frames.stop - 1]))
    )
    drivable = bag_drivable_area(checked.bag, checked.scenario, drivable_config, checked.bag_config)
    return OutputsInputs(scenario, drivable)


def write_outputs(
    options: AttackOptions,
    checked: Preflight,
    records: list[QueryRecord],
    journal_path: Path,
    wall_time: float,
    crashes: list[StackCrash],
    domain_id: int | None,
    resources: Callable[[], Resources],
    inputs: OutputsInputs | None = None,
    fork: bool = False,
) -> AttackSummary:
    """Write the adversarial bag (attacks only), summary.json and bev.png (bev.gif and report.html too unless
    --no-visuals); return the summary. ``resources`` is asked for once the bag is written (the graph's
    processes may end meanwhile); ``fork``: see write_view_figures."""
    from advsim_ros.viz.attack_view import load_attack_view
    from advsim_ros.viz.outputs import write_view_figures

    out_dir = options.out_dir.resolve()
    inputs = inputs or read_outputs_inputs(checked)
    analysis = attack_summary(records)
    window = checked.window
    decision_frame = window.window_start_frame + window.decision_index
    analysis["controls"] = controls(records, int(checked.scenario.frame_stamps_ns[decision_frame]))
    scorer = checked.parameters[graph.SCORER.name]
    drivable = inputs.drivable
    metrics = section(scorer, "metrics", MetricsConfig, "/scorer metrics")
    faults = query_faults(records, checked.scenario, decision_frame, metrics, drivable)
    for entry in analysis["queries"]:
        entry["fault"] = faults.get(entry["query_id"])
    best, recorded_id = analysis.get("best"), analysis.get("recorded_query_id")
    reproduction = best.get("reproduction") if best else None
    recorded_fault = faults.get(recorded_id) if recorded_id is not None else None
    analysis["finding"] = finding(analysis, analysis["controls"], reproduction, recorded_fault)
    summary: AttackSummary = {
        "scenario": {
            "bag": str(checked.bag),
            "scenario_id": checked.scenario.scenario_id,
            "window_start_frame": window.window_start_frame,
            "history_frames": window.history_frames,
            "future_frames": window.future_frames,
            "bag_params": bag_layout_json(checked.bag_config),  # the layout of the bag and of adversarial/
        },
        "stack": {"name": options.stack.name, "command": list(options.stack.command)},
        "search": {
            "algorithm": options.algorithm,
            "queries": options.queries,
            "seed": options.seed,
            "reruns": options.reruns,
            "rerun_top": options.rerun_top,
            "lanes": options.lanes,  # evaluation graphs of the last run (never changes a score)
        },
        **analysis,
        "verdict": attack_verdict(records, options.replay_only).as_json(),
        "stack_crashes": crashes,
        "wall_time_s": wall_time,
        # this run's processes, asked for once the bag is written (below): the place in summary.json kept here
        "resources": Resources(processes={}, graph_peak_rss_mb=0.0, graph_cpu_s=0.0, orchestrator_peak_rss_mb=0.0),
        "ros_domain_id": domain_id,
        "outputs": {"journal": str(journal_path), "bev": str(out_dir / "bev.png")},
    }
    scenario = inputs.scenario
    adversarial = original = window.crop(scenario)
    if options.replay_only:
        summary["replay"] = _replay_runs(records)
        recorded_perturbation = recorded_message(checked.bag, topics.PERTURBATION, perturbation_from_msg)
        summary["perturbed_actors"] = list(recorded_perturbation.actor_ids) if recorded_perturbation else []
    else:
        summary["perturbed_actors"] = [] if not records else _perturbed_actors(records)
        recorded = recorded_query(records)
        if recorded is not None:
            adversarial, reproduced = _write_adversarial_bag(out_dir, checked, inputs, recorded)
            summary["outputs"]["adversarial_bag"] = str(out_dir / ADVERSARIAL_BAG)
            summary["recorded_inputs_reproduced"] = reproduced
    summary["resources"] = resources()
    write_json_atomically(out_dir / "summary.json", summary)
    by_id = {record.query_id: record for record in records}
    shown = by_id.get(recorded_id) if recorded_id is not None else None
    if options.replay_only and records:
        shown = records[-1]
    # what the bag and the journal hold, not read back: the window (original and adversarial) and the shown plan
    bag = out_dir / ADVERSARIAL_BAG if summary["outputs"].get("adversarial_bag") else checked.bag
    written = (adversarial, shown.plan if shown else None)
    view = load_attack_view(bag, summary, checked.bag_config, original, written)
    # bev.gif and report.html too (`advsim report OUTDIR` draws them again from the bag and summary.json)
    visuals = bool(options.visual_report and summary["outputs"].get("adversarial_bag"))
    summary["outputs"].update(write_view_figures(view, out_dir, visuals, fork=fork))
    if visuals:
        write_json_atomically(out_dir / "summary.json", summary)
    return summary


def _perturbed_actors(records: list[QueryRecord]) -> list[str]:
    searched = [record for record in records if record.actor_ids]
    return list(searched[0].actor_ids) if searched else []


def _replay_runs(records: list[QueryRecord]) -> ReplayRecord:
    values = [record.value for record in records]
    return {"runs": len(records), "adversarial_losses": [None if v != v else v for v in values]}


def adversarial_sweeps(inputs: OutputsInputs, checked: Preflight, tracks: tuple[ActorTrack, ...]) -> tuple[Sweep, ...]:
    """The window's history sweeps with ``tracks`` re-simulated, as lidar_resim made them (made once per tracks)."""
    key = tracks_digest(tracks)
    if key not in inputs.made:
        window = checked.window
        cropped = window.crop(inputs.scenario)  # as lidar_resim: the model of the window's frames
        resim_parameters = checked.parameters[graph.LIDAR_RESIM.name]
        seed = int(resim_parameters.get("seed", 0))
        cache = Path(str(resim_parameters.get("cache_dir") or cache_root() / "resim"))
        if tracks and inputs.model is None:
            config = section(resim_parameters, "resim", ResimConfig, "resim")
            inputs.model = ResimModel.build(cropped, cache_dir=cache, config=config)
        sweeps_by_stamp = {sweep.stamp_ns: sweep for sweep in cropped.sweeps}
        sweeps = []
        for index in range(window.history_frames):
            logged = sweeps_by_stamp[int(cropped.frame_stamps_ns[index])]
            pose = cropped.ego.poses[index]
            points = query_sweep(inputs.model, cropped, logged, pose, tracks, seed)
            sweeps.append(Sweep(logged.stamp_ns, logged.frame_id, points, pose @ cropped.ego_T_sensor))
        inputs.made[key] = tuple(sweeps)
    return inputs.made[key]


def _write_adversarial_bag(
    out_dir: Path, checked: Preflight, inputs: OutputsInputs, recorded: QueryRecord
) -> tuple[Scenario, bool]:
    """The recorded query's window as a scenario bag; whether its sweeps digest to what the stack received."""
    window = checked.window
    scenario = inputs.scenario
    frames = window.frame_indices(scenario.num_frames)
    cropped = window.crop(scenario)
    bag = checked.bag_config
    odometry = odometry_msgs(scenario.ego, bag.world_frame, bag.ego_frame)
    sweeps = adversarial_sweeps(inputs, checked, recorded.tracks)
    digest = InputDigest()
    for index, sweep in enumerate(sweeps):
        digest.frame(sweep.stamp_ns, codec.encode(odometry[frames.start + index]), cropped.ego.poses[index])
        digest.sweep(codec.encode(cloud_msg(sweep)))
    adversarial = Scenario(
        scenario_id=f"{cropped.scenario_id}/adversarial",
        frame_stamps_ns=cropped.frame_stamps_ns,
        ego=cropped.ego,
        actors=replace_actors(cropped.actors, recorded.tracks),
        sweeps=sweeps,
        ego_T_sensor=cropped.ego_T_sensor,
        sensor=cropped.sensor,
        road_map=cropped.road_map,
        ego_geometry=cropped.ego_geometry,
        sensor_frame=cropped.sensor_frame,
        drivable_area=inputs.drivable,
    )
    decision = int(scenario.frame_stamps_ns[frames.start + window.decision_index])
    extra = [
        (
            topics.SCORE.name,
            names.QUERY_SCORE,
            decision,
            codec.encode(score_msg(ScoreRecord.from_dict(dict(recorded.score)), 0)),
        ),
        (
            topics.PERTURBATION.name,
            names.PERTURBATION,
            decision,
            codec.encode(
                perturbation_msg(
                    Perturbation(
                        recorded.query_id,
                        scenario.scenario_id,
                        recorded.actor_ids,
                        np.asarray(recorded.delta, dtype=np.float64),
                        recorded.algorithm,
                    ),
                    0,
                )
            ),
        ),
    ]
    if recorded.plan is not None:
        extra.append(
            (topics.PLAN.name, names.PATH, decision, codec.encode(path_msg(recorded.plan, decision, bag.world_frame)))
        )
    # MarkerArrays for Foxglove and RViz on /advsim/markers/* (advsim_ros.viz)
    from advsim_ros.viz.markers import StackOutputs, scenario_markers

    extra += scenario_markers(
        adversarial, recorded.actor_ids, StackOutputs(recorded.plan), window.decision_index, bag.world_frame
    )
    write_scenario_bag(
        adversarial, out_dir / ADVERSARIAL_BAG, config=bag, source=f"advsim attack of {checked.bag}", overwrite=True,
        extra=extra,
    )  # fmt: skip
    return adversarial, digest.hexdigest() == recorded.score.get("input_digest")


def recorded_message(path: Path, topic: TopicSpec, parse: Callable[[Any], T]) -> T | None:
    """The first message of a topic of an (adversarial) bag, parsed; None when the bag has none."""
    with BagReader(path) as reader:
        connection = reader.connection(topic.name, topic.msgtype)
        if connection is None:
            return None
        for _, _, message in reader.messages([connection]):
            return parse(message)
    return None


def recorded_score(path: Path) -> ScoreRecord | None:
    """The score stored in an adversarial bag (None when it has none)."""
    return recorded_message(path, topics.SCORE, score_from_msg)
