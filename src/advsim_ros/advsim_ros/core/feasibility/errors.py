"""The error every feasibility step raises when no physically plausible perturbation exists."""

from __future__ import annotations

from advsim_ros.core.types import ScenarioError


class InfeasibleError(ScenarioError):
    """No physically plausible perturbation exists for what was asked; the message says why.

    select_actors raises its subclass TooFewActorsError (core.feasibility.selection), which also
    carries the report on every actor."""
