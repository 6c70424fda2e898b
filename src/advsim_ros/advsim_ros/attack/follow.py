"""Following a running attack graph: journal finished queries, restart a crashed stack, fail clearly.

The loop ends when the search says it is finished (/advsim/search_status) and every query it
asked for is journaled (replay mode: when every requested run is). It fails with one message
naming the cause when a node of the graph dies, when the stack never connects (with what the
stack does instead, read from the ROS graph), or when nothing progresses for too long.
With evaluation lanes (`--lanes K`) it follows every lane's graph the same way; the search and
its status live in the first.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from advsim_ros.attack.checks import Preflight
from advsim_ros.attack.options import AttackError, AttackOptions, StackSpec
from advsim_ros.contract.codec import ContractError
from advsim_ros.contract.plan import plan_from_path
from advsim_ros.core.atomic import write_text_atomically
from advsim_ros.core.attack_summary import StackCrash
from advsim_ros.core.closed_loop import ControllerConfig
from advsim_ros.core.journal import Journal, QueryRecord
from advsim_ros.ros.launcher import Launcher, NodeSpec
from advsim_ros.ros.monitor import AttackMonitor

_POLL = 0.1  # [s]
STACK_GRAPH_FILE = "stack_graph.json"  # in OUTDIR/run: the stack's nodes, topics, types and QoS


def _log_tail(path: Path, lines: int = 30) -> str:
    try:
        return "\n".join(path.read_text(errors="replace").splitlines()[-lines:])
    except OSError:
        return "(no log)"


def stack_log_tails(out_dir: Path, stack: StackSpec, lines: int = 10) -> list[str]:
    """The last lines of each stack process's log in OUTDIR/run/logs, under a line naming the log."""
    shown = []
    for process in stack.processes():
        log = out_dir / "run" / "logs" / f"{process.name}.log"
        tail = log.read_text(errors="replace").splitlines()[-lines:] if log.exists() else []
        shown.append(f"the last lines of the stack's log {log}:" if tail else f"the stack's log {log} is empty")
        shown.extend(f"  {line}" for line in tail)
    return shown


@dataclass(frozen=True)
class Lane:
    """One evaluation graph of the attack: its processes, its monitor, its stack."""

    launcher: Launcher
    monitor: AttackMonitor
    stack: Sequence[NodeSpec]  # the stack's processes
    graph: Sequence[NodeSpec]  # the graph's own processes


def _progress(lanes: Sequence[Lane], journaled: int) -> dict[str, Any]:
    """What the progress bar shows, over every lane."""
    merged = dict(vars(lanes[0].monitor.progress))
    each = [lane.monitor.progress for lane in lanes]
    best = [p.best_adversarial_loss for p in each if not math.isnan(p.best_adversarial_loss)]
    merged.update(
        scored=sum(p.scored for p in each),
        failed=sum(p.failed for p in each),
        best_adversarial_loss=max(best) if best else math.nan,
        query=max(p.query for p in each),
        journaled=journaled,
    )
    return merged


def follow(
    options: AttackOptions,
    checked: Preflight,
    lanes: Sequence[Lane],
    journal: Journal,
    progress: Callable[[dict[str, Any]], None] | None,
    on_journaled: Callable[[Sequence[QueryRecord]], None] | None = None,
) -> list[StackCrash]:
    """Spin the monitors until the attack is over; returns the stack's crashes (query, exit code).

    ``on_journaled`` is called with the journal's records whenever queries were journaled."""
    clock = checked.window.clock(checked.scenario.frame_stamps_ns.tolist())
    decision_log = int(
        checked.scenario.frame_stamps_ns[checked.window.window_start_frame + checked.window.decision_index]
    )

    def offset(query_id: int) -> int:
        return clock.to_sim(query_id, decision_log) - decision_log

    crashes: list[StackCrash] = []
    first = lanes[0]
    replay_next = len(journal.records) if options.replay_only else -1
    connected_once = graph_written = False
    started = last_change = time.monotonic()
    world_frame = checked.bag_config.world_frame
    if options.replay_only and replay_next < options.replay_runs:
        first.monitor.request_replay(replay_next, world_frame)
    while True:
        finished = []
        for lane in lanes:
            lane.monitor.spin_once(_POLL / len(lanes))
            finished.extend(lane.monitor.take_finished())
        for query in sorted(finished, key=lambda query: query.perturbation.query_id):
            journal.append(query_record(query, offset))
            first.monitor.node.trace("journaled", query.perturbation.query_id)
        if finished:
            last_change = time.monotonic()
            if on_journaled is not None:
                on_journaled(journal.records)
            if progress is not None:
                progress(_progress(lanes, len(journal)))
            if options.replay_only:
                replay_next = len(journal.records)
                if replay_next < options.replay_runs:
                    first.monitor.request_replay(replay_next, world_frame)
        for lane in lanes:
            _check_processes(options, lane, connected_once, crashes)
        if options.replay_only and len(journal.records) >= options.replay_runs:
            break
        # over when the journal holds every query the search made: the status may overtake pieces of the last
        # queries that the writers are still re-sending to a monitor that fell behind (a starved or suspended process)
        searched = first.monitor.search_finished and len(journal) >= first.monitor.search_queries
        if searched and not options.replay_only and all(lane.monitor.idle() for lane in lanes):
            break
        now = time.monotonic()
        if connected_once and not graph_written:  # node names come after the endpoints: wait for them
            graph_written = _write_stack_graph(options, first.monitor, final=False)
        if not connected_once:
            connections = [lane.monitor.stack_connection() for lane in lanes]
            connected_once = all(connected for connected, _ in connections)
            if not connected_once and now - started > options.connect_timeout:
                _write_stack_graph(options, first.monitor, final=True)
                missing = "; ".join(
                    f"{'' if len(lanes) == 1 else f'lane {index}: '}{text}"
                    for index, (connected, text) in enumerate(connections)
                    if not connected
                )
                raise AttackError(
                    f"the stack did not connect within {options.connect_timeout:.0f} s: {missing}; "
                    f"stack log: {first.launcher.log_path(first.stack[0].name)}"
                )
        limit = options.startup_timeout if len(journal) == 0 else options.query_timeout
        if now - last_change > limit:
            lacking = "; ".join(text for text in (lane.monitor.missing() for lane in lanes) if text)
            raise AttackError(
                f"no query finished for {limit:.0f} s ({len(journal)} journaled"
                f"{f'; still missing: {lacking}' if lacking else ''}); logs in {first.launcher.log_dir}"
            )
    if not graph_written:
        _write_stack_graph(options, first.monitor, final=True)
    journal.mark_finished()
    return crashes


def _check_processes(options: AttackOptions, lane: Lane, connected_once: bool, crashes: list[StackCrash]) -> None:
    """Fail when a node of the lane's graph died; restart its stack when the stack did (or fail)."""
    graph_names = {spec.name for spec in lane.graph}
    stack_processes = {spec.name: spec for spec in lane.stack}
    launcher, monitor = lane.launcher, lane.monitor
    for name, code in launcher.exited().items():
        if name in graph_names:
            log = launcher.log_path(name)
            raise AttackError(f"node {name} exited with code {code}; its log ({log}):\n{_log_tail(log)}")
        elif name in stack_processes:
            log = launcher.log_path(name)
            if not connected_once:
                raise AttackError(
                    f"the stack exited with code {code} before it connected; its log ({log}):\n{_log_tail(log, 10)}"
                )
            crashes.append({"query_id": monitor.progress.query, "exit_code": code})
            launcher.stop(name)
            if not options.stack.restart:
                raise AttackError(f"the stack exited with code {code} during query {monitor.progress.query}")
            launcher.start(stack_processes[name])


def _write_stack_graph(options: AttackOptions, monitor: AttackMonitor, final: bool) -> bool:
    """OUTDIR/run/stack_graph.json: what the stack is on the graph (people, `advsim doctor`); True once written."""
    graph = monitor.stack_graph()
    if graph or final:
        write_text_atomically(options.out_dir.resolve() / "run" / STACK_GRAPH_FILE, json.dumps(graph, indent=1))
    return bool(graph) or final


def query_record(finished: Any, clock_offset: Callable[[int], int]) -> QueryRecord:
    """The journal line of a finished query (plan moved to log time)."""
    plan = executed = None
    reacted: tuple[Any, ...] = ()
    episode = finished.episode
    offset = clock_offset(finished.perturbation.query_id)
    if episode is not None and episode.decision_plan is not None:
        try:
            plan = plan_from_path(episode.decision_plan, offset)
        except ContractError:
            plan = None
    if episode is not None and episode.executed is not None:
        executed = episode.executed.to_executed(ControllerConfig().wheelbase, offset)
    if episode is not None:
        reacted = tuple(track.shifted(-offset).to_actor_track() for track in episode.reacted_actors)
    perturbation = finished.perturbation
    return QueryRecord(
        query_id=perturbation.query_id,
        algorithm=perturbation.algorithm,
        actor_ids=tuple(perturbation.actor_ids),
        delta=tuple(float(v) for v in perturbation.delta),
        score=finished.score.as_dict(),
        tracks=tuple(finished.tracks),
        plan=plan,
        executed=executed,
        reacted=reacted,
    )
