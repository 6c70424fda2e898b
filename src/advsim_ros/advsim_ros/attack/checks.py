"""Everything about an attack that can be checked before a process starts, each failure one clear line.

The bag (readable, with the LiDAR and ego-pose topics; every PointCloud2 readable, the window's
sweeps each with a valid point), the window (inside the log), the stack command (resolvable), the
remappings (contract topics, checked by StackSpec) and every node's parameters (the same configs
the nodes build, from the same files) are checked here, so a bad input starts nothing and loses
nothing.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from advsim_ros import graph
from advsim_ros.attack.options import AttackOptions, StackSpec
from advsim_ros.attack.params import node_files, node_parameters, section
from advsim_ros.core.curation import CurationConfig, best_window, curate_windows, load_curation_config
from advsim_ros.core.episode import WindowConfig
from advsim_ros.core.renamed import RENAMED_ALGORITHMS
from advsim_ros.core.search.registry import ALGORITHM_NAMES
from advsim_ros.core.types import Scenario, ScenarioError
from advsim_ros.io.bag import BagConfig, check_lidar_sweeps, lidar_topic_of, read_scenario_bag, summarize_bag

_log = logging.getLogger(__name__)


@dataclass(frozen=True, eq=False)
class Preflight:
    """What the checks established: the scenario (without sweeps), the window, every node's parameters."""

    bag: Path
    scenario: Scenario
    window: WindowConfig
    bag_config: BagConfig
    parameters: dict[str, dict[str, Any]]  # node -> its merged ros__parameters (overrides included)
    files: dict[str, tuple[Path, ...]]  # node -> the project's parameter files it gets (before the overrides)


GRAPH_NODES = tuple(node.name for node in graph.CONFIGURED)  # each reads params/<node>.yaml
# every node takes these (params/bag.yaml's and the attack's /** entries; run_id: ros.graph_node)
SHARED = {graph.WINDOW.key, graph.BAG.key, "run_id"}


def check_stack_command(stack: StackSpec) -> None:
    """ScenarioError unless every process's executable exists (a path, from its working folder) or is on PATH."""
    for process in stack.processes():
        where = "--stack" if stack.profile is None else f"stack profile: process {process.name}"
        executable = process.command[0]
        if os.sep in executable:
            path = Path(process.cwd or ".") / executable  # the launcher starts it in its cwd
            if not (path.is_file() and os.access(path, os.X_OK)):
                raise ScenarioError(f"{where}: {executable} is not an executable file")
        elif shutil.which(executable, path=process.env.get("PATH")) is None:  # a profile's env may set PATH
            raise ScenarioError(f"{where}: command {executable!r} not found on PATH")


def choose_window(scenario: Scenario, params_dir: Path) -> int:
    """The curated window (highest collision rate of sampled SDV plans) of a scenario."""
    curation_file = params_dir / "curation.yaml"
    config = load_curation_config(curation_file) if curation_file.exists() else CurationConfig()
    return best_window(curate_windows(scenario, config)).start_frame


def preflight(options: AttackOptions, overrides: dict[str, Any]) -> Preflight:
    """Check the attack's inputs; ScenarioError naming the first problem."""
    bag = options.bag.resolve()
    if not (bag / "metadata.yaml").exists():
        raise ScenarioError(f"{bag}: not a rosbag2 folder (no metadata.yaml)")
    if not options.replay_only and options.algorithm not in ALGORITHM_NAMES:
        raise ScenarioError(f"--algo {options.algorithm!r}: not one of {', '.join(ALGORITHM_NAMES)}")
    check_stack_command(options.stack)
    params_dir = options.params
    files = {node: node_files(params_dir, node) for node in GRAPH_NODES}
    parameters = {node: node_parameters(files[node], node, overrides) for node in GRAPH_NODES}
    player = parameters[graph.SCENARIO_PLAYER.name]
    bag_config = section(player, graph.BAG.key, BagConfig, graph.BAG.key)
    scenario = read_scenario_bag(bag, config=bag_config, load_sweeps=False)
    held = summarize_bag(bag).topics
    lidar_topic = lidar_topic_of({topic: summary.msgtype for topic, summary in held.items()}, bag_config.lidar_topic)
    lidar = held.get(lidar_topic)
    if lidar is None or lidar.message_count == 0:
        raise ScenarioError(f"{bag}: no LiDAR sweeps on {lidar_topic}; an attack needs them")
    start = options.window_start_frame
    if start is None:
        start = 0 if options.replay_only else choose_window(scenario, params_dir)
    window_values = {**player.get(graph.WINDOW.key, {}), "window_start_frame": int(start)}
    window = section({graph.WINDOW.key: window_values}, graph.WINDOW.key, WindowConfig, graph.WINDOW.key)
    frames = window.frame_indices(scenario.num_frames)  # the window inside the log, or the error saying by how much
    _check_sweeps(bag, bag_config, scenario, frames, window.history_frames)
    _check_node_configs(options, parameters)
    return Preflight(bag, scenario, window, bag_config, parameters, files)


def _check_sweeps(bag: Path, config: BagConfig, scenario: Scenario, frames: range, history_frames: int) -> None:
    """Every cloud readable, the window's sweeps each with a valid point, a sweep at every history frame
    (lidar_resim replays them): what the graph's nodes would otherwise find after it started."""
    stamps = [int(scenario.frame_stamps_ns[index]) for index in frames]
    found = check_lidar_sweeps(bag, config, stamps)
    missing = [index for index in frames[:history_frames] if int(scenario.frame_stamps_ns[index]) not in found]
    if missing:
        raise ScenarioError(f"{bag}: no LiDAR sweep on {config.lidar_topic} at the window's history frames {missing}")


def _known(node: graph.Node) -> set[str]:
    """The top-level parameters a node takes: its own fields, its sections' keys and the shared ones."""
    known = set(SHARED)
    for part in node.sections:
        if part.key == graph.ALGORITHMS:
            known.update(ALGORITHM_NAMES)
        elif part.key:
            known.add(part.key)
        else:
            known.update(field.name for field in dataclasses.fields(graph.resolve(part.config)))
    return known


def _check_node_configs(options: AttackOptions, parameters: dict[str, dict[str, Any]]) -> None:
    """Build every section of every node's parameters (advsim_ros.graph) the way the node will, so bad
    parameters fail here, not in a process."""
    known = {node.name: _known(node) for node in graph.CONFIGURED}
    for node, values in options.parameter_overrides.items():
        if node not in known:
            raise ScenarioError(f"parameter for node {node!r}: not a node of the graph (one of {', '.join(known)})")
        unknown = sorted(set(values) - known[node])
        if unknown:
            raise ScenarioError(f"/{node}: unknown parameter(s) {unknown} (known: {sorted(known[node])})")
    search = parameters[graph.SEARCH.name]
    for old, new in RENAMED_ALGORITHMS.items():  # attack.run reads the old section as the new one
        if old in search:
            _log.warning("/search: the section %r of the parameters files is deprecated: name it %r", old, new)
    for declared in graph.CONFIGURED:
        for part in declared.sections:
            key, context = part.key, f"/{declared.name}"
            if key == graph.ALGORITHMS:  # the attack's algorithm only (a replay has none)
                if options.replay_only:
                    continue
                key, config = options.algorithm, graph.resolve(part.config)(options.algorithm)
            else:
                config = graph.resolve(part.config)
            if part.build:
                graph.resolve(part.build)(parameters[declared.name].get(key, {}), f"{context} {key}")
            else:
                section(parameters[declared.name], key, config, context)
