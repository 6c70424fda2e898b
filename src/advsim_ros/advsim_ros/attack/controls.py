"""Reading a finding: the attack's controls and whose failure the found scenario shows.

Every attack evaluates, besides its search, two controls (core.search.driver):
- the original again (``--reruns`` times): an original that does not reproduce makes every
  comparison with it unreliable (``original_flaky``);
- the identity control: the perturbed actors re-inserted on their own logged tracks through the
  same re-simulation a perturbed actor gets. Its differences from the real original, ``sim_gap``,
  are what the simulator alone does to the stack.

A finding (the recorded query) is ``sim_dominated`` when its gain over the original does not exceed
SIM_MARGIN times the identity control's deviation from the original, or when it is a collision and
the identity control alone already collides where the original does not. Every colliding query
gets its fault and avoidability (core.fault): could an ego within its limits have avoided every
actor, and who moved into whom at the first contact. A finding counts as the stack's failure when
it is a collision that reproduced, of an original that reproduced, not sim-dominated, and
avoidable. docs/attack.md, "Reading a finding".
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from advsim_ros.attack.summary import Reproduction
from advsim_ros.contract.plan import PLAN_STEP_NS
from advsim_ros.core.attack_summary import AttackAnalysis, ControlsRecord, FindingRecord, ReproductionRecord, metric
from advsim_ros.core.closed_loop import executed_as_plan
from advsim_ros.core.fault import FaultRecord, classify_collision
from advsim_ros.core.journal import QueryRecord
from advsim_ros.core.metrics import MetricsConfig
from advsim_ros.core.search.driver import IDENTITY, ORIGINAL
from advsim_ros.core.types import DrivableArea, Plan, Scenario

SIM_MARGIN = 2.0  # a finding must gain more than this many times what re-simulation alone moves L_adv
PLAN_GAP_AT_S = (3.0, 5.0)  # where the two plans of the controls are compared [s after the decision]


def _finite(value: object) -> float | None:
    return float(value) if isinstance(value, int | float) and math.isfinite(value) else None


def plan_gap(first: Plan | None, second: Plan | None, decision_ns: int, after_s: float) -> float | None:
    """Distance between two plans' positions ``after_s`` after the decision [m] (None when either lacks it)."""
    at = decision_ns + round(after_s * 1e9)
    points = []
    for plan in (first, second):
        if plan is None or not plan.stamps_ns[0] <= at <= plan.stamps_ns[-1]:
            return None
        points.append([np.interp(at, plan.stamps_ns, plan.xy[:, axis]) for axis in (0, 1)])
    return float(np.hypot(points[0][0] - points[1][0], points[0][1] - points[1][1]))


def sim_gap(original: QueryRecord, identity: QueryRecord, decision_ns: int) -> dict[str, float | None]:
    """What re-simulating the perturbed actors where they were changes: identity control minus the original."""

    def difference(key: str) -> float | None:
        values = [_finite(record.score.get(key)) for record in (identity, original)]
        return None if values[0] is None or values[1] is None else values[0] - values[1]

    return {
        "adversarial_loss": difference("adversarial_loss"),
        "collision_5s": difference("collision_5s"),
        "detection_ap": difference("detection_ap"),
        **{f"plan_l2_{s:.0f}s": plan_gap(original.plan, identity.plan, decision_ns, s) for s in PLAN_GAP_AT_S},
    }


def controls(records: Sequence[QueryRecord], decision_ns: int) -> ControlsRecord:
    """The controls' part of summary.json: the original's re-runs, the identity control, their sim gap."""
    originals = tuple(sorted((r for r in records if r.algorithm == ORIGINAL), key=lambda r: r.query_id))
    identity = next((r for r in records if r.algorithm == IDENTITY), None)
    original = Reproduction(originals[0].query_id, originals).as_json() if len(originals) > 1 else None
    gap = None
    if originals and identity is not None and originals[0].ok and identity.ok:
        gap = sim_gap(originals[0], identity, decision_ns)
    return {
        "original": original,
        "original_flaky": None if original is None else not original["reproduced"],
        "identity": None if identity is None else {"query_id": identity.query_id, "score": dict(identity.score)},
        "sim_gap": gap,
    }


def query_faults(
    records: Sequence[QueryRecord],
    scenario: Scenario,
    decision_frame: int,
    metrics: MetricsConfig,
    drivable: DrivableArea | None,
) -> dict[int, FaultRecord]:
    """Fault and avoidability of every colliding query, by query id (closed loop: of what the ego drove)."""
    decision_ns = int(scenario.frame_stamps_ns[decision_frame])
    horizon_ns = round(max(metrics.horizons) * 1e9)
    faults = {}
    for record in records:
        if not record.ok or record.score.get("collision_5s") != 1.0 or record.plan is None:
            continue
        plan = record.plan
        if record.executed is not None:
            plan = executed_as_plan(record.executed, decision_ns, PLAN_STEP_NS, horizon_ns)
        fault = classify_collision(plan, scenario, record.tracks, decision_frame, metrics, drivable=drivable)
        if fault is not None:
            faults[record.query_id] = fault.as_json()
    return faults


def finding(
    summary: AttackAnalysis,
    control: ControlsRecord,
    reproduction: ReproductionRecord | None,
    fault: FaultRecord | None = None,
) -> FindingRecord | None:
    """What the recorded query shows and whether it counts as the stack's failure (None when nothing was found).

    ``fault``: the recorded query's fault and avoidability (query_faults), when it collides."""
    adversarial, original = summary.get("adversarial"), summary.get("original")
    if not adversarial or not original or adversarial.get("status") != "ok" or original.get("status") != "ok":
        return None
    gain = metric(adversarial, "adversarial_loss") - metric(original, "adversarial_loss")
    gap = control["sim_gap"]
    deviation = None if gap is None or gap["adversarial_loss"] is None else abs(gap["adversarial_loss"])
    collision = adversarial.get("collision_5s") == 1.0
    control_collides = gap is not None and gap["collision_5s"] == 1.0
    sim_dominated = None if deviation is None else gain <= SIM_MARGIN * deviation or (collision and control_collides)
    reproduced = None if reproduction is None else bool(reproduction["reproduced"])
    reasons = []
    if reproduced is False:
        reasons.append("flaky: the found scenario did not reproduce")
    if control["original_flaky"]:
        reasons.append("original_flaky: the unperturbed scenario did not reproduce")
    if sim_dominated:
        reasons.append(f"sim_dominated: gain {gain:.3g}, identity control {deviation:.3g} (margin {SIM_MARGIN:g})")
    if fault is not None and fault["class"] == "unavoidable":
        contact = fault["contact"]
        reasons.append(f"unavoidable: no ego within its limits escapes ({contact['mover']}, {contact['side']})")
    return {
        "collision": collision,
        "original_collides": original.get("collision_5s") == 1.0,
        "gain": gain,
        "control_deviation": deviation,
        "reproduced": reproduced,
        "original_flaky": control["original_flaky"],
        "sim_dominated": sim_dominated,
        "fault": fault,
        # the stack's failure: a collision that reproduced, of an original that did, not sim-dominated, avoidable
        "counts_as_failure": collision and not reasons,
        "excluded": reasons,
    }
