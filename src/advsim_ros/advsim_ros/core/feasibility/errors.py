"""The error every feasibility step raises when no physically plausible perturbation exists."""

from __future__ import annotations

from typing import TYPE_CHECKING

from advsim_ros.core.types import ScenarioError

if TYPE_CHECKING:
    from advsim_ros.core.feasibility.selection import ActorReport


class InfeasibleError(ScenarioError):
    """No physically plausible perturbation exists for what was asked; the message says why."""

    def __init__(self, message: str, reports: tuple[ActorReport, ...] = ()) -> None:
        super().__init__(message)
        self.reports = reports  # per-actor outcome when raised by select_actors
