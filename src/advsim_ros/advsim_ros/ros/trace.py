"""A timeline of the attack graph across its processes, for finding where a query waits.

With ``ADVSIM_TRACE_DIR`` set, every node appends ``time event query frame`` lines (time on the
machine-wide monotonic clock, so the processes' lines merge into one timeline) to
``<dir>/<node>.trace``; ``bench/bench_attack.py`` turns them into a per-query breakdown. Unset, a
trace call costs one attribute check.
"""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import IO

TRACE_ENV = "ADVSIM_TRACE_DIR"


class Trace:
    def __init__(self, node: str) -> None:
        folder = os.environ.get(TRACE_ENV)
        self._stream: IO[str] | None = None
        if folder:
            Path(folder).mkdir(parents=True, exist_ok=True)
            self._stream = open(Path(folder) / f"{node}.trace", "a", buffering=1, encoding="utf-8")  # noqa: SIM115

    def __call__(self, event: str, query: int = -1, frame: int = -1) -> None:
        if self._stream is not None:
            self._stream.write(f"{time.monotonic():.6f} {event} {query} {frame}\n")


def read_trace(folder: Path) -> list[tuple[float, str, str, int, int]]:
    """Every line of every node's trace in a folder, as (time, node, event, query, frame), in time order."""
    events = []
    for path in Path(folder).glob("*.trace"):
        for line in path.read_text(encoding="utf-8").splitlines():
            stamp, event, query, frame = line.split()
            events.append((float(stamp), path.stem, event, int(query), int(frame)))
    return sorted(events)
