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


def query_breakdown(events: list[tuple[float, str, str, int, int]]) -> dict[int, dict[str, float]]:
    """Seconds per stage of every query from a merged trace (see bench/bench_attack.py).

    search: the search's own time from the previous score to this query's perturbation;
    perturber: projecting the delta; to_replay: from the perturbed tracks to the replay's start
    (transport, the player's checks); resim_wait: time the player waited for rendered sweeps;
    stack: from a sweep sent to its plan back (the stack's compute and the transport both ways);
    scorer: scoring after DONE; protocol: the rest (messages in flight, decoding).
    """
    at: dict[tuple[str, int, int], float] = {}
    for stamp, _, event, query, frame in events:
        at.setdefault((event, query, frame), stamp)
    queries = sorted({q for _, _, e, q, _ in events if e == "perturbation_sent"})
    result: dict[int, dict[str, float]] = {}
    for query in queries:
        keys = ("perturbation_sent", "score_received", "query_start", "done_sent")
        if any((key, query, -1) not in at for key in keys):
            continue  # infeasible, or cut off by the end of the trace
        sent, scored, start, done = (at[(key, query, -1)] for key in keys)
        frames = sorted({f for (e, q, f) in at if e == "sweep_sent" and q == query and f >= 0})
        stack = sum(
            at[("plan_seen", query, f)] - at[("sweep_sent", query, f)]
            for f in frames
            if ("plan_seen", query, f) in at and ("sweep_sent", query, f) in at
        )
        previous = at.get(("score_received", query - 1, -1), sent)
        stages = {
            "search": sent - previous,
            "perturber": at.get(("tracks_sent", query, -1), sent) - at.get(("perturbation_received", query, -1), sent),
            "to_replay": start - at.get(("tracks_sent", query, -1), start),
            "stack": stack,
            "resim_wait": (done - start) - stack,
            "scorer": at.get(("score_sent", query, -1), done) - at.get(("done_received", query, -1), done),
            "total": scored - previous,
        }
        stages["protocol"] = stages["total"] - sum(v for k, v in stages.items() if k != "total")
        result[query] = stages
    return result
