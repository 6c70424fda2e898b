"""A stack process starts in its profile's folder with its extra environment; the graph's own variables win."""

from __future__ import annotations

from pathlib import Path

from advsim_ros.ros.identity import RUN_MARKER
from advsim_ros.ros.launcher import Launcher, NodeSpec, graph_environment, reserve_domain_id, wait_for

PROBE = 'pwd; echo "MODE=$MODE"; echo "ROS_DOMAIN_ID=$ROS_DOMAIN_ID"; echo "MARKER=$' + RUN_MARKER + '"'


def test_a_process_gets_its_cwd_and_env_but_not_the_graphs_variables(tmp_path: Path) -> None:
    folder = tmp_path / "stack"
    folder.mkdir()
    env = {"MODE": "fast", "ROS_DOMAIN_ID": "0", RUN_MARKER: "forged"}
    with reserve_domain_id() as lease, Launcher(graph_environment(lease.domain_id), tmp_path / "logs", lease) as graph:
        process = graph.start(NodeSpec("probe", ("sh", "-c", PROBE), rename_node=False, cwd=folder, env=env))
        assert wait_for(lambda: process.poll() is not None, 30)
        lines = (tmp_path / "logs" / "probe.log").read_text().splitlines()
        assert lines == [
            f"advsim: env {RUN_MARKER}, ROS_DOMAIN_ID of probe not set: the graph sets them",
            str(folder),
            "MODE=fast",
            f"ROS_DOMAIN_ID={lease.domain_id}",
            f"MARKER={graph.marker}",
        ]
