"""What an attack found, from its journal: the original, the best, whether the best reproduces.

Re-runs of a query are recognised by their delta (the same point as a searched query). A query
reproduces when every evaluation of it (the search's and the re-runs) succeeded with the same
L_adv and the same collision outcome; then whether the stack's inputs and plans were identical
too tells a non-deterministic stack (same inputs, different plans) from a framework fault
(different inputs). A best query that does not reproduce is reported as flaky, not as the result.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from advsim_ros.core.attack_summary import AttackAnalysis, BestQuery, QueryEntry, ReproductionRecord
from advsim_ros.core.journal import QueryRecord, ranked_queries
from advsim_ros.core.search.driver import NOT_SEARCHED, RERUN

REPRODUCE_TOLERANCE = 1e-9  # relative |L_adv| difference still counted as the same value


@dataclass(frozen=True)
class Reproduction:
    """A searched query and its re-runs."""

    query_id: int
    evaluations: tuple[QueryRecord, ...]  # the searched evaluation first, then each re-run

    @property
    def values(self) -> list[float]:
        return [record.value for record in self.evaluations]

    @property
    def reproduced(self) -> bool:
        values = self.values
        if not all(math.isfinite(v) for v in values):
            return False
        reference = values[0]
        same_value = all(abs(v - reference) <= REPRODUCE_TOLERANCE * max(1.0, abs(reference)) for v in values)
        collisions = {record.score.get("collision_5s") for record in self.evaluations}
        return same_value and len(collisions) == 1

    def as_json(self) -> ReproductionRecord:
        values = self.values
        finite = [v for v in values if math.isfinite(v)]
        digests = {key: len({r.score.get(f"{key}_digest") for r in self.evaluations}) == 1 for key in ("input", "plan")}
        return {
            "query_id": self.query_id,
            "rerun_query_ids": [record.query_id for record in self.evaluations[1:]],
            "adversarial_losses": [None if math.isnan(v) else v for v in values],
            "spread": (max(finite) - min(finite)) if finite else None,
            "reproduced": self.reproduced,
            "flaky": not self.reproduced,
            "inputs_identical": digests["input"],
            "plans_identical": digests["plan"],
        }


def reproductions(records: Sequence[QueryRecord]) -> list[Reproduction]:
    """Every searched query that was re-run, with its re-runs, best first."""
    searched = [r for r in records if r.algorithm not in NOT_SEARCHED]
    reruns = [r for r in records if r.algorithm == RERUN]
    found = []
    for query_id in ranked_queries({r.query_id: r.value for r in searched}, len(searched)):
        source = next(r for r in searched if r.query_id == query_id)
        again = tuple(r for r in reruns if r.delta == source.delta and r.actor_ids == source.actor_ids)
        if again:
            found.append(Reproduction(query_id, (source, *again)))
    return found


def query_entry(record: QueryRecord) -> QueryEntry:
    return {
        "query_id": record.query_id,
        "algorithm": record.algorithm,
        "actor_ids": list(record.actor_ids),
        "delta": list(record.delta),
        "score": dict(record.score),
    }


def attack_summary(records: Sequence[QueryRecord]) -> AttackAnalysis:
    """The analysis part of summary.json (see docs/outputs.md)."""
    by_id = {record.query_id: record for record in records}
    searched = [r for r in records if r.algorithm not in NOT_SEARCHED]
    checked = reproductions(records)
    reproducible = [item for item in checked if item.reproduced]
    best_record = by_id[reproducible[0].query_id] if reproducible else None
    if not checked:  # no re-runs asked for: the best value stands unverified
        ranked = ranked_queries({r.query_id: r.value for r in searched}, 1)
        best_record = by_id[ranked[0]] if ranked else None
    final = recorded_query(records)
    best: BestQuery | None = None
    if best_record is not None:
        item = next((c for c in checked if c.query_id == best_record.query_id), None)
        best = {**query_entry(best_record), "reproduction": item.as_json() if item is not None else None}
    return {
        "original": dict(by_id[0].score) if 0 in by_id else None,
        "best": best,
        "adversarial": dict(final.score) if final is not None else None,
        "recorded_query_id": final.query_id if final is not None else None,
        "reproductions": [item.as_json() for item in checked],
        "flaky": [item.query_id for item in checked if not item.reproduced],
        # the same bytes in, different plans out: the stack itself is not deterministic
        "stack_nondeterministic": any(
            item.as_json()["inputs_identical"] and not item.as_json()["plans_identical"] for item in checked
        ),
        "queries": [query_entry(record) for record in records],
        "failed_queries": sum(1 for r in searched if not r.ok),
    }


def recorded_query(records: Sequence[QueryRecord]) -> QueryRecord | None:
    """The query the adversarial bag records: the last re-run of the best (the best searched query without re-runs)."""
    checked = reproductions(records)
    if checked:
        return checked[0].evaluations[-1]
    searched = [r for r in records if r.algorithm not in NOT_SEARCHED]
    ranked = ranked_queries({r.query_id: r.value for r in searched}, 1)
    return next((r for r in searched if ranked and r.query_id == ranked[0]), None)


# rows of the original-vs-adversarial table printed after an attack: (QueryScore field, label, format)
COMPARISON_ROWS = (
    ("collision_3s", "collision up to 3 s", "{:.0f}"),
    ("collision_5s", "collision up to 5 s", "{:.0f}"),
    ("l2_human_3s", "L2 to human at 3 s [m]", "{:.2f}"),
    ("l2_human_5s", "L2 to human at 5 s [m]", "{:.2f}"),
    ("lateral_acceleration", "lateral acceleration [m/s^2]", "{:.2f}"),
    ("jerk", "jerk [m/s^3]", "{:.2f}"),
    ("adversarial_loss", "L_adv (higher: worse for the stack)", "{:.2f}"),
)
# Closed loop: the rows above are of what the ego drove; these say how it went and what open loop says
CLOSED_LOOP_ROWS = (
    ("min_distance", "closest gap to an actor [m]", "{:.2f}"),
    ("min_time_to_collision", "smallest time to collision [s]", "{:.2f}"),
    ("progress", "distance driven [m]", "{:.1f}"),
    ("open_loop_collision_5s", "open loop: decision plan collides (5 s)", "{:.0f}"),
    ("open_loop_adversarial_loss", "open loop: L_adv of the decision plan", "{:.2f}"),
)


def comparison_table(summary: AttackAnalysis) -> str:
    """The original and the adversarial scenario's scores side by side, as aligned text lines."""
    columns = (summary.get("original") or {}, summary.get("adversarial") or {})
    closed = any(column.get("loop") == "closed" for column in columns)
    rows = COMPARISON_ROWS + CLOSED_LOOP_ROWS if closed else COMPARISON_ROWS
    width = max(len(label) for _, label, _ in rows)
    title = "closed loop: what the ego drove" if closed else ""
    lines = [f"{title:{width}}  {'original':>10}  {'adversarial':>11}"]
    for key, label, form in rows:
        cells = [form.format(c[key]) if isinstance(c.get(key), (int, float)) else "-" for c in columns]
        lines.append(f"{label:{width}}  {cells[0]:>10}  {cells[1]:>11}")
    return "\n".join(lines)
