"""summary.json, the record of one attack (docs/outputs.md), as TypedDicts.

attack.outputs writes it (attack.summary and attack.controls build its parts); campaign/ and viz/ read it back.
It lives in core, not beside its writer, so that viz (a layer below attack) can type what it reads.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import NotRequired, TypeAlias, TypedDict

from advsim_ros.core.fault import FaultRecord

# a QueryScore as JSON (contract.protocol.ScoreRecord.as_dict; its ScoreValue, which core cannot import)
Score: TypeAlias = dict[str, str | int | float | None]


def metric(score: Mapping[str, object] | None, name: str) -> float:
    """A metric of a score as a number: NaN when there is no score or the metric was not computed (null)."""
    value = None if not score else score.get(name)
    if value is None:
        return math.nan
    if not isinstance(value, int | float | str):  # JSON holds nothing else here; a bug, not an input
        raise TypeError(f"score {name}: {value!r} is not a number")
    return float(value)


class ReproductionRecord(TypedDict):
    """Reproduction.as_json: a searched query and its re-runs."""

    query_id: int
    rerun_query_ids: list[int]
    adversarial_losses: list[float | None]  # None: NaN (not scored)
    spread: float | None
    reproduced: bool
    flaky: bool
    inputs_identical: bool
    plans_identical: bool


class QueryEntry(TypedDict):
    """One query of summary.json's "queries" (query_entry)."""

    query_id: int
    algorithm: str
    actor_ids: list[str]
    delta: list[float]
    score: Score
    fault: NotRequired[FaultRecord | None]  # attack.outputs adds it (None: no collision to classify)


class BestQuery(QueryEntry):
    reproduction: ReproductionRecord | None


class IdentityControl(TypedDict):
    query_id: int
    score: Score


class ControlsRecord(TypedDict):
    """attack.controls.controls: the original's re-runs, the identity control, their sim gap."""

    original: ReproductionRecord | None
    original_flaky: bool | None
    identity: IdentityControl | None
    sim_gap: dict[str, float | None] | None  # identity control minus original, per metric (None: not finite)


class FindingRecord(TypedDict):
    """attack.controls.finding: what the recorded query shows and whether it counts as the stack's failure."""

    collision: bool
    original_collides: bool
    gain: float
    control_deviation: float | None
    reproduced: bool | None
    original_flaky: bool | None
    sim_dominated: bool | None
    fault: FaultRecord | None
    counts_as_failure: bool
    excluded: list[str]  # "reason: why" each


class AttackAnalysis(TypedDict):
    """attack_summary: what the journal says; attack.outputs adds the controls, the finding and the rest."""

    original: Score | None
    best: BestQuery | None
    adversarial: Score | None
    recorded_query_id: int | None
    reproductions: list[ReproductionRecord]
    flaky: list[int]
    stack_nondeterministic: bool
    queries: list[QueryEntry]
    failed_queries: int
    controls: NotRequired[ControlsRecord]
    finding: NotRequired[FindingRecord | None]
    # attack.outputs sets these after the rest, where they stand in the file (AttackSummary's, declared here so
    # that the summary can be built from the analysis with **)
    perturbed_actors: NotRequired[list[str]]  # always
    replay: NotRequired[ReplayRecord]  # replays only
    recorded_inputs_reproduced: NotRequired[bool]  # attacks that wrote an adversarial bag


class VerdictRecord(TypedDict):
    """attack.verdict.Verdict.as_json: whether the attack's work succeeded."""

    ok: bool
    reason: str
    dominant_status: str


class ScenarioRecord(TypedDict):
    bag: str
    scenario_id: str
    window_start_frame: int
    history_frames: int
    future_frames: int
    bag_params: dict[str, object] | None  # io.bag.bag_layout_json (None: the contract's layout)


class StackRecord(TypedDict):
    name: str
    command: list[str]


class SearchRecord(TypedDict):
    algorithm: str
    queries: int
    seed: int
    reruns: int
    rerun_top: int
    lanes: int


class StackCrash(TypedDict):
    query_id: int
    exit_code: int


class Resources(TypedDict):
    """What the attack's processes used (empty when the journal was finished before)."""

    processes: dict[str, dict[str, float]]  # per process: peak_rss_mb, cpu_s
    graph_peak_rss_mb: float
    graph_cpu_s: float
    orchestrator_peak_rss_mb: float
    outputs_peak_rss_mb: NotRequired[float]  # the outputs process (attack.outputs_worker), when it wrote them
    outputs_cpu_s: NotRequired[float]


class OutputsRecord(TypedDict, total=False):
    journal: str
    bev: str
    adversarial_bag: str  # attacks that recorded a query
    bev_animation: str  # viz.outputs, unless --no-visuals
    report: str


class ReplayRecord(TypedDict):
    runs: int
    adversarial_losses: list[float | None]


class AttackSummary(AttackAnalysis):
    """summary.json, as attack.outputs writes it."""

    scenario: ScenarioRecord
    stack: StackRecord
    search: SearchRecord
    verdict: NotRequired[VerdictRecord]  # always; summaries of before verdicts have none
    stack_crashes: list[StackCrash]
    wall_time_s: float
    resources: Resources
    ros_domain_id: int | None
    outputs: OutputsRecord
