"""`advsim attack` and `advsim replay` as a Python API: check, launch the graph, follow it, journal, outputs.

    from advsim_ros.attack import AttackOptions, StackSpec, run_attack
    result = run_attack(AttackOptions(bag=Path("log.bag"), out_dir=Path("out"), stack=StackSpec.reference()))

Every node and the stack run as separate processes (own launcher; `ros2 launch` is not available
from the wheels) on a reserved ROS_DOMAIN_ID, DDS over shared memory only, tied to this process
(ros.launcher: nothing of the graph outlives it). This process follows the graph through a monitor
node and appends every finished query to OUTDIR/queries.jsonl (the journal) as it finishes.
Running the same attack again resumes from the journal: finished queries are replayed into the
search, not recomputed; a journal of another attack is refused. The outputs (attack.outputs) are
written from the journal alone.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import resource
import secrets
import shlex
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import yaml

from advsim_ros import graph
from advsim_ros.adapters.profile import StackProfile
from advsim_ros.attack.checks import Preflight, preflight
from advsim_ros.attack.options import AttackError, AttackOptions
from advsim_ros.attack.params import merge_parameters, node_files, node_parameters
from advsim_ros.core.atomic import write_json_atomically, write_text_atomically
from advsim_ros.core.attack_summary import AttackSummary, Resources, metric
from advsim_ros.core.digest import Digest
from advsim_ros.core.journal import Fingerprint, Journal
from advsim_ros.core.renamed import RENAMED_ALGORITHMS
from advsim_ros.core.search.registry import config_from_params
from advsim_ros.io.bag import bag_layout_json
from advsim_ros.io.cache import content_digest
from advsim_ros.ros.launcher import (
    Launcher,
    NodeSpec,
    graph_environment,
    join_graph,
    python_module_command,
    reserve_domain_id,
)
from advsim_ros.ros.trace import Trace

if TYPE_CHECKING:  # imported when used: `python -m advsim_ros.attack.outputs_worker` must find it not yet imported
    from advsim_ros.attack.outputs_worker import OutputsWorker

JOURNAL_NAME = "queries.jsonl"
LOCK_NAME = ".advsim.lock"  # held by the run using the folder (hold_output_folder)
CONTAINER = graph.Process.CONTAINER.value  # the process of the light nodes (nodes/container.py)
ADAPTER_PROFILE = "stack_profile.json"  # in OUTDIR/run: the profile stack_adapter works from
SEARCH = graph.SEARCH.name


@dataclass
class AttackResult:
    out_dir: Path
    summary: AttackSummary

    @property
    def best_adversarial_loss(self) -> float | None:
        best = self.summary.get("best")
        return None if best is None else metric(best["score"], "adversarial_loss")


def search_notes(options: AttackOptions) -> tuple[str, ...]:
    """What the attack's search settings (params/search.yaml, its budget, the user's overrides) warn about."""
    if options.replay_only:
        return ()
    overrides = _base_overrides(options, options.out_dir / JOURNAL_NAME)
    search = node_parameters(node_files(options.params, SEARCH), SEARCH, overrides)
    context = f"/{SEARCH} {options.algorithm}"
    return config_from_params(options.algorithm, search.get(options.algorithm, {}), context).notes()


def _base_overrides(options: AttackOptions, journal: Path) -> dict[str, Any]:
    """The attack's parameters on top of params/ (window start added once the window is chosen)."""
    overrides: dict[str, Any] = {
        "/**": {"ros__parameters": {"window": {"scenario_bag": str(options.bag.resolve())}}},
        f"/{graph.SCENARIO_PLAYER.name}": {
            "ros__parameters": {"plan_timeout": options.plan_timeout, "loop": options.loop}
        },
        # closed loop renders sweeps from where the ego drove: the model is needed even when nothing moves
        f"/{graph.LIDAR_RESIM.name}": {
            "ros__parameters": {
                "build_model": not options.replay_only or options.loop == "closed",
                "history_sweeps_only": options.loop == "open",  # open loop requests no later frame
            }
        },
    }
    if options.bag_config is not None:  # --bag-params: every node reads and publishes the bag's layout
        overrides["/**"]["ros__parameters"]["bag"] = bag_layout_json(options.bag_config)
    if not options.replay_only:
        overrides[f"/{graph.PERTURBER.name}"] = {"ros__parameters": {"num_actors": options.actors}}
        overrides[f"/{SEARCH}"] = {
            "ros__parameters": {
                "algorithm": options.algorithm,
                "seed": options.seed,
                "journal_file": str(journal),
                "reruns": options.reruns,
                "rerun_top": options.rerun_top,
                "perturbation_readers": 2,  # the perturber and this process's monitor (per lane)
                options.algorithm: {"max_queries": options.queries},
            }
        }
        search = overrides[f"/{SEARCH}"]["ros__parameters"]
        filed = node_parameters(node_files(options.params, SEARCH), SEARCH)
        for old, new in RENAMED_ALGORITHMS.items():  # a params folder of before a rename: the section as named now
            if new == options.algorithm and isinstance(filed.get(old), dict):  # (checks.preflight warns)
                search[new] = {**filed[old], **filed.get(new, {}), **search[new]}
    player = overrides[f"/{graph.SCENARIO_PLAYER.name}"]["ros__parameters"]
    if options.reactive_actors:
        player["reactive_actors"] = True
    if options.stack.relayed():  # the stack keeps its own topic names: stack_adapter bridges them
        player["stack_topics"] = _pairs(options.stack.relayed())
    profile = options.stack.profile
    if profile is not None and profile.timing.timer:  # a stack planning on its own timer: /clock is stepped
        player.update(
            clock_step=profile.timing.clock_step,
            real_time_factor=profile.timing.real_time_factor,
            wait_for_every_plan=False,
            await_relay=options.stack.adapter_profile() is not None,
        )
    for node, values in options.parameter_overrides.items():
        # nested: the user's search.bo.initial_points must not drop bo.max_queries set from --queries above
        entry = overrides.setdefault(f"/{node}", {"ros__parameters": {}})["ros__parameters"]
        merge_parameters(entry, json.loads(json.dumps(values)))
    return overrides


def _pairs(mapping: dict[str, str]) -> list[str]:
    return [f"{source}:={target}" for source, target in sorted(mapping.items())]


def _fingerprint(options: AttackOptions, checked: Preflight) -> Fingerprint:
    """Everything that makes this attack this attack (not the run id, not the output folder)."""
    params = Digest("attack parameters")
    for node in sorted(checked.files):
        for path in checked.files[node]:
            params.text(path.name)
            params.raw(path.read_bytes())
    # the rest of the overrides repeats options named below; the user's own overrides count here
    params.text(json.dumps(options.parameter_overrides, sort_keys=True, default=str))
    params.text(f"plan_timeout={options.plan_timeout}")
    bag = Digest("scenario bag")
    bag.raw((checked.bag / "metadata.yaml").read_bytes())
    stack = Digest("stack")
    for path in options.stack.params_files:
        stack.raw(path.read_bytes() if path.exists() else b"")
    adapter = options.stack.adapter_profile()
    if adapter is not None:
        stack.text(json.dumps(_adapter_identity(adapter), sort_keys=True))
    processes = options.stack.processes()
    if any(process.cwd or process.env for process in processes):  # digested: env values may be secrets
        stack.text(json.dumps(_environments(processes), sort_keys=True))
    return Fingerprint(
        {
            # not its path: the same bag elsewhere (a node's cache) resumes
            "bag": f"content:{content_digest(checked.bag)}",
            "bag_metadata": bag.hexdigest(),
            "window_start_frame": checked.window.window_start_frame,
            "stack": " ".join(options.stack.command),
            "stack_remappings": dict(sorted(options.stack.remappings.items())),
            # the other processes of a stack of several (absent otherwise: journals from before resume)
            **({"stack_processes": [shlex.join(p.command) for p in processes[1:]]} if len(processes) > 1 else {}),
            "stack_parameters": stack.hexdigest(),
            "mode": "replay" if options.replay_only else "attack",
            **({"loop": options.loop} if options.loop != "open" else {}),  # open-loop journals of before resume
            **({"reactive_actors": True} if options.reactive_actors else {}),  # and non-reactive ones
            "algorithm": options.algorithm,
            "seed": options.seed,
            "queries": options.queries,
            "actors": options.actors,
            "reruns": options.reruns,
            "rerun_top": options.rerun_top,
            "replay_runs": options.replay_runs,
            "parameters": params.hexdigest(),
            # the layout --bag-params gave (absent without: journals from before resume)
            **({"bag_params": bag_layout_json(options.bag_config)} if options.bag_config is not None else {}),
        },
        former={"bag": str(checked.bag)},  # journals of before: the bag's path
    )


def _adapter_identity(adapter: StackProfile) -> dict[str, Any]:
    """The adapter profile as the fingerprint takes it: not where its file lies, and processes without the
    cwd and env keys when they are unset (fingerprinted apart; journals from before they existed resume)."""
    values: dict[str, Any] = {**json.loads(adapter.to_json()), "folder": ""}
    values["processes"] = [
        {key: value for key, value in process.items() if not (key in ("cwd", "env") and not value)}
        for process in values["processes"]
    ]
    return values


def _environments(processes: Sequence[NodeSpec]) -> dict[str, Any]:
    """Each process's working folder and extra environment (they can change what a stack does)."""
    return {p.name: {"cwd": str(p.cwd or ""), "env": dict(sorted(p.env.items()))} for p in processes}


def run_attack(options: AttackOptions, progress: Callable[[dict[str, Any]], None] | None = None) -> AttackResult:
    """Run the whole attack (or the replay), resuming from OUTDIR's journal; write its outputs."""
    out_dir = options.out_dir.resolve()
    journal_path = out_dir / JOURNAL_NAME
    overrides = _base_overrides(options, journal_path)
    checked = preflight(options, overrides)
    overrides["/**"]["ros__parameters"]["window"]["window_start_frame"] = checked.window.window_start_frame
    fingerprint = _fingerprint(options, checked)
    with hold_output_folder(out_dir):
        return _run_locked(options, checked, overrides, fingerprint, progress)


@contextlib.contextmanager
def hold_output_folder(out_dir: Path) -> Iterator[None]:
    """One attack per output folder: an flock on OUTDIR/.advsim.lock for as long as this attack runs.

    The kernel drops the lock however this process ends (kill -9 included), so a crashed attack
    never leaves the folder locked; a second attack on a folder in use is refused with its pid.
    """
    if out_dir.exists() and not out_dir.is_dir():
        raise AttackError(f"{out_dir}: exists and is not a folder; give -o a folder (it is created if missing)")
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as error:  # a parent that is a file, no permission: one line, not an errno
        raise AttackError(f"{out_dir}: cannot create the output folder ({error.strerror})") from None
    fd = os.open(out_dir / LOCK_NAME, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "unknown"
            raise AttackError(
                f"{out_dir} is in use by another advsim run (pid {holder}); wait for it to end or use another "
                "output folder"
            ) from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        yield
    finally:
        os.close(fd)  # releases the lock


def _run_locked(
    options: AttackOptions,
    checked: Preflight,
    overrides: dict[str, Any],
    fingerprint: Fingerprint,
    progress: Callable[[dict[str, Any]], None] | None,
) -> AttackResult:
    out_dir = options.out_dir.resolve()
    journal = Journal.open(out_dir / JOURNAL_NAME, fingerprint)
    started = time.monotonic()
    trace = Trace("advsim_attack")
    trace("checked")
    from advsim_ros.attack.outputs import write_outputs  # open3d: not before the graph runs
    from advsim_ros.attack.outputs_worker import OutputsWorker

    if journal.finished:  # only the outputs are left to write
        trace("graph_done")
        records, wall_time = journal.records, time.monotonic() - started
        summary = write_outputs(options, checked, records, journal.path, wall_time, [], None, lambda: _resources({}))
    else:
        overrides_file = out_dir / "run" / "overrides.yaml"
        write_text_atomically(overrides_file, yaml.safe_dump(overrides, sort_keys=False))
        worker = OutputsWorker(options, checked, out_dir / "run" / "logs" / "outputs.log")
        try:
            summary = _run_graph(options, checked, overrides_file, journal, progress, worker, started, trace)
        finally:
            worker.close()
    trace("outputs_written")
    return AttackResult(out_dir, summary)


def _resources(used: dict[str, dict[str, float]]) -> Resources:
    """summary.json's "resources": the graph's processes (none when the journal was finished before) and this one."""
    return {
        "processes": used,
        "graph_peak_rss_mb": sum(item["peak_rss_mb"] for item in used.values()),
        "graph_cpu_s": sum(item["cpu_s"] for item in used.values()),
        "orchestrator_peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
    }


def _run_graph(
    options: AttackOptions,
    checked: Preflight,
    overrides_file: Path,
    journal: Journal,
    progress: Callable[[dict[str, Any]], None] | None,
    worker: OutputsWorker,
    started: float,
    trace: Trace,
) -> AttackSummary:
    """Launch the graph (one per evaluation lane, each on a ROS domain of its own), follow it to the end and have
    the worker write the outputs (the bag while the graph's processes end); returns the summary."""
    from advsim_ros.attack.follow import Lane, follow
    from advsim_ros.attack.outputs_worker import OutputsWorkerLostError
    from advsim_ros.ros.lockstep import StackNames
    from advsim_ros.ros.monitor import AttackMonitor  # rclpy only once the graph's environment is set

    run_id = secrets.randbelow(2**63 - 1) + 1
    run_dir = options.out_dir.resolve() / "run"
    skip = frozenset(record.query_id for record in journal.records)
    with contextlib.ExitStack() as resources:
        leases = [resources.enter_context(reserve_domain_id()) for _ in range(options.lanes)]
        domains = [lease.domain_id for lease in leases]
        join_graph(domains[0])  # the monitors in this process use the same transports
        # for people who want to look at the live graph
        write_text_atomically(run_dir / "graph.json", json.dumps({"ros_domain_id": domains[0], "run_id": run_id}))
        lanes_file = None
        if len(domains) > 1:  # the search's other lanes (an empty list would reach ROS untyped)
            lanes_file = run_dir / "lanes.yaml"
            write_text_atomically(
                lanes_file, yaml.safe_dump({f"/{SEARCH}": {"ros__parameters": {"lane_domains": domains[1:]}}})
            )
        lanes = []
        for index, lease in enumerate(leases):
            log_dir = run_dir / "logs" if index == 0 else run_dir / "logs" / f"lane{index}"
            specs = _graph_specs(options, checked, overrides_file, lanes_file, run_id, search=index == 0)
            stack = options.stack.processes()
            # each lane's processes carry a marker of their own (ros.identity): the lane's publishers, its reaper's prey
            launcher = resources.enter_context(Launcher(graph_environment(lease.domain_id), log_dir, lease))
            names = StackNames(graph.NAMES, options.stack.relayed())
            monitor = resources.enter_context(
                AttackMonitor(run_id, names, graph.MONITOR.name, skip, lease.domain_id, index)
            )
            for process in (*stack, *specs):
                launcher.start(process)
            trace("launched")
            lanes.append(Lane(launcher, monitor, stack, specs))
        crashes = follow(options, checked, lanes, journal, progress, worker.journaled)
        used = {
            name if index == 0 else f"lane{index}/{name}": figures
            for index, lane in enumerate(lanes)
            for name, figures in lane.launcher.resources().items()
        }
        trace("graph_done")
        worker.start_writing(journal.records, journal.path, time.monotonic() - started, crashes, domains[0])
    try:  # the graph's processes have ended meanwhile
        summary, worker_peak_mb, worker_cpu_s = worker.finish(_resources(used))
    except OutputsWorkerLostError:  # written here instead (the same files)
        from advsim_ros.attack.outputs import write_outputs

        return write_outputs(
            options, checked, journal.records, journal.path, time.monotonic() - started, crashes, domains[0],
            lambda: _resources(used),
        )  # fmt: skip
    summary["resources"]["outputs_peak_rss_mb"] = worker_peak_mb  # the worker's own figures, known only now
    summary["resources"]["outputs_cpu_s"] = worker_cpu_s
    write_json_atomically(options.out_dir.resolve() / "summary.json", summary)
    return summary


def _graph_specs(
    options: AttackOptions,
    checked: Preflight,
    overrides_file: Path,
    lanes_file: Path | None,
    run_id: int,
    search: bool,
) -> list[NodeSpec]:
    """The graph's own processes (the stack aside); the search only in the first lane."""
    role = graph.Role.REPLAY if options.replay_only else graph.Role.SEARCH if search else graph.Role.LANE
    light = [node.name for node in graph.started(role, graph.Process.CONTAINER)]
    container_files = list(dict.fromkeys(path for name in light for path in checked.files[name]))
    specs = [
        NodeSpec(
            CONTAINER,
            python_module_command("advsim_ros.nodes.container", *light),
            params_files=(*container_files, overrides_file, *((lanes_file,) if search and lanes_file else ())),
            parameters={"run_id": run_id},
            rename_node=False,  # each node keeps its own name
        ),
        *(
            NodeSpec(
                node.name,  # lidar_resim: it computes while the others wait
                python_module_command(node.module),
                params_files=(*checked.files[node.name], overrides_file),
                parameters={"run_id": run_id},
            )
            for node in graph.started(role, graph.Process.OWN)
        ),
    ]
    adapter = options.stack.adapter_profile()
    if adapter is not None:
        profile_file = options.out_dir.resolve() / "run" / ADAPTER_PROFILE
        write_text_atomically(profile_file, adapter.to_json())
        specs.append(
            NodeSpec(
                graph.STACK_ADAPTER.name,
                python_module_command(graph.STACK_ADAPTER.module),
                parameters={"run_id": run_id, "profile_file": str(profile_file)},
            )
        )
    return specs
