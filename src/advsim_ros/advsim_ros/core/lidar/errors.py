"""The error of input the LiDAR re-simulation cannot work with."""

from __future__ import annotations

from advsim_ros.core.types import ScenarioError


class ResimError(ScenarioError):
    """Input the re-simulation cannot work with; the message names the problem."""
