"""An attack's output folder made without the ROS graph, on a real KITTI window, for the viz and export tests.

The window is KITTI tracking 0000, frames 20..79 (1 s history + 5 s future). The "perturbed" actor is
one of the window's actors given a new trajectory along the SDV's logged path: 2.5 s ahead of the
SDV until it stops at the SDV's position of frame 40, so the SDV following its plan (its logged
future) runs into it. Scores come from the scorer's own function (core.scoring.evaluate_query),
summary.json from the attack's own summary code (the controls, the finding and the fault of the
colliding query included: the original re-run and the identity control score like the original) and
the bag from write_scenario_bag with the extra topics the attack writes, markers included.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from advsim_ros import graph
from advsim_ros.attack.controls import controls, finding, query_faults
from advsim_ros.attack.summary import attack_summary
from advsim_ros.contract import codec, names, topics
from advsim_ros.contract.enums import Status
from advsim_ros.contract.plan import path_msg
from advsim_ros.contract.protocol import ScoreRecord, perturbation_msg, score_msg
from advsim_ros.core.curation import crop_frames
from advsim_ros.core.journal import Fingerprint, Journal, QueryRecord
from advsim_ros.core.metrics import MetricsConfig
from advsim_ros.core.objective import load_scorer_settings
from advsim_ros.core.scoring import evaluate_query
from advsim_ros.core.types import ActorClass, ActorTrack, Perturbation, Plan, Scenario, replace_actors
from advsim_ros.io.bag import write_scenario_bag
from advsim_ros.viz.markers import StackOutputs, scenario_markers

REPO = Path(__file__).resolve().parents[2]
HISTORY, FUTURE = 10, 50
DECISION = HISTORY - 1
STOP_FRAME = 40  # the perturbed actor stops where the SDV is at this frame of the window


def _score(query_id: int, plan: Plan, window: Scenario, moved: list[ActorTrack]) -> dict[str, Any]:
    settings = load_scorer_settings(REPO / "params" / "scorer.yaml", node=graph.SCORER.name)
    evaluation = evaluate_query(plan, window, moved, DECISION, settings, None)
    terms, metrics = evaluation.terms, evaluation.metrics
    return ScoreRecord(
        query_id, Status.OK, adversarial_loss=terms.value, imitation_loss=terms.imitation,
        collision_loss=terms.collision, comfort_loss=terms.comfort, collision_3s=metrics.at("collision", 3.0),
        collision_5s=metrics.at("collision", 5.0), l2_human_3s=metrics.at("l2_human", 3.0),
        l2_human_5s=metrics.at("l2_human", 5.0), lateral_acceleration=metrics.lateral_acceleration, jerk=metrics.jerk,
        sweeps_delivered=HISTORY, plans_received=HISTORY,
    ).as_dict()  # fmt: skip


def _perturbed(window: Scenario, actor: ActorTrack) -> ActorTrack:
    """The actor driving the SDV's logged path 25 frames ahead of it, stopping at the SDV's pose of STOP_FRAME."""
    index = np.minimum(np.arange(window.num_frames) + 25, STOP_FRAME)
    yaws = window.ego.yaws[index]
    size = np.array([4.5, 1.9, 1.6])
    ahead = window.ego_geometry.forward_offset  # the SDV's box centre, where the actor's centre goes
    centers = np.column_stack([
        window.ego.xy[index, 0] + ahead * np.cos(yaws), window.ego.xy[index, 1] + ahead * np.sin(yaws),
        window.ego.poses[index, 2, 3] + size[2] / 2.0,
    ])  # fmt: skip
    return ActorTrack(actor.actor_id, ActorClass.VEHICLE, size, window.frame_stamps_ns, centers, yaws)


@pytest.fixture(scope="session")
def attack_out(kitti_scenario: Scenario, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """OUTDIR of an attack on a KITTI window: adversarial/ (with markers), summary.json, queries.jsonl."""
    root = tmp_path_factory.mktemp("viz")
    window = crop_frames(kitti_scenario, 20, 20 + HISTORY + FUTURE - 1)
    source = write_scenario_bag(window, root / "source", source="kitti_tracking/0000 frames 20..79")
    out = root / "attack"
    out.mkdir()
    moved = [_perturbed(window, window.actors[0])]
    future = slice(DECISION + 1, window.num_frames)
    plan = Plan(window.frame_stamps_ns[future], window.ego.xy[future], window.ego.yaws[future])
    delta = (0.5, -0.25)
    logged = (window.actor(moved[0].actor_id),)
    records = [
        QueryRecord(0, "original", (), (), _score(0, plan, window, []), (), plan),
        QueryRecord(1, "random", (moved[0].actor_id,), delta, _score(1, plan, window, moved), tuple(moved), plan),
        QueryRecord(2, "original", (), (), _score(2, plan, window, []), (), plan),
        QueryRecord(3, "identity", (moved[0].actor_id,), (), _score(3, plan, window, list(logged)), logged, plan),
    ]
    journal = Journal.open(out / "queries.jsonl", Fingerprint({"bag": str(source)}))
    for record in records:
        journal.append(record)
    summary = {
        "scenario": {"bag": str(source), "scenario_id": window.scenario_id, "window_start_frame": 0,
                     "history_frames": HISTORY, "future_frames": FUTURE},
        "stack": {"name": "logged_future", "command": []},
        "search": {"algorithm": "random", "queries": 1, "seed": 0, "reruns": 0, "rerun_top": 1},
        **attack_summary(records),
        "stack_crashes": [], "wall_time_s": 1.0, "ros_domain_id": None,
        "outputs": {"journal": str(out / "queries.jsonl"), "adversarial_bag": str(out / "adversarial")},
        "perturbed_actors": [moved[0].actor_id],
    }  # fmt: skip
    summary["controls"] = controls(records, int(window.frame_stamps_ns[DECISION]))
    faults = query_faults(records, window, DECISION, MetricsConfig(), None)
    for entry in summary["queries"]:
        entry["fault"] = faults.get(entry["query_id"])
    summary["finding"] = finding(summary, summary["controls"], None, faults.get(summary["recorded_query_id"]))
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    adversarial = Scenario(
        scenario_id=f"{window.scenario_id}/adversarial", frame_stamps_ns=window.frame_stamps_ns, ego=window.ego,
        actors=replace_actors(window.actors, moved), sweeps=window.sweeps[:HISTORY], ego_T_sensor=window.ego_T_sensor,
        sensor=window.sensor, ego_geometry=window.ego_geometry,
        sensor_frame=window.sensor_frame,
    )  # fmt: skip
    decision_ns = int(window.frame_stamps_ns[DECISION])
    perturbation = Perturbation(1, window.scenario_id, (moved[0].actor_id,), np.array(delta), "random")
    extra = [
        (topics.SCORE.name, names.QUERY_SCORE, decision_ns,
         codec.encode(score_msg(ScoreRecord.from_dict(records[1].score.copy()), 0))),  # type: ignore[arg-type]
        (topics.PERTURBATION.name, names.PERTURBATION, decision_ns, codec.encode(perturbation_msg(perturbation, 0))),
        (topics.PLAN.name, names.PATH, decision_ns, codec.encode(path_msg(plan, decision_ns, "world"))),
        *scenario_markers(adversarial, [moved[0].actor_id], StackOutputs(plan), DECISION, "world"),
    ]  # fmt: skip
    write_scenario_bag(adversarial, out / "adversarial", source="test", extra=extra)
    return out
