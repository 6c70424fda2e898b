"""Whether an attack's (or a replay's) work succeeded: the rule behind its exit code and a campaign row's status.

People put `advsim attack` and `advsim replay` in CI gates, so a run whose queries failed must not
look like a result. An attack failed when
- the original (query 0) was not scored: there is nothing to compare a finding with;
- any query was not scored because a process the attack did not start published on the stack's
  topics (foreign_publisher): the graph was not isolated while it measured;
- more than MAX_FAILED_SHARE of the queries the stack was asked to answer failed (stack_timeout,
  stack_error); infeasible perturbations are the search's own and do not count.
A replay failed when any of its runs was not scored. docs/attack.md, "Exit codes".
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass

from advsim_ros.contract.enums import Status
from advsim_ros.core.attack_summary import VerdictRecord
from advsim_ros.core.journal import QueryRecord

MAX_FAILED_SHARE = 0.5  # of the queries the stack was asked to answer


@dataclass(frozen=True)
class Verdict:
    ok: bool
    reason: str = ""  # one line saying why the work failed ('' when it did not)
    dominant_status: str = ""  # the failure status most queries ended with ('' when none failed)

    def as_json(self) -> VerdictRecord:
        return {"ok": self.ok, "reason": self.reason, "dominant_status": self.dominant_status}


def _status(record: QueryRecord) -> str:
    return str(record.score.get("status", ""))


def _why(records: Sequence[QueryRecord], status: str) -> str:
    """The first message of the queries that ended with ``status``."""
    return next((str(r.score.get("message") or "") for r in records if _status(r) == status), "")


def attack_verdict(records: Sequence[QueryRecord], replay: bool = False) -> Verdict:
    """The verdict on an attack's (``replay``: a replay's) journaled queries."""
    asked = [r for r in records if _status(r) != Status.INFEASIBLE.label]
    failed = [r for r in asked if not r.ok]
    if not asked:
        what = "replay run" if replay else "query"
        return Verdict(False, f"no {what} was answered by the stack" + (" (every one infeasible)" if records else ""))
    counts = Counter(_status(r) for r in failed)
    dominant = counts.most_common(1)[0][0] if counts else ""
    foreign = Status.FOREIGN_PUBLISHER.label
    if counts[foreign]:
        reason = f"{counts[foreign]} of {len(asked)} queries were not scored: {_why(failed, foreign)}"
        return Verdict(False, reason, foreign)
    original = next((r for r in records if r.query_id == 0), None)
    if replay and failed:
        reason = f"{len(failed)} of {len(asked)} replay runs were not scored ({dominant}: {_why(failed, dominant)})"
        return Verdict(False, reason, dominant)
    if not replay and original is not None and not original.ok:
        status = _status(original)
        reason = f"the original scenario (query 0) was not scored ({status}: {original.score.get('message') or ''})"
        return Verdict(False, reason, status)
    if len(failed) > MAX_FAILED_SHARE * len(asked):
        reason = (
            f"{len(failed)} of {len(asked)} queries failed, most of them {dominant} ({_why(failed, dominant)}); "
            f"more than {MAX_FAILED_SHARE:.0%} failed, so the result is not reported as one"
        )
        return Verdict(False, reason, dominant)
    return Verdict(True, "", dominant)
