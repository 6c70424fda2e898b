"""The reaper counts a killed process as gone only once every thread of it has exited (ros.reaper)."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

from advsim_ros.ros.reaper import group_members, kill_groups

# The main thread leaves with pthread_exit while a second thread runs on: the leader shows as a
# zombie in /proc/PID/stat, yet the process still holds its files, as a killed DDS node does while
# its threads tear down.
LEADER_GONE_THREAD_ALIVE = """
import ctypes, threading, time
threading.Thread(target=lambda: time.sleep(600)).start()
time.sleep(0.2)
ctypes.CDLL(None).pthread_exit(None)
"""


def _state(pid: int) -> str:
    return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]


def test_a_zombie_leader_with_a_running_thread_is_still_a_member_until_killed() -> None:
    process = subprocess.Popen([sys.executable, "-c", LEADER_GONE_THREAD_ALIVE], start_new_session=True)
    try:
        deadline = time.monotonic() + 30
        while _state(process.pid) != "Z" and time.monotonic() < deadline:
            time.sleep(0.05)
        assert _state(process.pid) == "Z", "the main thread did not exit"
        assert group_members({process.pid}) == [process.pid]  # its other thread still runs
        assert kill_groups({process.pid}) == []
        assert group_members({process.pid}) == []
    finally:
        process.kill()
        process.wait()
