"""The graph's reaper: kills what is left of an attack graph once its orchestrator is gone, however it ended.

``advsim attack`` (the orchestrator) starts this process first and tells it, on its standard
input, the process group of every process it starts (each node and the stack run in a group of
their own). When standard input closes — the orchestrator exited, crashed or was killed with
SIGKILL — the reaper sends SIGKILL to every group it was told about, waits until no process of
them is left, and exits. It holds the graph's ROS-domain lock until then, so the domain is not
handed to another graph while anything of this one still runs.

Run as ``python -m advsim_ros.ros.reaper``; it ignores SIGINT and SIGTERM (a Ctrl-C in the
terminal must not take it down before the graph).
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import time

_SETTLE_POLL = 0.02  # [s]
_GIVE_UP_AFTER = 30.0  # a process stuck in uninterruptible sleep is reported, not waited for forever [s]


def group_members(groups: set[int]) -> list[int]:
    """Pids of live processes whose process group is one of ``groups`` (from /proc)."""
    members = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat", "rb") as stream:
                fields = stream.read().rsplit(b")", 1)[1].split()
        except OSError:
            continue
        state, pgrp = fields[0], int(fields[2])
        if pgrp in groups and state != b"Z":
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


def main() -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    groups: set[int] = set()
    for line in sys.stdin:
        with contextlib.suppress(ValueError):
            groups.add(int(line))
    left = kill_groups(groups)
    if left:
        print(f"advsim reaper: processes {left} of the graph did not die", file=sys.stderr)


if __name__ == "__main__":
    main()
