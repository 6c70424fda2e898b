"""One row per attack of a campaign (results.csv), built from the attack's summary.json.

The row names the attack (scenario, window, stack, algorithm, budget, actors, objective, seed),
gives the original scenario's and the adversarial scenario's metrics side by side, and what the
attack cost. ``transfer`` rows say how a found scenario fared when replayed on another stack.
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

from advsim_ros.campaign.config import FailureRule
from advsim_ros.core.search.driver import NOT_SEARCHED

# the metrics of one scored query that the report tabulates (advsim_msgs/QueryScore field names)
METRICS = (
    "adversarial_loss",
    "collision_3s",
    "collision_5s",
    "l2_human_3s",
    "l2_human_5s",
    "lateral_acceleration",
    "jerk",
    "open_loop_collision_5s",  # closed loop: the decision plan's, beside what the ego drove
    "min_distance",
    "detection_ap",
    "prediction_l2_3s",
    "prediction_l2_5s",
)
IDENTITY = ("attack", "scenario", "window_start", "stack", "algorithm", "budget", "actors", "objective", "seed", "loop")
COLUMNS = (
    *IDENTITY,
    "status",  # ok | failed (the attack could not run to its end, or its queries failed: see error)
    *(f"original_{name}" for name in METRICS),
    *(f"adversarial_{name}" for name in METRICS),
    "queries",  # scored queries (original and re-runs included)
    "failed_queries",
    "flaky",  # the best query did not reproduce when re-run
    "original_flaky",  # the original did not reproduce when re-run (attack.controls)
    "sim_gap_adversarial_loss",  # identity control minus original: what re-simulation alone does to L_adv
    "sim_gap_plan_l2_5s",  # ... and to the plan at 5 s [m]
    "sim_dominated",  # the finding does not gain more than the margin over the identity control's deviation
    "fault",  # a colliding finding: avoidable | unavoidable by an ego within its limits (core.fault)
    "mover",  # who moved into whom at its first contact: ego_into_actor | actor_into_ego | both
    "excluded",  # why the finding is not counted as the stack's failure (reasons, ';'-separated)
    "failure",  # 1 when the campaign's failure rule counts it as the stack's failure (campaign.outputs)
    "wall_s",
    "cpu_s",
    "peak_rss_mb",
    "bag",
    "out_dir",  # relative to the campaign folder
    "error",
)
TRANSFER_COLUMNS = ("attack", "source_stack", "target_stack", "collision_5s", "adversarial_loss", "status", "out_dir")


def _metric(score: Mapping[str, Any] | None, name: str) -> float:
    if not score:
        return math.nan
    value = score.get(name)
    return math.nan if value is None else float(value)


def attack_row(
    identity: Mapping[str, Any], summary: Mapping[str, Any], cost: Mapping[str, float], out_dir: str
) -> dict[str, Any]:
    """The results row of a finished attack from its summary.json and what running it cost."""
    row: dict[str, Any] = {key: identity.get(key, "open") for key in IDENTITY}  # plans of before loops: open
    verdict = summary.get("verdict") or {"ok": True, "reason": ""}  # summaries of before verdicts: as they were
    row["status"] = "ok" if summary.get("adversarial") and verdict["ok"] else "failed"
    for prefix, score in (("original", summary.get("original")), ("adversarial", summary.get("adversarial"))):
        for name in METRICS:
            row[f"{prefix}_{name}"] = _metric(score, name)
    row["queries"] = len(summary.get("queries", ()))
    row["failed_queries"] = int(summary.get("failed_queries", 0))
    row["flaky"] = bool(summary.get("flaky"))
    controls, finding = summary.get("controls") or {}, summary.get("finding") or {}
    gap = controls.get("sim_gap") or {}
    fault = finding.get("fault") or {}
    row["original_flaky"] = _flag(controls.get("original_flaky"))
    row["sim_gap_adversarial_loss"] = _metric(gap, "adversarial_loss")
    row["sim_gap_plan_l2_5s"] = _metric(gap, "plan_l2_5s")
    row["sim_dominated"] = _flag(finding.get("sim_dominated"))
    row["fault"] = fault.get("class", "")
    row["mover"] = (fault.get("contact") or {}).get("mover", "")
    row["excluded"] = ";".join(str(reason).split(":")[0] for reason in finding.get("excluded") or ())
    # by the default rule; campaign.outputs applies the campaign's own (failure: in its config)
    row["failure"] = int(FailureRule().failed(summary.get("adversarial"), summary.get("finding")))
    row["wall_s"] = float(cost.get("wall_s", math.nan))
    row["cpu_s"] = float(cost.get("cpu_s", math.nan))
    row["peak_rss_mb"] = float(cost.get("peak_rss_mb", math.nan))
    row["bag"] = str(identity["bag"])
    row["out_dir"] = out_dir
    row["error"] = "" if row["status"] == "ok" else verdict["reason"] or "no adversarial scenario was scored"
    return row


def _flag(value: Any) -> bool | str:
    """A yes/no column: '' when it was not measured (no re-runs, no identity control, nothing found)."""
    return "" if value is None else bool(value)


def failed_row(identity: Mapping[str, Any], error: str, out_dir: str) -> dict[str, Any]:
    """The row of an attack that could not run to its end (its metrics NaN, the error one line)."""
    row: dict[str, Any] = {key: identity.get(key, "open") for key in IDENTITY}
    row.update({f"{p}_{name}": math.nan for p in ("original", "adversarial") for name in METRICS})
    row.update(status="failed", queries=0, failed_queries=0, flaky=False, wall_s=math.nan, cpu_s=math.nan, failure=0)
    row.update(original_flaky="", sim_gap_adversarial_loss=math.nan, sim_gap_plan_l2_5s=math.nan, sim_dominated="")
    row.update(fault="", mover="", excluded="")
    row.update(peak_rss_mb=math.nan, bag=str(identity["bag"]), out_dir=out_dir, error=error.splitlines()[0][:300])
    return row


def best_curve(summary: Mapping[str, Any]) -> list[float]:
    """Best L_adv found after each searched query (the original, re-runs and controls left out)."""
    best, curve = -math.inf, []
    for query in summary.get("queries", ()):
        if query.get("algorithm") in NOT_SEARCHED:
            continue
        value = query.get("score", {}).get("adversarial_loss")
        if value is not None and math.isfinite(value):
            best = max(best, float(value))
        curve.append(best if math.isfinite(best) else math.nan)
    return curve


def to_csv(rows: Iterable[Mapping[str, Any]], columns: Sequence[str]) -> str:
    """CSV text with a header; NaN as an empty cell."""
    stream = io.StringIO()
    writer = csv.DictWriter(stream, fieldnames=list(columns), extrasaction="ignore", lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({k: ("" if isinstance(v, float) and math.isnan(v) else v) for k, v in row.items()})
    return stream.getvalue()
