"""Only the graph is heard, and a run whose work failed says so: tried for real, from outside the attack.

`advsim attack` runs as a user runs it (a process of its own) on a 6 s KITTI 0000 window with the
test stack (processes/simple_stack.py) while other processes try to interfere: a node on the
attack's ROS domain publishing plans (with the machine's default DDS settings, and with the graph's
own transport profile), a second attack on the same output folder, a daemon the stack starts in a
session of its own; and stacks whose every answer is unusable.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from attack_runs import attack_argv, children, journaled, measured

from advsim_ros.ros.launcher import graph_environment, wait_for

PLAN_INJECTOR = Path(__file__).resolve().parent / "processes" / "plan_injector.py"


def _inet_sockets(pids: list[int]) -> list[tuple[int, str]]:
    """(pid, table and local address) of every IPv4/IPv6 socket the processes hold, from the kernel's tables."""
    tables = {}
    for table in ("udp", "udp6", "tcp", "tcp6", "raw", "raw6"):
        for line in Path(f"/proc/net/{table}").read_text().splitlines()[1:]:
            fields = line.split()
            tables[fields[9]] = f"{table} {fields[1]}"  # inode -> local address
    held = []
    for pid in pids:
        try:
            links = [os.readlink(f"/proc/{pid}/fd/{fd}") for fd in os.listdir(f"/proc/{pid}/fd")]
        except OSError:
            continue
        inodes = [link[len("socket:[") : -1] for link in links if link.startswith("socket:[")]
        held += [(pid, tables[inode]) for inode in inodes if inode in tables]
    return held


def _descendants(pid: int) -> list[int]:
    found, todo = [], [pid]
    while todo:
        below = children(todo.pop())
        found += below
        todo += below
    return found


def _running(argument: str) -> list[int]:
    """Live processes whose command line holds ``argument`` as a word."""
    found = []
    for entry in os.listdir("/proc"):
        try:
            words = Path(f"/proc/{entry}/cmdline").read_bytes().split(b"\0") if entry.isdigit() else []
            state = Path(f"/proc/{entry}/stat").read_text().rsplit(")", 1)[1].split()[0] if words else "Z"
        except OSError:
            continue
        if argument.encode() in words and state != "Z":
            found.append(int(entry))
    return found


def _start_injector(env: dict[str, str]) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, str(PLAN_INJECTOR)], env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
    )


def _stop(process: subprocess.Popen[str] | None) -> str:
    if process is None:
        return ""
    process.send_signal(signal.SIGINT)
    output, _ = process.communicate(timeout=30)
    return output


@pytest.mark.slow
def test_a_running_attack_hears_no_outside_process_opens_no_socket_and_keeps_its_folder_and_daemons_to_itself(
    kitti_window_bag: Path, tmp_path: Path, uninterrupted: tuple[str, dict[str, Any]], advsim: Callable[..., Any]
) -> None:
    stack, reference = uninterrupted
    escape = "8765.4321"  # the sleep the stack starts in a session of its own, found by its argument
    out = tmp_path / "isolated"
    argv = attack_argv(kitti_window_bag, out, f"{stack} -p escape_seconds:={escape}")
    orchestrator = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    graph_file = out / "run" / "graph.json"
    injector = None
    try:
        assert wait_for(lambda: graph_file.exists() or orchestrator.poll() is not None, timeout=600)
        domain = json.loads(graph_file.read_text())["ros_domain_id"]
        # the attack's own domain with the machine's default DDS settings and discovery on loopback, as a user's tool
        env = {**os.environ, "ROS_DOMAIN_ID": str(domain), "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}
        env.pop("FASTRTPS_DEFAULT_PROFILES_FILE", None)
        injector = _start_injector(env)
        second = advsim(*argv[3:], timeout=120)  # the same attack again, on the folder in use
        assert wait_for(lambda: len(journaled(out)) >= 2 or orchestrator.poll() is not None, timeout=600)
        sockets = _inet_sockets([orchestrator.pid, *_descendants(orchestrator.pid)])
        assert orchestrator.poll() is None, "the attack ended before its sockets were read"
        _, errors = orchestrator.communicate(timeout=600)
    finally:
        orchestrator.kill()  # only if the test failed: it has exited otherwise
        injected = _stop(injector)
    assert "plan injector publishing" in injected
    assert orchestrator.returncode == 0, errors
    assert second.returncode == 1
    assert second.stderr.strip().splitlines() == [
        f"advsim attack: error: {out.resolve()} is in use by another advsim run (pid {orchestrator.pid}); wait for "
        "it to end or use another output folder"
    ]
    assert sockets == []  # DDS over shared memory only: nothing of the graph listens on any interface
    assert measured(json.loads((out / "summary.json").read_text())) == measured(reference)
    assert wait_for(lambda: not _running(escape), timeout=10.0), "the stack's daemon outlived the attack"


@pytest.mark.slow
def test_a_process_that_joins_the_graph_and_publishes_plans_changes_no_score_and_fails_the_attack(
    kitti_window_bag: Path, tmp_path: Path, uninterrupted: tuple[str, dict[str, Any]]
) -> None:
    stack, reference = uninterrupted
    out = tmp_path / "injected"
    orchestrator = subprocess.Popen(
        attack_argv(kitti_window_bag, out, stack), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True
    )
    graph_file = out / "run" / "graph.json"
    injector = None
    try:
        assert wait_for(lambda: graph_file.exists() or orchestrator.poll() is not None, timeout=600)
        # the graph's own domain and transport profile: it is discovered, and its plans reach the player
        injector = _start_injector(graph_environment(json.loads(graph_file.read_text())["ros_domain_id"]))
        _, errors = orchestrator.communicate(timeout=600)
    finally:
        orchestrator.kill()
        _stop(injector)
    assert orchestrator.returncode == 1, errors
    error = next(line for line in errors.splitlines() if line.startswith("advsim attack: error:"))
    assert "queries were not scored: /planning/trajectory from node 'plan_injector'" in error
    assert "not a process of this attack" in error
    summary = json.loads((out / "summary.json").read_text())
    assert summary["verdict"]["dominant_status"] == "foreign_publisher"
    statuses = [query["score"]["status"] for query in summary["queries"]]
    assert "foreign_publisher" in statuses
    expected = {tuple(row[2]): row[3:] for row in measured(reference)}  # by the queried point
    scored = [row for row in measured(summary) if row[3] == "ok"]
    assert all(row[3:] == expected[tuple(row[2])] for row in scored)  # no scored query took an injected plan


@pytest.mark.slow
@pytest.mark.parametrize(
    ("parameters", "status"),
    [
        ({"crash_after_plans": 2}, "stack_error"),  # crashes after two plans, each time it is restarted
        ({"plans": "none"}, "stack_timeout"),  # connected, never answers
        ({"plans": "nan_poses"}, "stack_error"),
        ({"plans": "empty"}, "stack_error"),
    ],
)
def test_a_stack_whose_every_answer_fails_fails_the_attack_with_one_line_and_its_log(
    kitti_window_bag: Path,
    tmp_path: Path,
    simple_stack: Callable[..., str],
    parameters: dict[str, Any],
    status: str,
) -> None:
    out = tmp_path / "failing"
    argv = attack_argv(kitti_window_bag, out, simple_stack(**parameters), "--queries", "1", "--reruns", "0")
    result = subprocess.run([*argv, "--plan-timeout", "2"], capture_output=True, text=True, timeout=600, check=False)
    assert result.returncode == 1, result.stdout + result.stderr
    assert "Traceback" not in result.stderr
    error = next(line for line in result.stderr.splitlines() if line.startswith("advsim attack: error:"))
    assert f"the original scenario (query 0) was not scored ({status}" in error
    assert f"the stack's log {out.resolve() / 'run' / 'logs' / 'stack.log'}" in result.stderr  # its tail, or: empty
    summary = json.loads((out / "summary.json").read_text())
    assert {query["score"]["status"] for query in summary["queries"]} <= {status, "stack_error", "stack_timeout"}
    assert "look at:" not in result.stdout  # no report or animation of a scenario that was never found
    listed = result.stdout.strip().splitlines()[-1].removeprefix("outputs: ").split()
    assert listed
    assert all(Path(path).exists() for path in listed)


@pytest.mark.slow
@pytest.mark.parametrize(
    ("plans", "problem"),
    [("nan_poses", "NaN or infinite poses"), ("frame", "the plan is in frame 'stack_frame'")],
)
def test_doctor_says_not_ready_when_the_plans_cannot_be_scored(
    kitti_window_bag: Path, tmp_path: Path, simple_stack: Callable[..., str], advsim: Callable[..., Any], plans: str,
    problem: str,
) -> None:  # fmt: skip
    result = advsim("doctor", str(kitti_window_bag), "--stack", simple_stack(plans=plans), "-o", str(tmp_path / "d"))
    assert result.returncode == 1, result.stdout + result.stderr
    assert "plans: 10 of 10 sweeps answered" in result.stdout  # it answers every sweep ...
    assert problem in result.stdout  # ... with a plan the scorer cannot use
    assert result.stdout.strip().splitlines()[-1].startswith("verdict: NOT ready")
