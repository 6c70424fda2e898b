"""A stack with topic names of its own is attacked without touching its code (`--remap CONTRACT:=YOURS`).

The test stack (processes/own_names_stack.py) reads /points_raw and /localization/odom and answers
on /my_planner/path. Started through a script that passes no arguments on, only the relay can
connect it; started directly, a rename rule can. Both ways it must see exactly what the contract's
topics carry, so both attacks give the same scores query for query.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

PROCESSES = Path(__file__).resolve().parent / "processes"
REMAPS = (
    "--remap", "/sensor/lidar/points:=/points_raw",
    "--remap", "/ego/odom:=/localization/odom",
    "--remap", "/planning/trajectory:=/my_planner/path",
)  # fmt: skip


def _attack(bag: Path, out: Path, stack: str, *extra: str) -> dict[str, Any]:
    command = [
        sys.executable, "-m", "advsim_ros.cli", "attack", str(bag), "--stack", stack, "--algo", "random",
        "--queries", "2", "--reruns", "0", "--param", "perturber.num_candidates=20000", "--connect-timeout", "120",
        "-o", str(out), *REMAPS, *extra,
    ]  # fmt: skip
    environment = {**os.environ, "PYTHON": sys.executable}
    result = subprocess.run(command, capture_output=True, text=True, timeout=900, check=False, env=environment)
    assert result.returncode == 0, result.stderr[-3000:]
    summary: dict[str, Any] = json.loads((out / "summary.json").read_text())
    return summary


def _scores(summary: dict[str, Any]) -> list[tuple[int, str, float, str]]:
    return [
        (q["query_id"], q["score"]["status"], q["score"]["adversarial_loss"], q["score"]["input_digest"])
        for q in summary["queries"]
    ]


@pytest.mark.slow
def test_a_stack_with_its_own_topic_names_is_connected_by_the_relay_or_by_renaming_and_sees_the_same(
    synthetic_bag: Path, tmp_path: Path
) -> None:
    relayed = _attack(synthetic_bag, tmp_path / "relay", f"bash {PROCESSES / 'run_own_names_stack.sh'}")
    assert {q["score"]["status"] for q in relayed["queries"]} == {"ok"}
    assert {q["score"]["plans_received"] for q in relayed["queries"]} == {10}  # every frame answered
    logs = tmp_path / "relay" / "run" / "logs"
    assert "relaying /sensor/lidar/points -> /points_raw" in (logs / "stack_adapter.log").read_text()

    renamed = _attack(
        synthetic_bag,
        tmp_path / "rename",
        f"{sys.executable} {PROCESSES / 'own_names_stack.py'}",
        "--remap-mode",
        "rename",
    )
    assert not (tmp_path / "rename" / "run" / "logs" / "stack_adapter.log").exists()
    assert _scores(renamed) == _scores(relayed)


@pytest.mark.slow
def test_advsim_doctor_says_what_the_stack_uses_and_the_remaps_that_connect_it(
    synthetic_bag: Path, tmp_path: Path
) -> None:
    stack = f"bash {PROCESSES / 'run_own_names_stack.sh'}"
    environment = {**os.environ, "PYTHON": sys.executable}

    def doctor(out: str, *extra: str) -> subprocess.CompletedProcess[str]:
        command = _doctor_command(synthetic_bag, tmp_path, out, "--stack", stack, *extra)
        return subprocess.run(command, capture_output=True, text=True, timeout=600, check=False, env=environment)

    unconnected = doctor("plain", "--connect-timeout", "20")
    assert unconnected.returncode == 1, unconnected.stderr
    table = unconnected.stdout
    assert re.search(r"^/sensor/lidar/points\s+in\s+/sensor/lidar/points\s+-\s+-\s+MISSING$", table, re.MULTILINE)
    assert "stack node /own_names_stack: subscribes ['/localization/odom', '/points_raw']" in table
    for remap in REMAPS[1::2]:
        assert f"--remap {remap}" in table  # every remap it needs, and only from its own topics
    assert "verdict: NOT ready" in table
    # the profile it suggests attaches the stack as it stands: the same script, its topics bridged
    suggested = _doctor_command(synthetic_bag, tmp_path, "suggested", "--stack-profile",
                                str(tmp_path / "plain" / "suggested_profile.yaml"))  # fmt: skip
    profiled = subprocess.run(suggested, capture_output=True, text=True, timeout=600, check=False, env=environment)
    assert profiled.returncode == 0, profiled.stdout + profiled.stderr + _log_tails(tmp_path / "suggested")
    assert "verdict: ready to attack" in profiled.stdout

    connected = doctor("remapped", *REMAPS)
    assert connected.returncode == 0, connected.stdout + connected.stderr + _log_tails(tmp_path / "remapped")
    assert re.search(r"^/planning/trajectory\s+out\s+/my_planner/path\s+nav_msgs/msg/Path\s+reliable, volatile\s+ok$",
                     connected.stdout, re.MULTILINE)  # fmt: skip
    assert "plans: 10 of 10 sweeps answered" in connected.stdout
    assert "Found remap rule" not in connected.stderr  # the advsim command line is not rcl's


def _doctor_command(bag: Path, tmp_path: Path, out: str, *extra: str) -> list[str]:
    return [sys.executable, "-m", "advsim_ros.cli", "doctor", str(bag), "-o", str(tmp_path / out), *extra]


def _log_tails(out: Path, lines: int = 15) -> str:
    """The last lines of every graph log under out (what a failure needs to be understood)."""
    tails = []
    for log in sorted(out.rglob("*.log")):
        text = log.read_text(encoding="utf-8", errors="replace").splitlines()[-lines:]
        tails.append(f"\n--- {log.relative_to(out)}\n" + "\n".join(text))
    return "".join(tails)
