"""Handing one batch's queries to the evaluation lanes and collecting their scores (pure: waits and clock given).

With ``advsim attack --lanes K`` the search evaluates on K lanes: its own graph and K - 1 whole
graphs on ROS domains of their own (ros.lanes joins them). The queries of the algorithm's batch
go out in order, each lane the next one as soon as it is free, so up to K queries run at once. A
query whose score does not come within ``score_timeout`` of its sending counts as failed (NaN)
and frees its lane. The search node gives the publishing, the scores its subscriptions fill and
the wait on them; the order of the queries, and so their ids, never depends on which lane is free.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence

from advsim_ros.core.types import Perturbation

Ready = Callable[[], bool]


def evaluate_on_lanes(
    perturbations: Sequence[Perturbation],
    lanes: int,
    send: Callable[[int, Perturbation], None],
    scores: Mapping[int, float],
    wait: Callable[[Ready, float], object],
    stopped: Callable[[], bool],
    score_timeout: float,
    *,
    sent: Callable[[Perturbation], None] = lambda perturbation: None,
    timed_out: Callable[[int], None] = lambda query_id: None,
    clock: Callable[[], float] = time.monotonic,
) -> list[float]:
    """L_adv per query, NaN when it failed or no score came within ``score_timeout`` of its sending.

    ``send(lane, query)`` publishes a query on lane 0..lanes-1, then ``sent(query)`` is told (the
    node counts and traces it); ``scores`` (query id -> L_adv) fills as scores arrive, and
    ``wait(ready, timeout)`` returns once ``ready()`` or after ``timeout`` seconds of ``clock``.
    Returns early, unscored queries NaN, once ``stopped()``.
    """
    waiting = list(perturbations)
    busy: dict[int, tuple[int, float]] = {}  # lane -> (query id, sent at [clock s])
    late: set[int] = set()
    while (waiting or busy) and not stopped():
        for lane in range(lanes):
            if lane not in busy and waiting:
                perturbation = waiting.pop(0)
                send(lane, perturbation)
                busy[lane] = (perturbation.query_id, clock())
                sent(perturbation)
        deadline = min(sent_at for _, sent_at in busy.values()) + score_timeout
        wait(lambda: any(query_id in scores for query_id, _ in busy.values()), max(0.0, deadline - clock()))
        for lane, (query_id, sent_at) in list(busy.items()):
            if query_id in scores:
                del busy[lane]
            elif clock() - sent_at >= score_timeout:
                timed_out(query_id)
                late.add(query_id)
                del busy[lane]
    return [math.nan if p.query_id in late else scores.get(p.query_id, math.nan) for p in perturbations]
