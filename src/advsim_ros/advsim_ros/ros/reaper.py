"""The graph's reaper: kills what is left of an attack graph once its orchestrator is gone, however it ended.

``advsim attack`` (the orchestrator) starts this process first and tells it, on its standard
input, the process group of every process it starts (each node and the stack run in a group of
their own); ``advsim campaign`` tells it single processes instead (``pid PID STARTTIME``: the
local Ray's own processes, which share the driver's group), and the run's marker (``marker
TOKEN``: every process the graph started carries it in its environment, so a process the stack
put in a session of its own is found too). When standard input closes — the orchestrator exited,
crashed or was killed with SIGKILL — the reaper sends SIGKILL to every process and group it was
told about and every process carrying the marker, waits until none of them is left, removes the
Fast DDS shared-memory segments their processes left behind (a process killed with SIGKILL never
unlinks its segment, 32 MiB of RAM each under ``/dev/shm``), and exits. It holds the graph's
ROS-domain lock until then, so the domain is not handed to another graph while anything of this
one still runs.

Run as ``python -m advsim_ros.ros.reaper``; it ignores SIGINT and SIGTERM (a Ctrl-C in the
terminal must not take it down before the graph).
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from advsim_ros.ros.identity import marked_processes

_SETTLE_POLL = 0.02  # [s]
_GIVE_UP_AFTER = 30.0  # a process stuck in uninterruptible sleep is reported, not waited for forever [s]


def _stat(pid: int, task: str = "") -> list[bytes] | None:
    """The fields of /proc/PID/stat (of thread ``task`` when given) after the command name (state first), None when
    it is gone."""
    try:
        with open(f"/proc/{pid}/task/{task}/stat" if task else f"/proc/{pid}/stat", "rb") as stream:
            return stream.read().rsplit(b")", 1)[1].split()
    except OSError:
        return None


def _still_exiting(pid: int) -> bool:
    """A zombie leader whose other threads have not finished exiting: they still hold its files.

    A killed multi-threaded process (every DDS node) shows its leader as a zombie while the other
    threads are still tearing down; its shared-memory locks go only when the last one has gone.
    """
    try:
        tasks = os.listdir(f"/proc/{pid}/task")
    except OSError:
        return False
    return any(fields is not None and fields[0] not in (b"Z", b"X") for fields in (_stat(pid, t) for t in tasks))


def group_members(groups: set[int]) -> list[int]:
    """Pids of processes whose process group is one of ``groups`` and that have not fully exited (from /proc)."""
    members = []
    for entry in os.listdir("/proc"):
        fields = _stat(int(entry)) if entry.isdigit() else None
        if fields is not None and int(fields[2]) in groups and (fields[0] != b"Z" or _still_exiting(int(entry))):
            members.append(int(entry))
    return members


def kill_groups(groups: set[int]) -> list[int]:
    """SIGKILL every group until none of their processes is left; returns the pids that would not die."""
    deadline = time.monotonic() + _GIVE_UP_AFTER
    while True:
        for group in groups:
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.killpg(group, signal.SIGKILL)
        left = group_members(groups)
        if not left or time.monotonic() > deadline:
            return left
        time.sleep(_SETTLE_POLL)


def start_time(pid: int) -> int | None:
    """When the process started (clock ticks since boot): with the pid, it names one process, not a reused pid."""
    fields = _stat(pid)
    return None if fields is None else int(fields[19])


def descendants(root: int) -> list[int]:
    """Pids of the live processes below ``root`` (children, their children, ...)."""
    children: dict[int, list[int]] = {}
    for entry in os.listdir("/proc"):
        fields = _stat(int(entry)) if entry.isdigit() else None
        if fields is not None and fields[0] != b"Z":
            children.setdefault(int(fields[1]), []).append(int(entry))
    found, todo = [], [root]
    while todo:
        for child in children.get(todo.pop(), []):
            found.append(child)
            todo.append(child)
    return found


def kill_marked(marker: str) -> list[int]:
    """SIGKILL every process carrying the run's marker until none is left; returns the pids that would not die."""
    deadline = time.monotonic() + _GIVE_UP_AFTER
    while True:
        marked = [pid for pid in marked_processes(marker) if pid != os.getpid() and not _exited(pid)]
        if not marked or time.monotonic() > deadline:
            return marked
        for pid in marked:
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.kill(pid, signal.SIGKILL)
        time.sleep(_SETTLE_POLL)


def _exited(pid: int) -> bool:
    fields = _stat(pid)
    return fields is None or (fields[0] == b"Z" and not _still_exiting(pid))


def kill_processes(processes: set[tuple[int, int]]) -> None:
    """SIGKILL each (pid, start time) that is still that process."""
    for pid, started in processes:
        if start_time(pid) == started:
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.kill(pid, signal.SIGKILL)


FASTDDS_TOOL = Path(sys.prefix) / "tools" / "fastdds" / "fastdds.py"  # installed by the ros-fastrtps wheel


def clean_shared_memory() -> str:
    """Remove Fast DDS shared-memory segments and ports whose owner is dead, with Fast DDS's own tool.

    ``fastdds shm clean`` removes only what no live process holds a lock on, so graphs still
    running on this machine keep theirs. Returns the tool's report (or why it did not run).
    """
    if not FASTDDS_TOOL.is_file():
        return f"fastdds shm clean: not run, {FASTDDS_TOOL} is missing"
    try:
        done = subprocess.run(
            [sys.executable, str(FASTDDS_TOOL), "shm", "clean"], capture_output=True, text=True, timeout=60
        )
    except subprocess.TimeoutExpired:
        return "fastdds shm clean: gave up after 60 s"
    return " ".join((done.stdout + done.stderr).split())


def main() -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    groups: set[int] = set()
    processes: set[tuple[int, int]] = set()
    markers: set[str] = set()
    for line in sys.stdin:
        with contextlib.suppress(ValueError):
            words = line.split()
            if len(words) == 3 and words[0] == "pid":
                processes.add((int(words[1]), int(words[2])))
            elif len(words) == 2 and words[0] == "marker":
                markers.add(words[1])
            else:
                groups.add(int(line))
    kill_processes(processes)
    left = kill_groups(groups)
    for marker in markers:
        left += kill_marked(marker)
    if left:
        print(f"advsim reaper: processes {left} of the graph did not die", file=sys.stderr)
    print(f"advsim reaper: {clean_shared_memory()}", file=sys.stderr)


if __name__ == "__main__":
    main()
