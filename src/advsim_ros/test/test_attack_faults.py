"""Faults, for real: kill -9 of `advsim attack`, a suspended one (SIGSTOP), a full disk, a stray graph on the same
stack, a stack that never connects, SIGINT and SIGTERM, and bad input that must start nothing.

Every test runs `advsim attack` as a user would (a process of its own) on a 6 s KITTI 0000 window
with the test stack (the example stack, processes/simple_stack.py), and kills, interrupts or
disturbs it while it runs.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from attack_runs import ALL_QUERIES, QUERIES, alive, attack_argv, children, journaled, measured, started

from advsim_ros.ros.launcher import graph_environment, wait_for

INTRUDER = Path(__file__).resolve().parent / "processes" / "intruder.py"


def _timeless(entry: dict[str, Any]) -> dict[str, Any]:
    """A summary entry without its wall-clock times (the only thing a resumed run may change)."""
    score = {key: value for key, value in entry["score"].items() if key != "wall_time"}
    return {**entry, "score": score}


def _kill_9_at(argv: list[str], point: Callable[[], bool], out: Path, zombie_shm_segments: Callable[[], int]) -> None:
    """Run the attack, kill -9 it when ``point()`` holds, check that nothing of its graph is left within 5 s."""
    player_log = out / "run" / "logs" / "graph_nodes.log"
    zombie_shm_segments()  # what earlier tests left
    journaled_before = set(journaled(out))
    offset = player_log.stat().st_size if player_log.exists() else 0
    orchestrator = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        assert wait_for(lambda: point() or orchestrator.poll() is not None, timeout=600)
        # run/graph.json is written just before the first process starts: on a busy machine, wait for one
        assert wait_for(lambda: bool(children(orchestrator.pid)) or orchestrator.poll() is not None, timeout=60)
        assert orchestrator.poll() is None, "the attack ended before the kill point"
        graph = children(orchestrator.pid)
        assert graph, "no process of the graph found"
    finally:
        orchestrator.send_signal(signal.SIGKILL)
        orchestrator.wait()
    assert wait_for(lambda: not any(alive(pid) for pid in graph), timeout=5.0), [p for p in graph if alive(p)]
    assert zombie_shm_segments() == 0  # nor its shared memory (32 MiB a process under /dev/shm)
    # a query the journal held before this run was never replayed again
    assert started(player_log, offset).isdisjoint(journaled_before)
    ids = journaled(out)
    assert len(ids) == len(set(ids))


@pytest.mark.slow
def test_kill_9_of_advsim_attack_leaves_no_process_behind_and_the_same_command_resumes_without_recomputing(
    kitti_window_bag: Path,
    tmp_path: Path,
    uninterrupted: tuple[str, dict[str, Any]],
    zombie_shm_segments: Callable[[], int],
) -> None:
    stack, reference = uninterrupted
    out = tmp_path / "killed"
    argv = attack_argv(kitti_window_bag, out, stack)
    player_log = out / "run" / "logs" / "graph_nodes.log"
    kill_points: list[Callable[[], bool]] = [
        lambda: (out / "run" / "graph.json").exists(),  # while the graph starts
        lambda: len(journaled(out)) >= 3,  # in the middle of the search
        lambda: len(journaled(out)) >= QUERIES + 2,  # during the re-runs of the best
    ]
    for point in kill_points:
        _kill_9_at(argv, point, out, zombie_shm_segments)
    journaled_before = set(journaled(out))
    offset = player_log.stat().st_size
    final = subprocess.run(argv, capture_output=True, text=True, timeout=900, check=False)
    assert final.returncode == 0, final.stderr
    assert started(player_log, offset).isdisjoint(journaled_before)
    assert journaled(out) == list(range(ALL_QUERIES))  # every query exactly once
    summary = json.loads((out / "summary.json").read_text())
    assert measured(summary) == measured(reference)  # as if it had never been interrupted
    assert _timeless(summary["best"]) == _timeless(reference["best"])


@contextlib.contextmanager
def _small_disk(path: Path, size: str) -> Iterator[Path]:
    """A tmpfs of ``size`` mounted at ``path``: a disk that really fills (ENOSPC), unmounted afterwards."""
    path.mkdir()
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(path)],
                             capture_output=True, text=True, check=False)  # fmt: skip
    if mounted.returncode != 0:
        pytest.skip(
            f"a full disk is simulated with a small tmpfs, and mounting one needs root: {mounted.stderr.strip()}"
        )
    try:
        yield path
    finally:
        subprocess.run(["umount", "--lazy", str(path)], check=False)


def _fill(disk: Path) -> Path:
    """Take every free byte of ``disk`` with one file; returns it (delete it to free the space)."""
    filler = disk / "filler"
    with filler.open("wb", buffering=0) as stream:
        for size in (1 << 20, 1 << 12, 1):  # whole megabytes, then what is left of the last pages
            with contextlib.suppress(OSError):
                while True:
                    stream.write(b"\0" * size)
    assert shutil.disk_usage(disk).free == 0
    return filler


@pytest.mark.slow
def test_a_full_disk_ends_the_attack_with_one_line_keeps_every_finished_query_and_leaves_nothing(
    kitti_window_bag: Path,
    tmp_path: Path,
    uninterrupted: tuple[str, dict[str, Any]],
    zombie_shm_segments: Callable[[], int],
) -> None:
    stack, reference = uninterrupted
    with _small_disk(tmp_path / "disk", "256m") as disk:
        out = disk / "attack"
        argv = attack_argv(kitti_window_bag, out, stack)
        zombie_shm_segments()  # what earlier tests left
        orchestrator = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        try:
            assert wait_for(lambda: len(journaled(out)) >= 3 or orchestrator.poll() is not None, timeout=600)
            assert orchestrator.poll() is None, "the attack ended before the disk filled"
            graph = children(orchestrator.pid)
            filler = _fill(disk)  # the disk is full from here on, as if another program had taken it
            kept = journaled(out)
            _, errors = orchestrator.communicate(timeout=300)
        finally:
            orchestrator.kill()
        assert orchestrator.returncode == 1, errors
        assert "Traceback" not in errors
        last = errors.strip().splitlines()[-1]  # after the progress bar
        assert last.startswith("advsim attack: error: no space left on the device"), errors
        assert str(out) in last
        assert wait_for(lambda: not any(alive(pid) for pid in graph), timeout=5.0), [p for p in graph if alive(p)]
        assert zombie_shm_segments() == 0
        assert journaled(out)[: len(kept)] == kept  # every query finished before is kept
        assert not list(out.rglob(".*.tmp")), "a half-written output was left"
        filler.unlink()  # space freed: the same command resumes and measures what an undisturbed run did
        final = subprocess.run(argv, capture_output=True, text=True, timeout=900, check=False)
        assert final.returncode == 0, final.stderr
        assert journaled(out) == list(range(ALL_QUERIES))
        summary = json.loads((out / "summary.json").read_text())
    assert measured(summary) == measured(reference)


@pytest.mark.slow
def test_two_evaluation_lanes_measure_what_one_does_and_kill_9_leaves_nothing_of_either(
    kitti_window_bag: Path,
    tmp_path: Path,
    uninterrupted: tuple[str, dict[str, Any]],
    zombie_shm_segments: Callable[[], int],
) -> None:
    stack, reference = uninterrupted
    out = tmp_path / "lanes"
    argv = attack_argv(kitti_window_bag, out, stack, "--lanes", "2")
    second_lane = out / "run" / "logs" / "lane1" / "graph_nodes.log"
    # killed once the second lane's graph replays a query: both graphs, both stacks running
    _kill_9_at(argv, lambda: bool(started(second_lane, 0)), out, zombie_shm_segments)
    final = subprocess.run(argv, capture_output=True, text=True, timeout=900, check=False)
    assert final.returncode == 0, final.stderr
    assert sorted(journaled(out)) == list(range(ALL_QUERIES))  # journaled as they finish, each exactly once
    summary = json.loads((out / "summary.json").read_text())
    assert summary["search"]["lanes"] == 2
    assert any(name.startswith("lane1/") for name in summary["resources"]["processes"])
    assert measured(summary) == measured(reference)  # same queries, same scores, same digests


@pytest.mark.slow
def test_a_stray_graph_on_the_same_ros_domain_changes_nothing_in_the_attack(
    kitti_window_bag: Path, tmp_path: Path, uninterrupted: tuple[str, dict[str, Any]]
) -> None:
    stack, reference = uninterrupted
    out = tmp_path / "crosstalk"
    orchestrator = subprocess.Popen(attack_argv(kitti_window_bag, out, stack), stdout=subprocess.DEVNULL,
                                    stderr=subprocess.PIPE, text=True)  # fmt: skip
    graph_file = out / "run" / "graph.json"
    intruder = None
    try:
        assert wait_for(lambda: graph_file.exists() or orchestrator.poll() is not None, timeout=600)
        domain = json.loads(graph_file.read_text())["ros_domain_id"]
        intruder = subprocess.Popen([sys.executable, str(INTRUDER)], env=graph_environment(domain),
                                    stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)  # fmt: skip
        _, errors = orchestrator.communicate(timeout=600)
    finally:
        orchestrator.kill()  # only if the test failed: it has exited otherwise
        if intruder is not None:
            intruder.send_signal(signal.SIGINT)
            intruder.wait(timeout=30)
    assert orchestrator.returncode == 0, errors
    logs = "".join(path.read_text() for path in (out / "run" / "logs").glob("*.log"))
    assert "ignoring /advsim/perturbation messages of run 0x67932" in logs  # the stray run id, seen and ignored
    assert measured(json.loads((out / "summary.json").read_text())) == measured(reference)


@pytest.mark.slow
def test_an_attack_suspended_while_its_graph_searches_on_journals_every_query_when_it_continues(
    kitti_window_bag: Path, tmp_path: Path, uninterrupted: tuple[str, dict[str, Any]]
) -> None:
    """SIGSTOP (what Ctrl-Z sends; a starved process is the milder case) stops the orchestrator and its monitor,
    not the graph: the search runs to its end meanwhile, and on SIGCONT the monitor must still get every query."""
    stack, reference = uninterrupted
    out = tmp_path / "suspended"
    player_log = out / "run" / "logs" / "graph_nodes.log"
    last_query = ALL_QUERIES - 1  # the identity control
    orchestrator = subprocess.Popen(attack_argv(kitti_window_bag, out, stack), stdout=subprocess.DEVNULL,
                                    stderr=subprocess.PIPE, text=True)  # fmt: skip
    try:
        assert wait_for(lambda: len(journaled(out)) >= 2 or orchestrator.poll() is not None, timeout=600)
        assert orchestrator.poll() is None, "the attack ended before it could be suspended"
        orchestrator.send_signal(signal.SIGSTOP)
        ran_ahead = wait_for(lambda: last_query in started(player_log, 0), timeout=120)
        journaled_while_suspended = len(journaled(out))
        orchestrator.send_signal(signal.SIGCONT)
        _, errors = orchestrator.communicate(timeout=120)
    finally:
        orchestrator.kill()  # only if the test failed: it has exited otherwise
    assert ran_ahead, "the graph did not replay the last query while the orchestrator was suspended"
    assert journaled_while_suspended < last_query + 1  # so the monitor really missed queries as they happened
    assert orchestrator.returncode == 0, errors
    assert journaled(out) == list(range(last_query + 1))  # every query exactly once
    assert measured(json.loads((out / "summary.json").read_text())) == measured(reference)


def _outputs_process(orchestrator: int) -> int | None:
    """The attack's outputs process (attack.outputs_worker), once it runs."""
    for pid in children(orchestrator):
        with contextlib.suppress(OSError):
            if b"advsim_ros.attack.outputs_worker" in Path(f"/proc/{pid}/cmdline").read_bytes():
                return pid
    return None


@pytest.mark.slow
def test_an_outputs_process_killed_while_the_graph_searches_leaves_the_same_outputs_written_by_the_attack(
    kitti_window_bag: Path, tmp_path: Path, uninterrupted: tuple[str, dict[str, Any]]
) -> None:
    """The outputs are prepared by a process of their own (the OOM killer's likeliest prey: it holds the window's
    sweeps and the re-simulation model): killed, the attack writes them itself, the same, and still exits 0."""
    stack, reference = uninterrupted
    out = tmp_path / "outputs_killed"
    orchestrator = subprocess.Popen(attack_argv(kitti_window_bag, out, stack), stdout=subprocess.DEVNULL,
                                    stderr=subprocess.PIPE, text=True)  # fmt: skip
    try:
        assert wait_for(lambda: len(journaled(out)) >= 2 or orchestrator.poll() is not None, timeout=600)
        worker = _outputs_process(orchestrator.pid)
        assert worker is not None, "no outputs process while the graph searches"
        os.kill(worker, signal.SIGKILL)
        _, errors = orchestrator.communicate(timeout=600)
    finally:
        orchestrator.kill()  # only if the test failed: it has exited otherwise
    assert orchestrator.returncode == 0, errors
    summary = json.loads((out / "summary.json").read_text())
    assert measured(summary) == measured(reference)
    assert summary["recorded_inputs_reproduced"] is True  # the bag's sweeps are what the stack received
    assert "outputs_peak_rss_mb" not in summary["resources"]  # written by the orchestrator, not the worker
    assert (out / "bev.png").stat().st_size > 0
    assert (out / "report.html").stat().st_size > 0
    assert "outputs_peak_rss_mb" in reference["resources"]  # the undisturbed attack's came from the worker


@pytest.mark.slow
def test_a_stack_that_is_not_deterministic_is_reported_as_such_and_replay_check_counts_the_runs_that_reproduce(
    kitti_window_bag: Path, tmp_path: Path, simple_stack: Callable[..., str], advsim: Callable[..., Any]
) -> None:
    out = tmp_path / "flaky"
    result = subprocess.run(
        attack_argv(kitti_window_bag, out, simple_stack(flaky_probability=0.3)), capture_output=True, text=True,
        timeout=900, check=False,
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["stack_nondeterministic"] is True  # 30 answers to identical inputs were not all the same
    (reproduction,) = summary["reproductions"]
    assert reproduction["inputs_identical"] is True  # the framework sent the same bytes every time
    values = reproduction["adversarial_losses"]
    assert reproduction["spread"] == max(values) - min(values)
    assert reproduction["reproduced"] == (reproduction["spread"] == 0.0)
    assert (reproduction["query_id"] in summary["flaky"]) == (not reproduction["reproduced"])
    replay = advsim("replay", str(out / "adversarial"), "--stack", simple_stack(flaky_probability=1.0), "--check",
                    "--runs", "3", "-o", str(tmp_path / "replay"))  # fmt: skip
    assert replay.returncode == 3, replay.stdout + replay.stderr
    assert "reproduced 0 of 3 runs" in replay.stdout


@pytest.mark.slow
def test_an_original_that_does_not_reproduce_is_reported_original_flaky_and_its_finding_not_counted(
    kitti_window_bag: Path, tmp_path: Path, simple_stack: Callable[..., str], uninterrupted: tuple[str, dict[str, Any]]
) -> None:
    _, reference = uninterrupted
    out = tmp_path / "late_start"
    argv = attack_argv(kitti_window_bag, out, simple_stack(wrong_first_sweeps=10))  # query 0 planned from a bad speed
    result = subprocess.run(argv, capture_output=True, text=True, timeout=900, check=False)
    assert result.returncode == 0, result.stderr  # the original was scored: the attack ran, its reading says why
    summary = json.loads((out / "summary.json").read_text())
    controls = summary["controls"]
    assert controls["original_flaky"] is True
    first, *again = controls["original"]["adversarial_losses"]
    assert again == [reference["original"]["adversarial_loss"]] * 2  # the re-runs score as an undisturbed original
    assert first != again[0]
    assert controls["original"]["inputs_identical"] is True  # the same bytes in: the stack differed, not the graph
    identity = controls["identity"]
    assert identity["score"]["status"] == "ok"
    assert controls["sim_gap"] is not None
    finding = summary["finding"]
    if finding is not None and finding["collision"]:
        assert not finding["counts_as_failure"]
        assert any(reason.startswith("original_flaky") for reason in finding["excluded"])


@pytest.mark.slow
def test_a_stack_that_never_hears_the_lidar_ends_the_attack_with_what_it_listens_to(
    kitti_window_bag: Path, tmp_path: Path, simple_stack: Callable[..., str]
) -> None:
    stack = simple_stack() + " -r /sensor/lidar/points:=/points_raw"  # the user's own topic name, not remapped
    result = subprocess.run(
        attack_argv(kitti_window_bag, tmp_path / "deaf", stack, "--connect-timeout", "20"),
        capture_output=True, text=True, timeout=600, check=False,
    )  # fmt: skip
    assert result.returncode == 1
    message = result.stderr.strip().splitlines()[-1]
    assert "the stack did not connect within 20 s: no subscription to the LiDAR topic /sensor/lidar/points" in message
    assert "/points_raw" in message  # what it subscribes to instead


@pytest.mark.slow
@pytest.mark.parametrize(
    ("sent", "code", "word"), [(signal.SIGINT, 130, "interrupted"), (signal.SIGTERM, 143, "terminated")]
)
def test_sigint_and_sigterm_end_the_attack_with_one_line_their_exit_code_and_nothing_left(
    kitti_window_bag: Path, tmp_path: Path, simple_stack: Callable[..., str], sent: int, code: int, word: str
) -> None:
    out = tmp_path / "stopped"
    # a budget it cannot finish before the signal (a warm machine scores several queries a second)
    argv = attack_argv(kitti_window_bag, out, simple_stack(), "--queries", "500")
    # as from a terminal: SIGINT handled (a test run started in the background by a script inherits it ignored)
    orchestrator = subprocess.Popen(
        argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),  # before any thread starts
    )  # fmt: skip
    try:
        assert wait_for(lambda: len(journaled(out)) >= 2 or orchestrator.poll() is not None, timeout=600)
        graph = children(orchestrator.pid)
        orchestrator.send_signal(sent)
        _, errors = orchestrator.communicate(timeout=60)
    finally:
        orchestrator.kill()
    assert orchestrator.returncode == code, errors
    assert "Traceback" not in errors
    assert errors.strip().splitlines()[-1].startswith(f"advsim attack: {word}")
    assert not [pid for pid in graph if alive(pid)]
    assert len(journaled(out)) >= 2  # what finished is kept


@pytest.mark.parametrize(
    ("case", "expected"),
    [
        ("missing_stack", "--stack: command 'no-such-stack-command' not found on PATH"),
        ("window", "window frames 100..159 need 160 frames, the log has 60"),
        ("not_a_bag", "not a rosbag2 folder (no metadata.yaml)"),
        ("remap", "remapping of /velodyne_points: not a topic of the contract"),
        ("parameter", "/perturber: unknown parameter(s) ['num_candidate']"),
        ("out_is_a_file", "exists and is not a folder; give -o a folder"),
    ],
)
def test_bad_input_gets_one_line_naming_the_problem_and_starts_nothing(
    kitti_window_bag: Path, tmp_path: Path, advsim: Callable[..., Any], case: str, expected: str
) -> None:
    out = tmp_path / "out"
    remap_file = tmp_path / "remap.yaml"
    remap_file.write_text("/velodyne_points: /points_raw\n")
    (tmp_path / "empty").mkdir()
    arguments = {
        "missing_stack": [str(kitti_window_bag), "--stack", "no-such-stack-command"],
        "window": [str(kitti_window_bag), "--window-start", "100"],
        "not_a_bag": [str(tmp_path / "empty")],
        "remap": [str(kitti_window_bag), "--remap-file", str(remap_file)],
        "parameter": [str(kitti_window_bag), "--param", "perturber.num_candidate=10"],
        "out_is_a_file": [str(kitti_window_bag)],
    }[case]
    if case == "out_is_a_file":
        out.write_text("a file of the user's")
    result = advsim("attack", *arguments, "-o", str(out), timeout=120)
    assert result.returncode == 1
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert expected in lines[0]
    if case == "out_is_a_file":
        assert out.read_text() == "a file of the user's"  # nothing lost
    else:
        assert not out.exists()  # nothing started, nothing written
