"""Who is on an attack's graph: DDS endpoints tied to the processes the attack started.

Every process an attack starts (its nodes, the stack, whatever the stack forks) carries the
attack's secret marker in its environment (``ADVSIM_RUN_MARKER``; ros.launcher sets it, children
inherit it). Fast DDS writes the id of the process that created a participant into the
participant's GUID prefix, and so into every endpoint GID rclpy reports: vendor id 1.15
(eProsima) in bytes 0-1, the pid's low 16 bits, little-endian, in bytes 4-5. An endpoint belongs
to the attack when a live process with those pid bits carries the marker, or when they are the
bits of a process the graph's launcher started (``ADVSIM_RUN_PIDS`` names the file it lists them
in: a crashed stack's endpoints stay in the graph until their lease expires, after its /proc entry
is gone); anything else that publishes on the stack's topics is foreign, and the query it overlaps
cannot be trusted.

The graph's DDS runs over shared memory only (ros/fastdds_graph.xml), so only a process on this
machine, on the attack's randomly drawn domain and with the graph's transport profile, can be
discovered at all; this check is what stands between such a process and a score. It reads
/proc: the pids are this machine's (the graph never leaves it).
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

if TYPE_CHECKING:
    from rclpy.topic_endpoint_info import TopicEndpointInfo


class GraphView(Protocol):
    """What this module reads of a node: the publishers on a topic (rclpy's Node has it)."""

    def get_publishers_info_by_topic(self, topic_name: str) -> list[TopicEndpointInfo]: ...


RUN_MARKER = "ADVSIM_RUN_MARKER"
RUN_PIDS = "ADVSIM_RUN_PIDS"  # the file the launcher lists the pids of the processes it started in
_EPROSIMA = (1, 15)  # Fast DDS's RTPS vendor id


def endpoint_pid_bits(gid: Sequence[int]) -> int | None:
    """The low 16 bits of the pid that created a Fast DDS endpoint (None for another DDS vendor's)."""
    if len(gid) < 6 or (gid[0], gid[1]) != _EPROSIMA:
        return None
    return int(gid[4]) | int(gid[5]) << 8


def carries_marker(pid: int, marker: str) -> bool:
    """Whether process ``pid`` was started with ``RUN_MARKER=marker`` in its environment."""
    try:
        environ = Path(f"/proc/{pid}/environ").read_bytes()
    except OSError:  # gone, or not ours to read: not provably the attack's
        return False
    return f"{RUN_MARKER}={marker}".encode() in environ.split(b"\0")


def marked_processes(marker: str) -> list[int]:
    """Pids of the live processes that carry the marker (whatever session or group they put themselves in)."""
    return [int(entry) for entry in os.listdir("/proc") if entry.isdigit() and carries_marker(int(entry), marker)]


@dataclass(frozen=True)
class ForeignEndpoint:
    """A publisher on one of the stack's topics that no process of the attack created."""

    topic: str
    node: str  # the ROS node name it announced ('' when the participant announced none)
    pid_bits: int | None  # the low 16 bits of its process id (None: not Fast DDS)

    def describe(self) -> str:
        who = f"pid {self.pid_bits} (mod 65536)" if self.pid_bits is not None else "a participant of another DDS"
        node = f"node {self.node!r}, " if self.node else ""
        return f"{self.topic} from {node}{who}, not a process of this attack"


class Membership:
    """Answers "was this endpoint created by a process of the attack?" for endpoint GIDs, with a cache.

    A GID names one endpoint of one process for that endpoint's life, so a verdict never changes;
    a GID not seen before costs one look at the few processes whose pid has its 16 bits.
    """

    def __init__(self, marker: str, started: Path | None = None) -> None:
        self.marker = marker
        self.started = started  # the launcher's list of the pids it started, dead ones included
        self._verdicts: dict[bytes, bool] = {}

    def _started_bits(self) -> set[int]:
        try:
            lines = self.started.read_text().split() if self.started is not None else []
        except OSError:
            return set()
        return {int(line) & 0xFFFF for line in lines if line.isdigit()}

    def belongs(self, gid: Sequence[int]) -> bool:
        key = bytes(gid)
        verdict = self._verdicts.get(key)
        if verdict is None:
            bits = endpoint_pid_bits(gid)
            verdict = bits is not None and (
                any(
                    int(entry) & 0xFFFF == bits and carries_marker(int(entry), self.marker)
                    for entry in os.listdir("/proc")
                    if entry.isdigit()
                )
                or bits in self._started_bits()
            )
            self._verdicts[key] = verdict
        return verdict

    def foreign_publishers(self, node: GraphView, topic_names: Iterable[str]) -> list[ForeignEndpoint]:
        """Publishers on these topics (read from ``node``'s view of the ROS graph) that are not the attack's."""
        found = []
        for topic in dict.fromkeys(topic_names):
            for info in node.get_publishers_info_by_topic(topic):
                gid = list(info.endpoint_gid)
                if not self.belongs(gid):
                    found.append(ForeignEndpoint(topic, str(info.node_name), endpoint_pid_bits(gid)))
        return found


def run_membership() -> Membership | None:
    """The membership of the attack this process belongs to (None when it was not started by an attack)."""
    marker, started = os.environ.get(RUN_MARKER), os.environ.get(RUN_PIDS)
    return Membership(marker, Path(started) if started else None) if marker else None
