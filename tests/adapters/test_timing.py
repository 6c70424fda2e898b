"""A timer-driven stack's sweep is answered with the plan in force at its decision time (adapters.timing)."""

from __future__ import annotations

from advsim_ros.adapters.profile import TimingProfile
from advsim_ros.adapters.timing import FrameRelay, PlanBook

MS = 1_000_000
S = 10_000 * MS  # the sweep's stamp


def _book(answer_margin: float = 0.05) -> PlanBook[str]:
    return PlanBook(TimingProfile(mode="timer", decision_delay=0.1, answer_margin=answer_margin, max_plan_age=0.5))


def test_the_plan_made_at_the_decision_time_answers_as_soon_as_it_arrived_however_late() -> None:
    book = _book(answer_margin=0.5)
    book.sweep(S)
    book.plan(S - 20 * MS, "old")
    book.plan(S + 80 * MS, "in force")
    assert book.due(S + 140 * MS) == []  # a plan made at the decision time may still be on its way
    assert book.due(S + 300 * MS) == []  # a stack computing slowly: still waited for (the answer never races it)
    book.plan(S + 100 * MS, "made at the decision time")
    book.plan(S + 200 * MS, "too late")
    assert book.due(S + 300 * MS) == [(S, S + 100 * MS, "made at the decision time")]
    assert book.due(S + 900 * MS) == []  # answered once


def test_a_plan_made_after_the_decision_time_settles_which_one_was_in_force() -> None:
    book = _book()
    book.sweep(S)
    book.plan(S + 80 * MS, "in force")
    book.plan(S + 130 * MS, "after")  # a timer off the sweeps' grid: nothing made at D itself
    assert book.due(S + 130 * MS) == [(S, S + 80 * MS, "in force")]


def test_a_stack_that_plans_no_more_is_answered_with_the_plan_in_force_once_the_margin_passed() -> None:
    book = _book()
    book.sweep(S)
    book.plan(S + 80 * MS, "last plan")
    assert book.due(S + 140 * MS) == []
    assert book.due(S + 150 * MS) == [(S, S + 80 * MS, "last plan")]  # decision 100 ms + margin 50 ms


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


def test_a_frame_is_passed_on_once_its_pose_and_its_relayed_sweep_went_to_the_stack() -> None:
    relay = FrameRelay(relays_sweeps=True)
    assert not relay.passed_on(S, "sweep")
    assert relay.passed_on(S, "pose")
    assert not relay.passed_on(S + 100 * MS, "pose")  # its sweep never came (the player's wait timed out)
    assert not relay.passed_on(S + 200 * MS, "pose")
    assert relay.passed_on(S + 200 * MS, "sweep")
    assert relay.passed == {}  # the incomplete earlier frame is forgotten with it
    assert FrameRelay(relays_sweeps=False).passed_on(S, "pose")  # the stack reads the player's LiDAR itself
