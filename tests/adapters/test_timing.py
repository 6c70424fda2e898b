"""A timer-driven stack's sweep is answered with the plan in force at its decision time (adapters.timing)."""

from __future__ import annotations

from advsim_ros.adapters.profile import TimingProfile
from advsim_ros.adapters.timing import PlanBook

MS = 1_000_000
S = 10_000 * MS  # the sweep's stamp


def _book() -> PlanBook[str]:
    return PlanBook(TimingProfile(mode="timer", decision_delay=0.1, answer_margin=0.05, max_plan_age=0.5))


def test_the_latest_plan_made_by_the_decision_time_answers_once_the_margin_has_passed() -> None:
    book = _book()
    book.sweep(S)
    book.plan(S - 20 * MS, "old")
    book.plan(S + 80 * MS, "in force")
    book.plan(S + 100 * MS, "made at the decision time")
    assert book.due(S + 140 * MS) == []  # a plan made at the decision time may still be on its way
    book.plan(S + 180 * MS, "too late")
    assert book.due(S + 150 * MS) == [(S, S + 100 * MS, "made at the decision time")]
    assert book.due(S + 500 * MS) == []  # answered once


def test_plans_of_an_earlier_query_are_not_in_force_and_a_late_first_plan_answers() -> None:
    book = _book()
    book.plan(S - 600 * MS, "earlier query")
    book.sweep(S)
    assert book.due(S + 200 * MS) == []  # nothing in force, nothing later yet: wait
    book.plan(S + 230 * MS, "first after")
    assert book.due(S + 240 * MS) == [(S, S + 230 * MS, "first after")]


def test_plans_arriving_out_of_order_are_kept_in_the_order_they_were_made() -> None:
    book = _book()
    book.sweep(S)
    book.plan(S + 90 * MS, "b")
    book.plan(S + 40 * MS, "a")
    assert [made for made, _ in book.made] == [S + 40 * MS, S + 90 * MS]
    assert book.due(S + 150 * MS)[0][2] == "b"
