"""Enumerations of the attack protocol; values equal the constants of the advsim_msgs .msg files."""

from __future__ import annotations

from enum import IntEnum


class Phase(IntEnum):
    """advsim_msgs/Episode PHASE_*."""

    START = 0
    REPLAY = 1
    DECISION = 2
    DONE = 3


class Outcome(IntEnum):
    """advsim_msgs/Episode OUTCOME_*: how a query's replay ended."""

    COMPLETE = 0
    PLANS_MISSING = 1
    STACK_LOST = 2
    FOREIGN_PUBLISHER = 3


class Status(IntEnum):
    """advsim_msgs/QueryScore STATUS_*."""

    OK = 0
    STACK_TIMEOUT = 1
    STACK_ERROR = 2
    INFEASIBLE = 3
    FOREIGN_PUBLISHER = 4

    @property
    def label(self) -> str:
        """The name summaries and journals use: ok, stack_timeout, stack_error, infeasible, foreign_publisher."""
        return self.name.lower()
