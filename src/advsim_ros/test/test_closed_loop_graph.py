"""Closed loop in the attack graph: the ego drives the stack's plans and every sweep is rendered where it is.

On the braking-lead scene a stack that keeps a gap to what it sees ahead (processes/
gap_keeping_stack.py) plans, before the lead brakes, to keep its speed: open loop (the paper's
score) that plan runs into the lead. Closed loop, replanning every 0.1 s from sweeps rendered at
the ego's actual pose, it brakes when the gap closes and stops short of the lead; both figures are
in the same score. The executed trajectory keeps to the controller's limits, and the same query
drives the same way twice.
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

from advsim_ros.core.closed_loop import ControllerConfig

PROCESSES = Path(__file__).resolve().parent / "processes"


def _gap_keeping_profile(folder: Path) -> Path:
    profile = {
        "name": "gap_keeping",
        "processes": [{"name": "gap_keeping_stack", "command": f"$ADVSIM_PYTHON {PROCESSES / 'gap_keeping_stack.py'}"}],
    }
    path = folder / "gap_keeping.yaml"
    path.write_text(yaml.safe_dump(profile))
    return path


def _replay(bag: Path, out: Path, profile: Path, loop: str, runs: int) -> dict[str, Any]:
    command = [
        sys.executable, "-m", "advsim_ros.cli", "replay", str(bag), "--stack-profile", str(profile),
        "--loop", loop, "--runs", str(runs), "-o", str(out),
    ]  # fmt: skip
    result = subprocess.run(command, capture_output=True, text=True, timeout=900, check=False, env=dict(os.environ))
    assert result.returncode == 0, result.stderr[-3000:]
    summary: dict[str, Any] = json.loads((out / "summary.json").read_text())
    return summary


@pytest.mark.slow
def test_the_ego_drives_the_stacks_plans_and_what_it_drove_is_scored_beside_the_decision_plan(
    lead_brake_bag: Path, tmp_path: Path
) -> None:
    profile = _gap_keeping_profile(tmp_path)
    opened = _replay(lead_brake_bag, tmp_path / "open", profile, "open", 1)
    closed = _replay(lead_brake_bag, tmp_path / "closed", profile, "closed", 2)
    open_score = opened["queries"][0]["score"]
    first, second = (query["score"] for query in closed["queries"])
    assert open_score["loop"] == "open"
    assert first["loop"] == "closed"
    # the decision plan is the same either way, and open loop it runs into the braking lead ...
    assert first["open_loop_collision_5s"] == open_score["collision_5s"] == 1.0
    assert first["open_loop_adversarial_loss"] == pytest.approx(open_score["adversarial_loss"])
    # ... while the ego that replans brakes in time and stops short of it
    assert first["collision_5s"] == 0.0
    assert first["min_distance"] > 1.0
    # closed loop the stack saw 10 history sweeps and then one per 0.1 s for 5 s, and answered each
    assert first["sweeps_delivered"] == first["plans_received"] == 10 + 49
    assert first["progress"] > 0.0
    # same query, same drive
    assert second["adversarial_loss"] == first["adversarial_loss"]
    assert second["input_digest"] == first["input_digest"]
    journal = [json.loads(line) for line in (tmp_path / "closed" / "queries.jsonl").read_text().splitlines()[1:]]
    executed = np.array(journal[0]["executed"]["states"])
    assert np.array_equal(executed, np.array(journal[1]["executed"]["states"]))
    limits = ControllerConfig()
    assert np.abs(np.diff(executed[:, 4])).max() <= limits.max_jerk * limits.control_period + 1e-9
    assert np.abs(executed[:, 5]).max() <= limits.max_steer + 1e-9
    assert executed[:, 4].min() >= -limits.max_decel - 1e-9
    assert executed[:, 4].max() <= limits.max_accel + 1e-9
