"""Fixtures for tests that start real ROS 2 processes talking over Fast DDS on loopback."""

from collections.abc import Iterator
from pathlib import Path

import pytest

from advsim_ros.ros.launcher import Launcher, graph_environment, reserve_domain_id


@pytest.fixture
def ros_graph(tmp_path: Path) -> Iterator[Launcher]:
    """A launcher for one isolated graph: its own ROS_DOMAIN_ID, discovery on loopback only."""
    with reserve_domain_id() as domain_id, Launcher(graph_environment(domain_id), tmp_path / "logs") as launcher:
        yield launcher
