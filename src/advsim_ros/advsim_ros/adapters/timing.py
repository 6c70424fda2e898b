"""Which plan of a timer-driven stack answers which sweep (pure; used by the stack_adapter node).

A stack planning on its own timer answers no sweep in particular. The sweep stamped S is answered
with the plan in force at its decision time D = S + decision_delay: the latest plan made at or
before D and no older than max_plan_age (older ones belong to an earlier query), chosen once a
plan made at or after D has arrived: one publisher's plans arrive in the order they were made, so
the choice never depends on how long the stack computed. A stack that plans no more is answered
when the sim clock is answer_margin past D. When none is in force, the first plan made after D
answers (the stack had not planned yet).
"""

from __future__ import annotations

import bisect
from dataclasses import dataclass, field
from typing import Generic, TypeVar

from advsim_ros.adapters.profile import TimingProfile
from advsim_ros.core.metrics import NS_PER_S

PlanT = TypeVar("PlanT")
KEPT_PLANS = 200  # the stack's recent plans remembered


@dataclass
class PlanBook(Generic[PlanT]):
    """The stack's recent plans by the time they were made, and the sweeps still to answer."""

    timing: TimingProfile
    made: list[tuple[int, PlanT]] = field(default_factory=list)  # (made [ns, sim clock], plan), in time order
    pending: list[int] = field(default_factory=list)  # sweep stamps not answered yet
    answered: set[int] = field(default_factory=set)

    def sweep(self, stamp_ns: int) -> None:
        """A sweep (frame) the stack was sent."""
        if stamp_ns not in self.answered and stamp_ns not in self.pending:
            self.pending.append(stamp_ns)

    def plan(self, made_ns: int, plan: PlanT) -> None:
        """A plan the stack made at made_ns (sim clock)."""
        index = bisect.bisect_right([made for made, _ in self.made], made_ns)
        self.made.insert(index, (made_ns, plan))
        del self.made[: max(0, len(self.made) - KEPT_PLANS)]

    def due(self, clock_ns: int) -> list[tuple[int, int, PlanT]]:
        """(sweep stamp, made, plan) for every pending sweep the clock has reached the answer time of."""
        delay = round(self.timing.decision_delay * NS_PER_S)
        oldest = round(self.timing.max_plan_age * NS_PER_S)
        margin = round(self.timing.answer_margin * NS_PER_S)
        answers = []
        for sweep in list(self.pending):
            decision = sweep + delay
            settled = bool(self.made) and self.made[-1][0] >= decision
            if not settled and clock_ns < decision + margin:
                continue
            in_force = [item for item in self.made if decision - oldest <= item[0] <= decision]
            later = [item for item in self.made if item[0] > decision]
            chosen = in_force[-1] if in_force else (later[0] if later else None)
            if chosen is None:
                continue  # not planned yet: the first plan made after the decision time will answer
            self.pending.remove(sweep)
            self.answered.add(sweep)
            answers.append((sweep, chosen[0], chosen[1]))
        return answers


@dataclass
class FrameRelay:
    """Which frames' inputs a timer-driven stack has been passed in full (the player moves /clock to a
    frame only then): its pose, and its sweep when the adapter relays the LiDAR."""

    relays_sweeps: bool = False
    passed: dict[int, set[str]] = field(default_factory=dict)  # frame stamp -> kinds passed on so far

    def passed_on(self, stamp_ns: int, kind: str) -> bool:
        """Record that the frame's pose or sweep went to the stack; True once the frame is complete."""
        kinds = self.passed.setdefault(stamp_ns, set())
        kinds.add(kind)
        if kinds < ({"pose", "sweep"} if self.relays_sweeps else {"pose"}):
            return False
        for stamp in [stamp for stamp in self.passed if stamp <= stamp_ns]:
            del self.passed[stamp]  # earlier ones lack a sweep the player never sent (its wait timed out)
        return True
