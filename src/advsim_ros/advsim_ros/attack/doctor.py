"""`advsim doctor`: how a stack connects to the contract, found by running it on one window of a bag.

The stack is started with the graph as `advsim replay` starts it (the window's own scenario,
nothing perturbed, one run) and then described from what really happened: its nodes and, for
every topic of the contract, the endpoint the stack has for it (under the contract's name or the
one given with --remap), its type and QoS and whether they fit what the graph offers or expects;
whether a plan came back for every sweep; how long the stack took per sweep (from the graph's
trace); and, when something is not connected, the --remap lines that would connect it (the
stack's topics of the right type and direction that are not the contract's).
"""

from __future__ import annotations

import dataclasses
import json
import os
import statistics
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from advsim_ros.adapters.messages import PLAN_MSGTYPES, POSE_MSGTYPES
from advsim_ros.attack.follow import STACK_GRAPH_FILE, stack_log_tails
from advsim_ros.attack.options import AttackError, AttackOptions
from advsim_ros.attack.run import run_attack
from advsim_ros.attack.suggestion import ADAPTED_TYPES, suggested_profile
from advsim_ros.contract import topics
from advsim_ros.contract.qos import Durability, Reliability
from advsim_ros.contract.topics import TopicSpec
from advsim_ros.core.attack_summary import AttackSummary, Score

REQUIRED = (topics.LIDAR, topics.PLAN)  # without these nothing can be attacked
SUGGESTED_PROFILE = "suggested_profile.yaml"


@dataclass(frozen=True)
class TopicRow:
    """One contract topic as the stack has it."""

    contract: str
    direction: str  # "in" (the graph publishes, the stack reads) or "out" (the stack answers)
    stack_topic: str  # the name the stack was looked for under
    found: str  # the stack's node(s) with an endpoint there, "" when none
    stack_type: str
    stack_qos: str
    verdict: str  # "ok", "MISSING", "not used", "wrong type: ...", "QoS: ..."


@dataclass(frozen=True)
class DoctorReport:
    nodes: list[dict[str, Any]]  # ros.introspect.stack_graph
    rows: list[TopicRow]
    suggestions: list[str]  # --remap lines that would connect what is missing
    error: str  # why the replay did not complete ("" when it did)
    sweeps_delivered: int
    plans_received: int
    stack_ms_median: float | None  # per sweep: from the sweep sent to its plan back [ms]
    out_dir: Path
    timer: bool = False  # the profile says the stack plans on its own timer (only the decision plan is awaited)
    profile: dict[str, Any] | None = None  # a suggested stack profile (written to OUTDIR/suggested_profile.yaml)
    plan_problem: str = ""  # why the decision plan could not be scored ("" when it was)
    notes: tuple[str, ...] = ()  # what the suggested profile chose, or leaves for the user to fill in
    log_tails: tuple[str, ...] = ()  # no plan came: the last lines of each stack process's log

    @property
    def ok(self) -> bool:
        """The stack answered every sweep of the window with a plan (a timer-driven one: the decision sweep), and
        the decision plan is one the scorer can use (finite, non-empty, increasing stamps, in the world frame)."""
        wanted = 1 if self.timer else self.sweeps_delivered
        answered = self.sweeps_delivered > 0 and self.plans_received >= wanted > 0
        return not self.error and answered and not self.plan_problem

    def as_text(self) -> str:
        lines = [f"{'contract topic':<24} {'dir':<4} {'stack topic':<28} {'type':<34} {'QoS':<26} verdict"]
        for row in self.rows:
            lines.append(
                f"{row.contract:<24} {row.direction:<4} {row.stack_topic:<28} {row.stack_type or '-':<34} "
                f"{row.stack_qos or '-':<26} {row.verdict}"
            )
        lines.append("")
        for node in self.nodes:
            lines.append(f"stack node {node['node']}: subscribes {[e['topic'] for e in node['subscribes']]}")
            lines.append(f"{'':>11}{'':<{len(node['node'])}}  publishes  {[e['topic'] for e in node['publishes']]}")
        if not self.nodes:
            lines.append("no node of the stack appeared on the ROS graph")
        if self.sweeps_delivered:
            timing = f", {self.stack_ms_median:.0f} ms per sweep (median)" if self.stack_ms_median is not None else ""
            lines.append(f"plans: {self.plans_received} of {self.sweeps_delivered} sweeps answered{timing}")
            if self.timer:
                lines.append("  the profile says the stack plans on its own timer: the decision sweep's plan counts")
            elif self.plans_received < self.sweeps_delivered:
                lines.append(
                    "  the contract wants one nav_msgs/Path per sweep with header.stamp = the sweep's stamp; a stack "
                    "planning on its own timer: a stack profile with timing: {mode: timer}"
                )
        if self.plan_problem:
            lines.append(f"plan: not usable: {self.plan_problem}")
        if self.error:
            lines.append(f"replay: {self.error}")
        if self.suggestions:
            lines.append("to connect it, try: " + " ".join(self.suggestions))
        if self.profile is not None and not self.ok:
            lines.append(f"a stack profile that would connect it ({self.out_dir / SUGGESTED_PROFILE}):")
            lines.extend("  " + line for line in yaml.safe_dump(self.profile, sort_keys=False).splitlines())
        lines.extend(f"  note: {note}" for note in self.notes)
        lines.append(f"verdict: {'ready to attack' if self.ok else 'NOT ready'} (details in {self.out_dir})")
        lines.extend(self.log_tails)
        return "\n".join(lines)


def _qos_text(qos: dict[str, Any] | None) -> str:
    return "" if qos is None else f"{qos['reliability']}, {qos['durability']}"  # depth is not on the graph


def _qos_problem(spec: TopicSpec, direction: str, qos: dict[str, Any] | None) -> str:
    """Why the stack's endpoint and the graph's do not match ("" when they do)."""
    if qos is None:
        return ""
    offered = spec.offered
    if direction == "in":  # the graph offers, the stack requests
        if qos["reliability"] == "reliable" and offered.reliability is not Reliability.RELIABLE:
            return "QoS: requests reliable, the graph offers best effort"
        if qos["durability"] == "transient_local" and offered.durability is not Durability.TRANSIENT_LOCAL:
            return "QoS: requests transient local, the graph offers volatile"
        return ""
    # the stack offers, the graph requests
    if offered.reliability is Reliability.RELIABLE and qos["reliability"] != "reliable":
        return "QoS: offers best effort, the graph requests reliable"
    return ""


def topic_rows(
    nodes: list[dict[str, Any]],
    renamed: dict[str, str],
    expected: dict[str, str] | None = None,
    best_effort: frozenset[str] = frozenset(),
) -> list[TopicRow]:
    """The stack's endpoint for every contract topic; ``expected``: types a profile adapts (contract topic -> type)."""
    expected = expected or {}
    rows = []
    for spec in topics.STACK_TOPICS:
        direction = "in" if spec in topics.STACK_INPUTS else "out"
        name = renamed.get(spec.name, spec.name)
        side = "subscribes" if direction == "in" else "publishes"
        hits = [(node["node"], endpoint) for node in nodes for endpoint in node[side] if endpoint["topic"] == name]
        if not hits:
            verdict = "MISSING" if spec in REQUIRED else "not used"
            rows.append(TopicRow(spec.name, direction, name, "", "", "", verdict))
            continue
        endpoint = hits[0][1]
        wanted = expected.get(spec.name, spec.msgtype)
        if endpoint["type"] != wanted:
            adapted = ADAPTED_TYPES.get(spec.name, {})
            adaptable = [key for key, msgtype in adapted.items() if msgtype == endpoint["type"]]
            hint = f" (a profile adapts it: type {' or '.join(adaptable)})" if adaptable else ""
            verdict = f"wrong type: expected {wanted}{hint}"
        else:
            adapted_qos = spec.name in best_effort  # the profile says it publishes best effort: read so
            verdict = ("" if adapted_qos else _qos_problem(spec, direction, endpoint["qos"])) or "ok"
        found = ", ".join(sorted({node for node, _ in hits}))
        rows.append(TopicRow(spec.name, direction, name, found, endpoint["type"], _qos_text(endpoint["qos"]), verdict))
    return rows


def suggestions(nodes: list[dict[str, Any]], rows: list[TopicRow]) -> list[str]:
    """--remap CONTRACT:=YOURS for every missing topic the stack has under another name with the right type."""
    contract_names = {spec.name for spec in topics.STACK_TOPICS}
    found = []
    for row in rows:
        if row.found:
            continue
        spec = topics.stack_topic(row.contract)
        side = "subscribes" if row.direction == "in" else "publishes"
        candidates = sorted(
            {
                endpoint["topic"]
                for node in nodes
                for endpoint in node[side]
                if endpoint["type"] == spec.msgtype and endpoint["topic"] not in contract_names
            }
        )
        if len(candidates) == 1:
            found.append(f"--remap {row.contract}:={candidates[0]}")
    return found


def _stack_ms(trace_dir: Path) -> float | None:
    from advsim_ros.ros.trace import read_trace

    at: dict[tuple[str, int], float] = {}
    for stamp, _, event, _, frame in read_trace(trace_dir):
        at.setdefault((event, frame), stamp)
    waits = [
        1e3 * (at[("plan_seen", frame)] - at[("sweep_sent", frame)])
        for (event, frame) in at
        if event == "sweep_sent" and ("plan_seen", frame) in at
    ]
    return statistics.median(waits) if waits else None


def run_doctor(options: AttackOptions) -> DoctorReport:
    """Replay the window once with the stack and describe how it connected (AttackOptions as for replay)."""
    from advsim_ros.ros.trace import TRACE_ENV

    options = dataclasses.replace(options, replay_only=True, replay_runs=1, queries=0)
    out_dir = options.out_dir.resolve()
    trace_dir = out_dir / "run" / "trace"
    previous = os.environ.get(TRACE_ENV)
    os.environ[TRACE_ENV] = str(trace_dir)
    error = ""
    summary: AttackSummary | None = None
    try:
        summary = run_attack(options).summary
    except AttackError as failure:
        error = str(failure)
    finally:
        if previous is None:
            os.environ.pop(TRACE_ENV, None)
        else:
            os.environ[TRACE_ENV] = previous
    graph_file = out_dir / "run" / STACK_GRAPH_FILE
    nodes: list[dict[str, Any]] = json.loads(graph_file.read_text()) if graph_file.exists() else []
    profile = options.stack.profile
    expected = {}
    if profile is not None:
        expected[topics.ODOM.name] = POSE_MSGTYPES[profile.inputs.pose.type]
        expected[topics.PLAN.name] = PLAN_MSGTYPES[profile.outputs.plan.type]
    best_effort: frozenset[str] = frozenset()
    if profile is not None:
        outputs = profile.outputs
        answers = ((topics.PLAN, outputs.plan), (topics.DETECTIONS, outputs.detections),
                   (topics.PREDICTIONS, outputs.predictions))  # fmt: skip
        best_effort = frozenset(spec.name for spec, output in answers if output.reliability == "best_effort")
    rows = topic_rows(nodes, options.stack.relayed(), expected, best_effort)  # renamed (rename mode): the contract's
    queries = summary["queries"] if summary is not None else []
    score: Score = queries[0]["score"] if queries else {}
    timer = profile is not None and profile.timing.timer
    plans, sweeps = int(score.get("plans_received") or 0), int(score.get("sweeps_delivered") or 0)
    # a plan came back but could not be scored (NaN, empty, stamps, frame): the scorer's reason
    plan_problem = str(score.get("message") or score.get("status")) if plans and score.get("status") != "ok" else ""
    seen_timer = timer or (0 < plans < sweeps)  # answers some sweeps, not each: planning on a timer
    suggestion, notes = suggested_profile(nodes, options.stack, seen_timer)
    if nodes:
        from advsim_ros.core.atomic import write_text_atomically

        write_text_atomically(out_dir / SUGGESTED_PROFILE, yaml.safe_dump(suggestion, sort_keys=False))
    return DoctorReport(
        timer=timer,
        profile=suggestion if nodes else None,
        notes=tuple(notes) if nodes else (),
        # why no plan came is often only in the stack's own output (a file it did not find, a traceback)
        log_tails=tuple(stack_log_tails(out_dir, options.stack)) if plans == 0 else (),
        nodes=nodes,
        rows=rows,
        suggestions=suggestions(nodes, rows),
        error=error,
        sweeps_delivered=sweeps,
        plans_received=plans,
        stack_ms_median=_stack_ms(trace_dir) if trace_dir.is_dir() else None,
        out_dir=out_dir,
        plan_problem=plan_problem,
    )
