"""Processes of an attack carry its marker; endpoints are tied to them by the pid bits in their GIDs (ros.identity).

That Fast DDS really writes the pid there is tested with rclpy in src/advsim_ros/test/test_graph_identity.py.
"""

from __future__ import annotations

import os
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from advsim_ros.ros.identity import RUN_MARKER, Membership, carries_marker, endpoint_pid_bits, marked_processes
from advsim_ros.ros.launcher import reserve_domain_id, start_reaper

MARKER = "0f1e2d3c4b5a69788796a5b4c3d2e1f0"


def _gid(pid: int) -> list[int]:
    """An endpoint GID as Fast DDS makes them: vendor 1.15, host id, the pid's low 16 bits, then counters."""
    return [1, 15, 120, 253, pid & 0xFF, (pid >> 8) & 0xFF, 33, 107, 0, 0, 0, 1, 0, 0, 19, 3]


@pytest.fixture
def marked() -> Iterator[subprocess.Popen[bytes]]:
    """A process in a session of its own that carries the marker, as a stack's daemon would."""
    process = subprocess.Popen(["sleep", "600"], env={**os.environ, RUN_MARKER: MARKER}, start_new_session=True)
    deadline = time.monotonic() + 10.0
    # Popen returns after the fork: until the child has exec'd, /proc shows the parent's environment
    while Path(f"/proc/{process.pid}/cmdline").read_bytes().split(b"\0")[0] != b"sleep" and time.monotonic() < deadline:
        time.sleep(0.001)
    yield process
    process.kill()
    process.wait()


def test_a_process_started_with_the_marker_carries_it_and_is_found_and_others_are_not(
    marked: subprocess.Popen[bytes],
) -> None:
    assert carries_marker(marked.pid, MARKER)
    assert not carries_marker(marked.pid, "another" + MARKER)
    assert not carries_marker(os.getpid(), MARKER)  # this test's own process was started without it
    assert marked_processes(MARKER) == [marked.pid]


def test_an_endpoint_belongs_to_the_attack_only_when_its_pid_bits_name_a_marked_process(
    marked: subprocess.Popen[bytes],
) -> None:
    membership = Membership(MARKER)
    assert endpoint_pid_bits(_gid(marked.pid)) == marked.pid & 0xFFFF
    assert membership.belongs(_gid(marked.pid))
    assert not membership.belongs(_gid(os.getpid()))
    cyclone = [1, 16, *_gid(marked.pid)[2:]]  # another DDS vendor's GID layout says nothing about its process
    assert endpoint_pid_bits(cyclone) is None
    assert not membership.belongs(cyclone)


def test_an_endpoint_of_a_process_the_launcher_started_belongs_after_the_process_is_gone(tmp_path: Path) -> None:
    crashed = subprocess.Popen(["true"])
    crashed.wait()  # gone from /proc, as a crashed stack whose endpoints linger in the graph until their lease ends
    started = tmp_path / "pids"
    started.write_text(f"{os.getpid() + 1}\n{crashed.pid}\n")
    assert Membership(MARKER, started).belongs(_gid(crashed.pid))
    assert not Membership(MARKER).belongs(_gid(crashed.pid))  # without the launcher's list: not provably ours
    assert not Membership(MARKER, tmp_path / "no such file").belongs(_gid(crashed.pid))


def test_the_reaper_ends_a_marked_process_whatever_session_it_put_itself_in(tmp_path: Path) -> None:
    daemon = subprocess.Popen(["sleep", "600"], env={**os.environ, RUN_MARKER: MARKER}, start_new_session=True)
    reaper = start_reaper(tmp_path / "reaper.log", {**os.environ, RUN_MARKER: MARKER}, marker=MARKER)
    try:
        assert reaper.stdin is not None
        assert reaper.poll() is None
        reaper.stdin.close()  # as when the orchestrator is gone, however it ended
        assert reaper.wait(timeout=60) == 0
        assert daemon.wait(timeout=10) == -9
        assert not carries_marker(reaper.pid, MARKER)  # it never had the marker: it does not reap itself
    finally:
        daemon.kill()
        daemon.wait()
        reaper.kill()
        reaper.wait()
    assert "did not die" not in (tmp_path / "reaper.log").read_text()


def test_the_domain_an_attack_gets_is_drawn_at_random_among_the_free_ones() -> None:
    drawn = set()
    for _ in range(20):
        with reserve_domain_id() as lease:  # released at once: the next draw has the same choice
            drawn.add(lease.domain_id)
    assert len(drawn) > 5  # the first free one each time would give a single domain
    assert all(100 <= domain < 230 for domain in drawn)
