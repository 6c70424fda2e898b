"""The attack's monitor, fed the protocol's messages by hand: what it says an unfinished query lacks."""

from __future__ import annotations

import numpy as np

from advsim_ros import graph
from advsim_ros.contract.enums import Status
from advsim_ros.contract.protocol import ScoreRecord, perturbation_msg, score_msg
from advsim_ros.core.types import Perturbation
from advsim_ros.ros.lockstep import StackNames
from advsim_ros.ros.monitor import AttackMonitor

RUN = 7


def _perturbation(query_id: int) -> object:
    return perturbation_msg(Perturbation(query_id, "window", ("3",), np.zeros(4), "random"), RUN)


def test_an_unfinished_query_is_named_with_the_pieces_it_still_lacks() -> None:
    monitor = AttackMonitor(
        RUN, StackNames(graph.NAMES), graph.MONITOR.name
    )  # not entered: no ROS context, messages are handed to its callbacks
    assert monitor.missing() == ""
    monitor._on_perturbation(_perturbation(4))
    monitor._on_score(score_msg(ScoreRecord(4, Status.OK, adversarial_loss=2.0), RUN))
    monitor._on_score(score_msg(ScoreRecord(6, Status.OK, adversarial_loss=1.0), RUN))
    assert monitor.missing() == (
        "query 4: episode DONE, perturbed tracks; query 6: perturbation, episode DONE, perturbed tracks"
    )
    # an infeasible query is never replayed: only its perturbation can be missing
    monitor._on_score(score_msg(ScoreRecord(5, Status.INFEASIBLE, "outside the feasible set"), RUN))
    monitor._on_perturbation(_perturbation(5))
    assert [query.perturbation.query_id for query in monitor.take_finished()] == [5]
    assert "query 5" not in monitor.missing()
