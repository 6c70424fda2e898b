"""Stacks written without the contract in mind are attacked through a stack profile, their code unchanged.

The test stacks (processes/foreign_stack.py) plan on a 10 Hz timer of their own on the sim clock:
one localises from NavSatFix and answers a spatial nav_msgs/Path in a `map` frame anchored at its
first fix, the other speaks Autoware's topics and types (kinematic state in, Trajectory out). The
graph's stack_adapter bridges them and the player steps /clock; repeated queries must give the
same score, and `advsim doctor` must say what connects them.
"""

from __future__ import annotations

import collections
import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
import yaml

PROCESSES = Path(__file__).resolve().parent / "processes"
PROFILES = Path(__file__).resolve().parents[3] / "params" / "stacks"
FOREIGN_STACK = PROCESSES / "foreign_stack.py"


def _gnss_profile(folder: Path, *arguments: str) -> Path:
    command = " ".join(["$ADVSIM_PYTHON", str(FOREIGN_STACK), "gnss", *arguments])
    profile = {
        "profile": 1,
        "name": "gnss_planner",
        "processes": [{"name": "gnss_planner", "command": command}],
        "timing": {"mode": "timer", "clock_step": 0.01, "decision_delay": 0.1},
        "inputs": {
            "lidar": {"topic": "/points_raw"},
            "pose": {"type": "navsatfix", "topic": "/fix", "datum": {"latitude": 49.0, "longitude": 8.4}},
        },
        "outputs": {
            "plan": {
                "type": "spatial_path",
                "topic": "/gnss_planner/path",
                "frame_id": "map",
                "frame_origin": "first_fix",
                "reliability": "best_effort",
            }
        },
    }
    path = folder / "gnss.yaml"
    path.write_text(yaml.safe_dump(profile))
    return path


def _autoware_profile(folder: Path) -> Path:
    """The shipped Autoware profile with the test stack as its process."""
    profile = yaml.safe_load((PROFILES / "autoware.yaml").read_text())
    profile["processes"] = [{"name": "autoware", "command": f"$ADVSIM_PYTHON {FOREIGN_STACK} autoware"}]
    profile["inputs"]["lidar"]["also"] = ["/sensing/lidar/top/pointcloud"]  # per-sensor beside concatenated
    path = folder / "autoware.yaml"
    path.write_text(yaml.safe_dump(profile))
    return path


def _advsim(*arguments: str, timeout: float = 900) -> subprocess.CompletedProcess[str]:
    command = [sys.executable, "-m", "advsim_ros.cli", *arguments]
    return subprocess.run(command, capture_output=True, text=True, timeout=timeout, check=False, env=dict(os.environ))


def _attack(bag: Path, out: Path, profile: Path) -> dict[str, Any]:
    result = _advsim(
        "attack", str(bag), "--stack-profile", str(profile), "--algo", "random", "--queries", "2", "--reruns", "1",
        "--param", "perturber.num_candidates=20000", "-o", str(out),
    )  # fmt: skip
    assert result.returncode == 0, result.stderr[-3000:]
    summary: dict[str, Any] = json.loads((out / "summary.json").read_text())
    return summary


def _repeat_share(bag: Path, out: Path, profile: Path, runs: int) -> float:
    """The share of `advsim replay --runs N` whose score is the most common one."""
    result = _advsim("replay", str(bag), "--stack-profile", str(profile), "--runs", str(runs), "-o", str(out))
    assert result.returncode == 0, result.stderr[-3000:]
    losses = json.loads((out / "summary.json").read_text())["replay"]["adversarial_losses"]
    assert len(losses) == runs
    assert None not in losses
    return collections.Counter(losses).most_common(1)[0][1] / runs


@pytest.mark.slow
def test_a_gnss_localised_timer_driven_stack_with_a_spatial_path_is_attacked_through_a_profile(
    synthetic_bag: Path, tmp_path: Path
) -> None:
    profile = _gnss_profile(tmp_path)
    summary = _attack(synthetic_bag, tmp_path / "attack", profile)
    scores = [query["score"] for query in summary["queries"]]
    assert {score["status"] for score in scores} == {"ok"}
    assert all(score["sweeps_delivered"] == 10 for score in scores)
    # the plan came back in the stack's map frame, anchored where the ego was: close to the human's path
    assert all(score["l2_human_3s"] < 2.0 for score in scores)
    log = (tmp_path / "attack" / "run" / "logs" / "stack_adapter.log").read_text()
    assert "pose: /ego/odom -> /fix (sensor_msgs/msg/NavSatFix)" in log
    assert "/planning/trajectory <- /gnss_planner/path (nav_msgs/msg/Path, timer" in log
    assert not summary["flaky"]
    share = _repeat_share(tmp_path / "attack" / "adversarial", tmp_path / "replay", profile, runs=10)
    assert share >= 0.9, f"the same query gave the same score in {share:.0%} of repeats"


@pytest.mark.slow
def test_a_timer_driven_gnss_stack_with_heading_less_spatial_paths_reproduces_its_original_in_every_cold_graph(
    synthetic_bag: Path, tmp_path: Path
) -> None:
    """Ten graphs started from nothing, the clock stepped at real time: query 0 scores the same each time."""
    profile = _gnss_profile(tmp_path, "headingless")
    losses = []
    for run in range(10):
        result = _advsim("replay", str(synthetic_bag), "--stack-profile", str(profile), "-o", str(tmp_path / f"{run}"))
        assert result.returncode == 0, result.stderr[-3000:]
        (score,) = [q["score"] for q in json.loads((tmp_path / f"{run}" / "summary.json").read_text())["queries"]]
        assert score["status"] == "ok"
        losses.append(score["adversarial_loss"])
    assert len(set(losses)) == 1, losses


@pytest.mark.slow
def test_a_stack_speaking_autoware_topics_and_types_is_attacked_through_the_shipped_profile(
    lead_brake_bag: Path, tmp_path: Path
) -> None:
    summary = _attack(lead_brake_bag, tmp_path / "attack", _autoware_profile(tmp_path))
    scores = [query["score"] for query in summary["queries"]]
    assert {score["status"] for score in scores} == {"ok"}
    # blocked by the braking lead, its trajectory ends with speed 0 a few metres ahead: it stops there
    assert all(score["collision_5s"] == 0.0 for score in scores)
    log = (tmp_path / "attack" / "run" / "logs" / "stack_adapter.log").read_text()
    assert "/planning/trajectory <- /planning/scenario_planning/trajectory (autoware_planning_msgs" in log
    lidar = "LiDAR: /sensor/lidar/points -> /sensing/lidar/concatenated/pointcloud, /sensing/lidar/top/pointcloud"
    assert lidar in log
    assert "/perception/detections <- /perception/object_recognition/detection/objects" in log
    stack_log = (tmp_path / "attack" / "run" / "logs" / "autoware.log").read_text()
    assert "per-sensor sweep received" in stack_log
    # Autoware objects reach the scorer as the contract's detections and predictions
    assert all(score["detection_ap"] is not None for score in scores)
    assert all(score["prediction_l2_3s"] is not None for score in scores)
    reproduction = summary["reproductions"][0]
    assert reproduction["reproduced"]


@pytest.mark.slow
def test_advsim_doctor_proposes_a_profile_for_a_foreign_stack_and_passes_it_with_one(
    synthetic_bag: Path, tmp_path: Path
) -> None:
    bare = _advsim(
        "doctor", str(synthetic_bag), "--stack", f"{sys.executable} {FOREIGN_STACK} gnss", "-o", str(tmp_path / "bare"),
        "--connect-timeout", "20", timeout=600,
    )  # fmt: skip
    assert bare.returncode == 1, bare.stderr[-2000:]
    assert "verdict: NOT ready" in bare.stdout
    suggested = yaml.safe_load((tmp_path / "bare" / "suggested_profile.yaml").read_text())
    assert suggested["inputs"]["lidar"] == {"topic": "/points_raw"}
    assert suggested["inputs"]["pose"]["type"] == "navsatfix"
    assert suggested["outputs"]["plan"]["topic"] == "/gnss_planner/path"
    assert suggested["outputs"]["plan"]["reliability"] == "best_effort"
    assert suggested["inputs"]["pose"]["datum"] == {"latitude": 0.0, "longitude": 0.0, "altitude": 0.0}  # yours here

    profiled = _advsim(
        "doctor", str(synthetic_bag), "--stack-profile", str(_gnss_profile(tmp_path)), "-o", str(tmp_path / "ok"),
        timeout=600,
    )  # fmt: skip
    stack_logs = "\n".join(f"{log.name}: {log.read_text()[-1500:]}" for log in (tmp_path / "ok").glob("run/logs/*.log"))
    assert profiled.returncode == 0, profiled.stdout[-3000:] + "\n" + stack_logs
    assert "verdict: ready to attack" in profiled.stdout
    rows = {line.split()[0]: line for line in profiled.stdout.splitlines() if line.startswith("/")}
    assert rows["/ego/odom"].split()[-1] == "ok"
    assert rows["/planning/trajectory"].split()[-1] == "ok"
    # what it suggests from a working profile keeps what no graph shows (the datum, the plan's frame): it works too
    again = _advsim("doctor", str(synthetic_bag), "--stack-profile", str(tmp_path / "ok" / "suggested_profile.yaml"),
                    "-o", str(tmp_path / "again"), timeout=600)  # fmt: skip
    assert again.returncode == 0, again.stdout[-3000:]
    assert "verdict: ready to attack" in again.stdout


def test_a_misconfigured_profile_is_one_line_and_starts_nothing(synthetic_bag: Path, tmp_path: Path) -> None:
    cases = {
        "unknown type": "processes: [{command: x}]\noutputs: {plan: {type: autoware_path}}\n",
        "missing frame": "processes: [{command: x}]\noutputs: {plan: {frame_origin: static}}\n",
        "missing datum": "processes: [{command: x}]\ninputs: {pose: {type: navsatfix, topic: /fix}}\n",
        "wrong QoS": "processes: [{command: x}]\noutputs: {plan: {topic: /p, reliability: keep_all}}\n",
    }
    for case, text in cases.items():
        profile = tmp_path / f"{case.replace(' ', '_')}.yaml"
        profile.write_text(text)
        out = tmp_path / case.replace(" ", "_")
        result = _advsim("attack", str(synthetic_bag), "--stack-profile", str(profile), "-o", str(out), timeout=120)
        assert result.returncode == 1, case
        lines = result.stderr.strip().splitlines()
        assert len(lines) == 1, (case, result.stderr)
        assert str(profile) in lines[0], case
        assert not out.exists(), case
    both = _advsim(
        "attack", str(synthetic_bag), "--stack", "x", "--stack-profile", str(profile), "-o", str(tmp_path / "b"),
        timeout=120,
    )  # fmt: skip
    assert both.returncode == 1
    assert "leave out --stack and --remap" in both.stderr
