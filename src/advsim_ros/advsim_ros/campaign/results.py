"""One row per attack of a campaign (results.csv), built from the attack's summary.json.

The row names the attack (scenario, window, stack, algorithm, budget, actors, objective, seed),
gives the original scenario's and the adversarial scenario's metrics side by side, and what the
attack cost. ``transfer`` rows say how a found scenario fared when replayed on another stack.
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import TypedDict, TypeVar, cast

from advsim_ros.campaign.config import AttackPlan, CampaignError, FailureRule
from advsim_ros.core.attack_summary import AttackSummary, Score, metric
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


class Named(TypedDict):
    """The IDENTITY columns."""

    attack: str
    scenario: str
    window_start: int
    stack: str
    algorithm: str
    budget: int
    actors: int
    objective: str
    seed: int
    loop: str  # open | closed


class AttackIdentity(Named):
    """What names an attack: the IDENTITY columns and its bag (identity_of)."""

    bag: str


class ScoreColumns(TypedDict):
    """The original's and the adversarial scenario's METRICS, NaN where not measured."""

    original_adversarial_loss: float
    original_collision_3s: float
    original_collision_5s: float
    original_l2_human_3s: float
    original_l2_human_5s: float
    original_lateral_acceleration: float
    original_jerk: float
    original_open_loop_collision_5s: float
    original_min_distance: float
    original_detection_ap: float
    original_prediction_l2_3s: float
    original_prediction_l2_5s: float
    adversarial_adversarial_loss: float
    adversarial_collision_3s: float
    adversarial_collision_5s: float
    adversarial_l2_human_3s: float
    adversarial_l2_human_5s: float
    adversarial_lateral_acceleration: float
    adversarial_jerk: float
    adversarial_open_loop_collision_5s: float
    adversarial_min_distance: float
    adversarial_detection_ap: float
    adversarial_prediction_l2_3s: float
    adversarial_prediction_l2_5s: float


class ResultsRow(Named, ScoreColumns):
    """One row of results.csv (COLUMNS), as the campaign journal keeps it."""

    status: str  # ok | failed
    queries: int
    failed_queries: int
    flaky: bool
    original_flaky: bool | str  # '' when not measured (_flag)
    sim_gap_adversarial_loss: float
    sim_gap_plan_l2_5s: float
    sim_dominated: bool | str  # '' when not measured
    fault: str
    mover: str
    excluded: str
    failure: int  # 0 | 1
    wall_s: float
    cpu_s: float
    peak_rss_mb: float
    bag: str
    out_dir: str
    error: str


class TransferRow(TypedDict):
    """One row of transfer.csv (TRANSFER_COLUMNS): a found scenario replayed on another stack."""

    attack: str
    source_stack: str
    target_stack: str
    collision_5s: float | None  # None: the replay was not scored (NaN when its job failed)
    adversarial_loss: float | None
    status: str
    out_dir: str


def identity_of(plan: AttackPlan) -> AttackIdentity:
    """The IDENTITY columns of an attack's row (and its bag)."""
    return {
        "attack": plan.key, "scenario": plan.scenario, "window_start": plan.window_start, "stack": plan.stack,
        "algorithm": plan.algorithm, "budget": plan.budget, "actors": plan.actors, "objective": plan.objective,
        "seed": plan.seed, "loop": plan.loop, "bag": plan.bag,
    }  # fmt: skip


def _scores(original: Score | None, adversarial: Score | None) -> ScoreColumns:
    columns = {f"{prefix}_{name}": metric(score, name) for prefix, score in (("original", original),
               ("adversarial", adversarial)) for name in METRICS}  # fmt: skip
    # keys built from METRICS, which ScoreColumns spells out (tests/campaign/test_rows.py checks they agree)
    return cast(ScoreColumns, columns)


def _named(identity: AttackIdentity) -> Named:
    """The IDENTITY columns in their order (the journal keeps a row's keys in the order they were set)."""
    return {
        "attack": identity["attack"], "scenario": identity["scenario"], "window_start": identity["window_start"],
        "stack": identity["stack"], "algorithm": identity["algorithm"], "budget": identity["budget"],
        "actors": identity["actors"], "objective": identity["objective"], "seed": identity["seed"],
        "loop": identity.get("loop", "open"),  # identities of before loops have none: open (the paper's)
    }  # fmt: skip


def attack_row(identity: AttackIdentity, summary: AttackSummary, cost: Mapping[str, float], out_dir: str) -> ResultsRow:
    """The results row of a finished attack from its summary.json and what running it cost."""
    verdict = summary.get("verdict")  # summaries of before verdicts: as they were
    status = "ok" if summary.get("adversarial") and (verdict is None or verdict["ok"]) else "failed"
    controls, finding = summary.get("controls"), summary.get("finding")
    gap = controls.get("sim_gap") if controls else None
    fault = finding.get("fault") if finding else None
    contact = fault.get("contact") if fault else None
    return {
        **_named(identity),
        "status": status,
        **_scores(summary.get("original"), summary.get("adversarial")),
        "queries": len(summary.get("queries", ())),
        "failed_queries": int(summary.get("failed_queries", 0)),
        "flaky": bool(summary.get("flaky")),
        "original_flaky": _flag(controls.get("original_flaky") if controls else None),
        "sim_gap_adversarial_loss": metric(gap, "adversarial_loss"),
        "sim_gap_plan_l2_5s": metric(gap, "plan_l2_5s"),
        "sim_dominated": _flag(finding.get("sim_dominated") if finding else None),
        "fault": fault.get("class", "") if fault else "",
        "mover": contact.get("mover", "") if contact else "",
        "excluded": ";".join(
            str(reason).split(":")[0] for reason in (finding.get("excluded") if finding else ()) or ()
        ),
        # by the default rule; campaign.outputs applies the campaign's own (failure: in its config)
        "failure": int(FailureRule().failed(summary.get("adversarial"), summary.get("finding"))),
        "wall_s": float(cost.get("wall_s", math.nan)),
        "cpu_s": float(cost.get("cpu_s", math.nan)),
        "peak_rss_mb": float(cost.get("peak_rss_mb", math.nan)),
        "bag": str(identity["bag"]),
        "out_dir": out_dir,
        "error": ""
        if status == "ok"
        else (verdict["reason"] if verdict else "") or "no adversarial scenario was scored",
    }


def _flag(value: bool | None) -> bool | str:
    """A yes/no column: '' when it was not measured (no re-runs, no identity control, nothing found)."""
    return "" if value is None else bool(value)


def failed_row(identity: AttackIdentity, error: str, out_dir: str) -> ResultsRow:
    """The row of an attack that could not run to its end (its metrics NaN, the error one line)."""
    return {
        **_named(identity), **_scores(None, None), "status": "failed", "queries": 0, "failed_queries": 0,
        "flaky": False, "wall_s": math.nan, "cpu_s": math.nan, "failure": 0, "original_flaky": "",
        "sim_gap_adversarial_loss": math.nan, "sim_gap_plan_l2_5s": math.nan, "sim_dominated": "", "fault": "",
        "mover": "", "excluded": "", "peak_rss_mb": math.nan, "bag": str(identity["bag"]), "out_dir": out_dir,
        "error": error.splitlines()[0][:300],
    }  # fmt: skip


def best_curve(summary: AttackSummary) -> list[float]:
    """Best L_adv found after each searched query (the original, re-runs and controls left out)."""
    best, curve = -math.inf, []
    for query in summary.get("queries", ()):
        if query.get("algorithm") in NOT_SEARCHED:
            continue
        value = metric(query.get("score"), "adversarial_loss")
        if math.isfinite(value):
            best = max(best, value)
        curve.append(best if math.isfinite(best) else math.nan)
    return curve


def to_csv(rows: Iterable[Mapping[str, object]], columns: Sequence[str]) -> str:
    """CSV text with a header; NaN as an empty cell."""
    stream = io.StringIO()
    writer = csv.DictWriter(stream, fieldnames=list(columns), extrasaction="ignore", lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({k: ("" if isinstance(v, float) and math.isnan(v) else v) for k, v in row.items()})
    return stream.getvalue()


# Reading results.csv and transfer.csv back: every cell is text; each column's parser turns it into the value
# the row had (to_csv wrote NaN as '', a bool as True/False), each with what it expects for the error message.
Parser = tuple[Callable[[str], object], str]
_TEXT: Parser = (str, "text")
_INT: Parser = (int, "an integer")
_NUMBER: Parser = (lambda cell: math.nan if cell == "" else float(cell), "a number or empty (NaN)")
_OPTIONAL: Parser = (lambda cell: None if cell == "" else float(cell), "a number or empty (not scored)")
_YES_NO = {"True": True, "False": False}
_BOOL: Parser = (lambda cell: _YES_NO[cell], "True or False")
_FLAG: Parser = (lambda cell: "" if cell == "" else _YES_NO[cell], "True, False or empty (not measured)")
_IDENTITY_INTS = ("window_start", "budget", "actors", "seed")
_INTS = (*_IDENTITY_INTS, "queries", "failed_queries", "failure")
_NUMBERS = (*(f"{p}_{name}" for p in ("original", "adversarial") for name in METRICS), "sim_gap_adversarial_loss",
            "sim_gap_plan_l2_5s", "wall_s", "cpu_s", "peak_rss_mb")  # fmt: skip
RESULTS_PARSERS: dict[str, Parser] = {
    column: _INT if column in _INTS else _NUMBER if column in _NUMBERS else _TEXT for column in COLUMNS
} | {"flaky": _BOOL, "original_flaky": _FLAG, "sim_dominated": _FLAG}
TRANSFER_PARSERS: dict[str, Parser] = {column: _TEXT for column in TRANSFER_COLUMNS} | {
    "collision_5s": _OPTIONAL,
    "adversarial_loss": _OPTIONAL,
}
Row = TypeVar("Row", ResultsRow, TransferRow)


def _parsed(cells: Mapping[str, str | None], parsers: Mapping[str, Parser], where: str) -> dict[str, object]:
    row: dict[str, object] = {}
    for column, (parse, expected) in parsers.items():
        cell = cells.get(column)
        if cell is None:
            raise CampaignError(f"{where}: no {column} column")
        try:
            row[column] = parse(cell)
        except (ValueError, KeyError):
            raise CampaignError(f"{where}: {column} is {cell!r}, expected {expected}") from None
    return row


def parse_results_row(cells: Mapping[str, str | None], where: str = "results.csv") -> ResultsRow:
    """A results.csv row (csv.DictReader's cells) as the row it was written from (NaN for ''); CampaignError naming
    the column otherwise."""
    return cast(ResultsRow, _parsed(cells, RESULTS_PARSERS, where))  # every column parsed to its ResultsRow type


def parse_transfer_row(cells: Mapping[str, str | None], where: str = "transfer.csv") -> TransferRow:
    """A transfer.csv row as the row it was written from ('' as None: not scored)."""
    return cast(TransferRow, _parsed(cells, TRANSFER_PARSERS, where))  # every column parsed to its TransferRow type


def _read_csv(text: str, name: str, parse: Callable[[Mapping[str, str | None], str], Row]) -> list[Row]:
    reader = csv.DictReader(io.StringIO(text))
    return [parse(cells, f"{name} line {reader.line_num}") for cells in reader]


def read_results_csv(text: str) -> list[ResultsRow]:
    """The rows of a results.csv (to_csv's text with COLUMNS)."""
    return _read_csv(text, "results.csv", parse_results_row)


def read_transfer_csv(text: str) -> list[TransferRow]:
    """The rows of a transfer.csv (to_csv's text with TRANSFER_COLUMNS)."""
    return _read_csv(text, "transfer.csv", parse_transfer_row)
