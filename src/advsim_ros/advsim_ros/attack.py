"""`advsim attack` and `advsim replay` as a Python API: start the graph, follow it, write the outputs.

    from advsim_ros.attack import AttackOptions, StackSpec, run_attack
    result = run_attack(AttackOptions(bag=Path("log.bag"), out_dir=Path("out"), stack=StackSpec.reference()))

Every node and the stack run as separate processes (own launcher; `ros2 launch` is not available
from the wheels) on an isolated ROS_DOMAIN_ID with discovery on loopback. This process follows
the graph through a small monitor node: it shows progress with the best L_adv so far, restarts a
stack that crashed (when configured), records the best query's replay, and writes
OUTDIR/adversarial (a scenario bag), OUTDIR/summary.json and OUTDIR/bev.png. Finished queries are
kept in OUTDIR/queries.jsonl as they finish: running again with the same OUTDIR resumes there.
"""

from __future__ import annotations

import dataclasses
import json
import os
import shlex
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from advsim_ros.core.curation import CurationConfig, best_window, curate_windows, load_curation_config
from advsim_ros.core.types import ScenarioError
from advsim_ros.io.bag import read_scenario_bag
from advsim_ros.ros.launcher import (
    Launcher,
    NodeSpec,
    graph_environment,
    graph_overrides,
    python_module_command,
    reserve_domain_id,
)

PACKAGE_ROOT = Path(__file__).resolve().parent
REPO_PARAMS = PACKAGE_ROOT.parents[2] / "params"


def default_params_dir() -> Path:
    """params/ of the source tree, else the installed share/advsim_ros/params."""
    if REPO_PARAMS.is_dir():
        return REPO_PARAMS
    installed = Path(sys.prefix) / "share" / "advsim_ros" / "params"
    if installed.is_dir():
        return installed
    raise ScenarioError(f"no params folder found (looked in {REPO_PARAMS} and {installed})")


class AttackError(RuntimeError):
    """The attack could not run to the end; the message says why and where the logs are."""


@dataclass(frozen=True)
class StackSpec:
    """The stack under test: a command started as its own process, with topic remappings."""

    name: str  # log-file name and how the summary refers to it
    command: tuple[str, ...]  # executable and arguments (the launcher appends --ros-args ...)
    remappings: Mapping[str, str] = field(default_factory=dict)  # contract topic -> the stack's topic
    params_files: tuple[Path, ...] = ()
    restart: bool = True  # start it again when it exits during the attack
    rename_node: bool = False  # reference stacks are single nodes; users' commands keep their names
    sim_time: bool = True  # append `-p use_sim_time:=true` (off for commands that take no --ros-args)

    @staticmethod
    def reference(params_dir: Path | None = None) -> StackSpec:
        """The modular reference stack (ground removal, detector, tracker, prediction, planner)."""
        params = (params_dir or default_params_dir()) / "stack_modular.yaml"
        return StackSpec(
            "modular_stack",
            python_module_command("advsim_ros.stacks.modular.node"),
            params_files=(params,) if params.exists() else (),
        )

    @staticmethod
    def learned(params_dir: Path | None = None) -> StackSpec:
        """The imitation-learning reference stack (BEV raster -> planner)."""
        params = (params_dir or default_params_dir()) / "stack_learned.yaml"
        return StackSpec(
            "learned_stack",
            python_module_command("advsim_ros.stacks.learned.node"),
            params_files=(params,) if params.exists() else (),
        )

    @staticmethod
    def parse(text: str, remappings: Mapping[str, str] | None = None, params_dir: Path | None = None) -> StackSpec:
        """'reference', 'learned', or a command line to run as the stack."""
        if text in ("reference", "modular"):
            spec = StackSpec.reference(params_dir)
        elif text == "learned":
            spec = StackSpec.learned(params_dir)
        else:
            command = tuple(shlex.split(text))
            if not command:
                raise ScenarioError("--stack: empty command")
            # a user's command line gets --ros-args only for remappings (ros2 launch takes none)
            spec = StackSpec("stack", command, sim_time=False)
        return dataclasses.replace(spec, remappings=dict(remappings or {}))


@dataclass(frozen=True)
class AttackOptions:
    """One attack: which log window, which stack, which search, where the outputs go."""

    bag: Path  # scenario bag (rosbag2 folder)
    out_dir: Path
    stack: StackSpec
    algorithm: str = "bo"
    queries: int = 75  # search queries (the original scenario and the best's replay come on top)
    actors: int = 1  # actors perturbed at once
    seed: int = 0
    window_start_frame: int | None = None  # None: the curated window with the highest collision rate
    params_dir: Path | None = None  # None: the project's params/
    plan_timeout: float = 10.0  # longest wait for a plan per frame [s]
    startup_timeout: float = 600.0  # longest wait for the graph to become ready (feasible sets, background) [s]
    query_timeout: float = 300.0  # longest a single query may take before it is given up [s]
    parameter_overrides: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)  # node -> {param: value}
    replay_only: bool = False  # `advsim replay`: score the bag's own scenario once, no search, no re-simulation

    def __post_init__(self) -> None:
        if self.queries < 1 and not self.replay_only:
            raise ScenarioError(f"--queries: must be at least 1, got {self.queries}")
        if self.actors < 1:
            raise ScenarioError(f"--actors: must be at least 1, got {self.actors}")


@dataclass
class AttackResult:
    out_dir: Path
    summary: dict[str, Any]

    @property
    def best_adversarial_loss(self) -> float | None:
        best = self.summary.get("best")
        return None if best is None else float(best["score"]["adversarial_loss"])


def choose_window(bag: Path, params_dir: Path) -> int:
    """The curated window (highest collision rate of sampled SDV plans) of a scenario bag."""
    scenario = read_scenario_bag(bag, load_sweeps=False)
    curation_file = params_dir / "curation.yaml"
    config = load_curation_config(curation_file) if curation_file.exists() else CurationConfig()
    return best_window(curate_windows(scenario, config)).start_frame


def _write_yaml(path: Path, document: Mapping[str, Any]) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(yaml.safe_dump(json.loads(json.dumps(document)), sort_keys=False), encoding="utf-8")
    return path


def run_attack(options: AttackOptions, progress: Callable[[dict[str, Any]], None] | None = None) -> AttackResult:
    """Run the whole attack (or the replay) and write its outputs; see the module docstring."""
    from advsim_ros.ros.monitor import AttackMonitor  # rclpy only once the graph's environment is set

    params_dir = options.params_dir or default_params_dir()
    bag = options.bag.resolve()
    if not (bag / "metadata.yaml").exists():
        raise ScenarioError(f"{bag}: not a rosbag2 folder (no metadata.yaml)")
    out_dir = options.out_dir.resolve()
    out_dir.mkdir(parents=True, exist_ok=True)
    run_dir = out_dir / "run"
    start_frame = options.window_start_frame
    if start_frame is None:
        start_frame = 0 if options.replay_only else choose_window(bag, params_dir)
    window = {"scenario_bag": str(bag), "window_start_frame": int(start_frame)}
    search_algorithm = options.algorithm
    overrides: dict[str, Any] = {
        "/**": {"ros__parameters": {"window": window}},
        "/perturber": {"ros__parameters": {"num_actors": options.actors}},
        "/scenario_player": {
            "ros__parameters": {"plan_timeout": options.plan_timeout, "publish_lidar_directly": options.replay_only}
        },
        "/search": {
            "ros__parameters": {
                "algorithm": search_algorithm,
                "seed": options.seed,
                "results_file": str(out_dir / "queries.jsonl"),
                search_algorithm: {"max_queries": max(options.queries, 1)},
            }
        },
    }
    for node, values in options.parameter_overrides.items():
        overrides.setdefault(f"/{node}", {"ros__parameters": {}})["ros__parameters"].update(values)
    overrides_file = _write_yaml(run_dir / "overrides.yaml", overrides)

    def node_spec(name: str, module: str) -> NodeSpec:
        files = [params_dir / "bag.yaml", params_dir / f"{name}.yaml", overrides_file]
        return NodeSpec(name, python_module_command(module), params_files=tuple(f for f in files if f.exists()))

    graph = [
        node_spec("scorer", "advsim_ros.nodes.scorer"),
        node_spec("scenario_player", "advsim_ros.nodes.scenario_player"),
    ]
    if not options.replay_only:
        graph += [
            node_spec("lidar_resim", "advsim_ros.nodes.lidar_resim"),
            node_spec("perturber", "advsim_ros.nodes.perturber"),
            node_spec("search", "advsim_ros.nodes.search"),
        ]
    stack = NodeSpec(
        options.stack.name,
        options.stack.command,
        remappings=options.stack.remappings,
        params_files=options.stack.params_files,
        parameters={"use_sim_time": True} if options.stack.sim_time else {},
        rename_node=options.stack.rename_node,
    )
    expected = 1 if options.replay_only else options.queries + 2  # original + queries + replay of the best
    started = time.monotonic()
    with reserve_domain_id() as domain_id:
        env = graph_environment(domain_id)
        os.environ.update(graph_overrides(domain_id))  # the monitor in this process joins the same graph
        with Launcher(env, run_dir / "logs") as launcher, AttackMonitor(options.replay_only) as monitor:
            launcher.start(stack)
            for spec in graph:
                launcher.start(spec)
            if options.replay_only:
                monitor.request_original()
            crashes = _follow(options, launcher, monitor, stack, graph, expected, progress)
            record = monitor.recording()
    wall_time = time.monotonic() - started
    from advsim_ros.report import write_outputs

    summary = write_outputs(
        out_dir=out_dir,
        bag=bag,
        options=options,
        window_start_frame=int(start_frame),
        monitor_record=record,
        stack_crashes=crashes,
        wall_time=wall_time,
        domain_id=domain_id,
    )
    return AttackResult(out_dir, summary)


def _follow(
    options: AttackOptions,
    launcher: Launcher,
    monitor: Any,
    stack: NodeSpec,
    graph: Sequence[NodeSpec],
    expected: int,
    progress: Callable[[dict[str, Any]], None] | None,
) -> list[dict[str, Any]]:
    """Spin the monitor until every expected score arrived; restart a crashed stack; fail on a dead node."""
    crashes: list[dict[str, Any]] = []
    graph_names = {spec.name for spec in graph}
    last_change = time.monotonic()
    seen = 0
    while monitor.num_scores < expected:
        monitor.spin_once(0.2)
        for name, code in launcher.exited().items():
            if name in graph_names:
                tail = _log_tail(launcher.log_path(name))
                raise AttackError(f"node {name} exited with code {code}; its log ({launcher.log_path(name)}):\n{tail}")
            if name == stack.name:
                query = monitor.current_query
                crashes.append({"query_id": query, "exit_code": code})
                launcher.stop(name)
                if not options.stack.restart:
                    raise AttackError(f"the stack exited with code {code} during query {query} (restart is off)")
                launcher.start(stack)
        if monitor.num_scores != seen:
            seen = monitor.num_scores
            last_change = time.monotonic()
            if progress is not None:
                progress(monitor.progress())
        limit = options.startup_timeout if seen == 0 else options.query_timeout
        if time.monotonic() - last_change > limit:
            raise AttackError(
                f"no score for {limit:.0f} s after {seen} of {expected} queries; logs in {launcher.log_dir}"
            )
    # the last query's DONE may still be on its way (another topic than the score)
    deadline = time.monotonic() + 2.0
    while monitor.missing_episodes() and time.monotonic() < deadline:
        monitor.spin_once(0.1)
    return crashes


def _log_tail(path: Path, lines: int = 30) -> str:
    try:
        return "\n".join(path.read_text(errors="replace").splitlines()[-lines:])
    except OSError:
        return "(no log)"
