"""Reactive actors in the attack graph: a car logged close behind the ego brakes behind it instead of driving through.

On the braking-lead scene with a car following the ego 0.3 s behind (conftest's tailgated_bag), a
stack that keeps a long gap to what is ahead (processes/gap_keeping_stack.py, 12 m at a
standstill) brakes hard from the decision on, long before the logged ego did. Without reactive
actors the follower replays its log and runs into the simulated ego from behind: the closed-loop
score has a collision. With ``--reactive-actors`` the follower's progress follows the IDM behind
the ego: lidar_resim renders it where it reacted to, the Episode carries its drive, the scorer
finds no collision and the journal keeps it.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from advsim_ros.core.types import EgoGeometry

PROCESSES = Path(__file__).resolve().parent / "processes"


def _profile(folder: Path) -> Path:
    """The gap-keeping stack, keeping 12 m to what is ahead: it brakes at 8 m/s^2 from the decision on."""
    process = {
        "name": "gap_keeping_stack",
        "command": f"$ADVSIM_PYTHON {PROCESSES / 'gap_keeping_stack.py'}",
        "parameters": {"standstill_gap": 12.0},
    }
    path = folder / "cautious.yaml"
    path.write_text(yaml.safe_dump({"name": "cautious", "processes": [process]}))
    return path


def _replay(bag: Path, out: Path, profile: Path, *extra: str) -> subprocess.CompletedProcess[str]:
    command = [sys.executable, "-m", "advsim_ros.cli", "replay", str(bag), "--stack-profile", str(profile), *extra,
               "-o", str(out)]  # fmt: skip
    return subprocess.run(command, capture_output=True, text=True, timeout=600, check=False, env=dict(os.environ))


def _query(out: Path) -> tuple[dict[str, Any], dict[str, Any]]:
    """The replay's score and its journal line."""
    summary = json.loads((out / "summary.json").read_text())
    line = json.loads((out / "queries.jsonl").read_text().splitlines()[1])
    return summary["queries"][0]["score"], line


@pytest.mark.slow
def test_a_car_logged_behind_the_ego_drives_into_it_unless_it_reacts(tailgated_bag: Path, tmp_path: Path) -> None:
    profile = _profile(tmp_path)
    for name, extra in (("rigid", ()), ("reactive", ("--reactive-actors",))):
        result = _replay(tailgated_bag, tmp_path / name, profile, "--loop", "closed", *extra)
        assert result.returncode == 0, result.stderr[-3000:]
    rigid, rigid_line = _query(tmp_path / "rigid")
    reactive, reactive_line = _query(tmp_path / "reactive")
    assert rigid["loop"] == reactive["loop"] == "closed"
    # the stack looks ahead: the ego drives the same way in both, braking hard from the decision on, until the
    # follower that does not react comes through it (then the stack sees it ahead)
    ego_states = np.array(reactive_line["executed"]["states"])
    np.testing.assert_array_equal(ego_states[:50], np.array(rigid_line["executed"]["states"])[:50])
    assert ego_states[:50, 4].min() < -7.0
    # non-reactive, the car logged behind drives through the ego that braked ...
    assert rigid["collision_5s"] == 1.0
    assert rigid["min_distance"] == 0.0
    assert "reacted" not in rigid_line
    # ... reactive, it brakes behind it: no collision, and the gap stays open
    assert reactive["collision_5s"] == 0.0
    assert reactive["min_distance"] > 1.0
    (follower,) = reactive_line["reacted"]
    assert follower["actor_id"] == "follower"
    assert follower["stamps_ns"] == reactive_line["executed"]["stamps_ns"]  # one state per control step
    ego_rear = ego_states[-1, 0] + EgoGeometry().forward_offset - 0.5 * EgoGeometry().length
    assert follower["centers"][-1][0] + 0.5 * follower["size"][0] < ego_rear - 1.0  # stands behind the ego
    # the stack was shown the follower where it reacted to: the rendered sweeps differ
    assert reactive["input_digest"] != rigid["input_digest"]


def test_reactive_actors_are_refused_in_open_loop(tmp_path: Path) -> None:
    result = _replay(tmp_path / "any_bag", tmp_path / "open", _profile(tmp_path), "--reactive-actors")
    assert result.returncode == 1
    assert result.stderr.strip().splitlines() == [
        "advsim replay: error: --reactive-actors: only with --loop closed (in open loop nothing drives)"
    ]
