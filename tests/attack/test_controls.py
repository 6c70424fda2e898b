"""Reading a finding: the original's re-runs, the identity control's sim gap and when a finding is sim-dominated."""

from __future__ import annotations

import numpy as np

from advsim_ros.attack.controls import SIM_MARGIN, controls, finding, plan_gap
from advsim_ros.core.journal import QueryRecord
from advsim_ros.core.types import Plan

DECISION_NS = 10_000_000_000
STEP_NS = 100_000_000


def _plan(lateral: float) -> Plan:
    """A straight plan at 10 m/s along x, ``lateral`` m to the left, poses every 0.1 s for 5 s."""
    stamps = DECISION_NS + STEP_NS * np.arange(1, 51, dtype=np.int64)
    xs = 10.0 * (stamps - DECISION_NS) / 1e9
    return Plan(stamps, np.stack([xs, np.full(50, lateral)], axis=-1), np.zeros(50))


def _record(query_id: int, algorithm: str, loss: float, collision: float = 0.0, lateral: float = 0.0) -> QueryRecord:
    score = {"status": "ok", "adversarial_loss": loss, "collision_5s": collision, "detection_ap": 0.5}
    actors = () if algorithm == "original" else ("7",)
    return QueryRecord(query_id, algorithm, actors, (), score, plan=_plan(lateral))


def _summary(records: list[QueryRecord], best: QueryRecord) -> dict[str, object]:
    return {"original": dict(records[0].score), "adversarial": dict(best.score)}


def test_the_identity_controls_gap_is_what_re_simulation_alone_changes() -> None:
    records = [
        _record(0, "original", 10.0),
        _record(1, "bo", 30.0, collision=1.0, lateral=2.0),
        _record(2, "original", 10.0),
        _record(3, "identity", 11.0, lateral=0.6),
    ]
    result = controls(records, DECISION_NS)
    assert result["original"]["query_id"] == 0
    assert result["original"]["rerun_query_ids"] == [2]
    assert result["original_flaky"] is False
    assert result["identity"]["query_id"] == 3
    gap = result["sim_gap"]
    assert gap["adversarial_loss"] == 1.0
    assert gap["collision_5s"] == 0.0
    assert gap["detection_ap"] == 0.0
    assert np.isclose(gap["plan_l2_3s"], 0.6)
    assert np.isclose(gap["plan_l2_5s"], 0.6)
    found = finding(_summary(records, records[1]), result, {"reproduced": True})
    assert found is not None
    assert found["gain"] == 20.0
    assert found["sim_dominated"] is False  # 20 > 2 x 1
    assert found["excluded"] == []


def test_a_finding_within_the_margin_of_the_control_is_sim_dominated_and_a_flaky_original_is_said() -> None:
    records = [
        _record(0, "original", 10.0),
        _record(1, "bo", 10.0 + SIM_MARGIN * 3.0),
        _record(2, "original", 12.5),  # the unperturbed scenario scored differently when re-run
        _record(3, "identity", 13.0),
    ]
    result = controls(records, DECISION_NS)
    assert result["original_flaky"] is True
    found = finding(_summary(records, records[1]), result, {"reproduced": True})
    assert found is not None
    assert found["sim_dominated"] is True  # a gain of 6 does not exceed 2 x 3
    assert [reason.split(":")[0] for reason in found["excluded"]] == ["original_flaky", "sim_dominated"]


def test_a_collision_the_identity_control_already_has_is_sim_dominated() -> None:
    records = [
        _record(0, "original", 10.0),
        _record(1, "bo", 90.0, collision=1.0),
        _record(2, "identity", 10.5, collision=1.0),
    ]
    found = finding(_summary(records, records[1]), controls(records, DECISION_NS), None)
    assert found is not None
    assert found["sim_dominated"] is True
    assert found["reproduced"] is None  # no re-runs were asked for
    assert controls(records, DECISION_NS)["original"] is None


def test_plans_are_compared_only_where_both_reach() -> None:
    short = Plan(np.array([DECISION_NS + STEP_NS]), np.zeros((1, 2)), np.zeros(1))
    assert plan_gap(_plan(0.0), short, DECISION_NS, 3.0) is None
    assert plan_gap(_plan(0.0), None, DECISION_NS, 3.0) is None
    assert plan_gap(_plan(0.0), _plan(1.5), DECISION_NS, 5.0) == 1.5
