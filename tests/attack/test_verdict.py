"""An attack whose queries failed is not a result: the verdict behind the exit code (attack.verdict)."""

from __future__ import annotations

from advsim_ros.attack.verdict import MAX_FAILED_SHARE, attack_verdict
from advsim_ros.core.journal import QueryRecord


def _query(query_id: int, status: str = "ok", message: str = "") -> QueryRecord:
    score = {"status": status, "message": message, "adversarial_loss": 1.0 if status == "ok" else None}
    return QueryRecord(query_id, "original" if query_id == 0 else "bo", (), (), score)


def test_an_attack_whose_queries_were_answered_succeeds_even_with_some_failures_and_infeasible_points() -> None:
    records = [_query(0), _query(1), _query(2, "stack_timeout", "late"), _query(3, "infeasible"), _query(4)]
    verdict = attack_verdict(records)
    assert verdict.ok
    assert verdict.reason == ""


def test_an_original_that_was_not_scored_fails_the_attack() -> None:
    verdict = attack_verdict([_query(0, "stack_error", "unusable plan: NaN"), _query(1), _query(2)])
    assert not verdict.ok
    assert verdict.reason == "the original scenario (query 0) was not scored (stack_error: unusable plan: NaN)"


def test_more_than_the_documented_share_of_failed_queries_fails_the_attack_naming_the_dominant_status() -> None:
    failed = int(10 * MAX_FAILED_SHARE) + 1
    records = [_query(0)] + [_query(q, "stack_timeout", "no plan") for q in range(1, failed + 1)]
    records += [_query(q) for q in range(failed + 1, 11)]
    verdict = attack_verdict(records)
    assert not verdict.ok
    assert verdict.dominant_status == "stack_timeout"
    assert verdict.reason.startswith(f"{failed} of 11 queries failed, most of them stack_timeout (no plan)")


def test_one_query_with_a_foreign_publisher_fails_the_attack() -> None:
    records = [_query(0), _query(1, "foreign_publisher", "/planning/trajectory from node 'x'"), _query(2)]
    verdict = attack_verdict(records)
    assert not verdict.ok
    assert verdict.reason == "1 of 3 queries were not scored: /planning/trajectory from node 'x'"


def test_a_replay_fails_when_any_run_was_not_scored_and_when_nothing_was_answered() -> None:
    assert attack_verdict([_query(0), _query(1)], replay=True).ok
    assert not attack_verdict([_query(0), _query(1, "stack_error", "crash")], replay=True).ok
    assert attack_verdict([], replay=True).reason == "no replay run was answered by the stack"
    every_one_infeasible = attack_verdict([_query(1, "infeasible")])
    assert every_one_infeasible.reason == "no query was answered by the stack (every one infeasible)"
