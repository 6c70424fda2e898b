"""One job of a campaign (an attack, or the replay of a found scenario on another stack) in a process of its own.

    python -m advsim_ros.campaign.worker JOB.json

A Ray task starts this process (campaign.schedule.run_job) so that every attack gets a fresh
interpreter and its own ROS domain, as `advsim attack` would; the process is tied to the Ray
worker (parent-death signal), and its graph to it (ros.launcher), so a dead driver leaves
nothing running. The job's outcome goes atomically to OUT/job_result.json: that file is what
"finished" means, and a job that has it is never run again. A job whose inputs were shipped to its
node (campaign.shipping) names their paths there under "local"; its plan keeps the driver's, its identity.
"""

from __future__ import annotations

import json
import math
import resource
import sys
import time
from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path
from typing import Any, NotRequired, TypeAlias, TypedDict

from advsim_ros.campaign.config import AttackPlan, stack_spec
from advsim_ros.campaign.results import ResultsRow, TransferRow, attack_row, best_curve, identity_of
from advsim_ros.core.atomic import write_json_atomically
from advsim_ros.core.attack_summary import AttackSummary, FindingRecord, Score, metric
from advsim_ros.io.bag import bag_layout_of

RESULT_NAME = "job_result.json"
# JOB.json, what campaign.schedule (and shipping, suite) hand the worker process: its keys depend on the kind of
# job and it holds the config's own entries (a stack entry, parameter overrides), so it stays JSON here
JobSpec: TypeAlias = dict[str, Any]


class AttackJobResult(TypedDict):
    """OUT/job_result.json of an attack job."""

    row: ResultsRow
    curve: list[float]  # best L_adv after each searched query (results.best_curve)
    adversarial: Score | None
    bag: str | None  # the adversarial bag, when the attack recorded a query
    finding: FindingRecord | None
    bag_params: NotRequired[Mapping[str, object]]  # the bag's layout (io.bag.bag_layout_json), when not the contract's


class TransferJobResult(TypedDict):
    """OUT/job_result.json of a transfer job."""

    row: TransferRow


JobResult: TypeAlias = AttackJobResult | TransferJobResult


def _cost(summary: AttackSummary, wall_s: float) -> dict[str, float]:
    """Wall time, CPU seconds and peak memory of the job: its graph's processes, its outputs process and this one."""
    resources = summary["resources"]
    own = resource.getrusage(resource.RUSAGE_SELF)
    return {
        "wall_s": wall_s,
        "cpu_s": resources.get("graph_cpu_s", 0.0) + resources.get("outputs_cpu_s", 0.0) + own.ru_utime + own.ru_stime,
        "peak_rss_mb": resources.get("graph_peak_rss_mb", 0.0)
        + resources.get("outputs_peak_rss_mb", 0.0)
        + own.ru_maxrss / 1024.0,
    }


def run_job(job: JobSpec) -> JobResult:
    """Run the job described by job (see campaign.schedule) and return what goes into the campaign journal."""
    from advsim_ros.attack import AttackOptions, run_attack

    out_dir = Path(job["out_dir"])
    config_dir = Path(job["config_dir"])
    started = time.monotonic()
    if job["kind"] == "attack":
        plan = AttackPlan.from_json(job["plan"])
        local = job.get("local") or {}
        runnable = replace(plan, bag=local.get("bag", plan.bag), stack_entry=local.get("stack_entry", plan.stack_entry))
        summary = run_attack(runnable.options(out_dir, config_dir)).summary
        row = attack_row(identity_of(plan), summary, _cost(summary, time.monotonic() - started), job["relative_dir"])
        result: AttackJobResult = {
            "row": row, "curve": best_curve(summary), "adversarial": summary.get("adversarial"),
            "bag": summary["outputs"].get("adversarial_bag"), "finding": summary.get("finding"),
        }  # fmt: skip
        if plan.bag_params is not None:  # adversarial/'s layout, too
            result["bag_params"] = plan.bag_params
        return result
    options = AttackOptions(
        bag=Path(job["bag"]), out_dir=out_dir, stack=stack_spec(job["stack_entry"], config_dir), queries=0,
        window_start_frame=0, replay_only=True, plan_timeout=float(job["plan_timeout"]), visual_report=False,
        parameter_overrides=job.get("parameters") or {},
        bag_config=bag_layout_of(job.get("bag_params"), f"{job['out_dir']}: job bag_params"),
    )  # fmt: skip
    summary = run_attack(options).summary
    queries = summary.get("queries") or []
    score: Score = queries[-1]["score"] if queries else {}
    collision, loss = metric(score, "collision_5s"), metric(score, "adversarial_loss")
    replayed: TransferRow = {
        "attack": job["source"], "source_stack": job["source_stack"], "target_stack": job["target_stack"],
        "collision_5s": None if math.isnan(collision) else collision,  # null stays null (not scored)
        "adversarial_loss": None if math.isnan(loss) else loss,
        "status": str(score.get("status", "failed")), "out_dir": job["relative_dir"],
    }  # fmt: skip
    return {"row": replayed}


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    job = json.loads(Path(args[0]).read_text(encoding="utf-8"))
    result = run_job(job)
    write_json_atomically(Path(job["out_dir"]) / RESULT_NAME, result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
