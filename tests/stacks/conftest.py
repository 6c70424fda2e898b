"""Fixtures for the reference stacks' tests: real KITTI data beside the repository, a synthetic log."""

from __future__ import annotations

import numpy as np
import pytest

from advsim_ros.io.synthetic import SyntheticConfig, SyntheticLog, generate_synthetic_log


@pytest.fixture(scope="session")
def synthetic_log() -> SyntheticLog:
    """A 7 s synthetic street (70 sweeps): two windows of 1 s history + 5 s future."""
    return generate_synthetic_log(np.random.default_rng(7), SyntheticConfig(duration=7.0), "synthetic_7")
