"""advsim_ros.graph is the one list of the graph's nodes: setup.py's console scripts and the container agree with it."""

from __future__ import annotations

import dataclasses
import runpy
from pathlib import Path
from typing import Any

import pytest
import setuptools

from advsim_ros import graph
from advsim_ros.nodes import container

SETUP = Path(__file__).resolve().parents[1] / "setup.py"
STACKS = {"modular_stack", "learned_stack"}  # the reference stacks under test: console scripts, not graph nodes


def _console_scripts(monkeypatch: pytest.MonkeyPatch) -> dict[str, str]:
    captured: dict[str, Any] = {}
    monkeypatch.setattr(setuptools, "setup", lambda **kwargs: captured.update(kwargs))
    monkeypatch.chdir(SETUP.parent)
    runpy.run_path(str(SETUP), run_name="__main__")
    scripts = [line.split(" = ") for line in captured["entry_points"]["console_scripts"]]
    return {name: target for name, target in scripts}


def test_setup_py_has_one_console_script_per_runnable_node_of_the_declaration(monkeypatch: pytest.MonkeyPatch) -> None:
    scripts = _console_scripts(monkeypatch)
    nodes = {name: target for name, target in scripts.items() if name not in STACKS | {"advsim"}}
    assert nodes == {node.name: node.entry_point for node in graph.runnable()}
    for target in scripts.values():
        module, _, function = target.partition(":")
        assert callable(graph.resolve(f"{module}:{function}")), target


def test_the_container_runs_exactly_the_declared_nodes_with_their_classes() -> None:
    assert set(container._MODULES) == {node.name for node in graph.runnable()}
    for node in graph.runnable():
        assert graph.resolve(f"{node.module}:{node.node_class}").__name__ == node.node_class


def test_every_declared_section_names_a_config_the_checks_can_build() -> None:
    for node in graph.CONFIGURED:
        keys = [section.key for section in node.sections]
        assert len(keys) == len(set(keys)), f"/{node.name}: a section declared twice"
        for section in node.sections:
            config = graph.resolve(section.config)
            if section.key == graph.ALGORITHMS:
                config = config("random")  # name -> config class
            assert dataclasses.is_dataclass(config), f"/{node.name} {section.key}: {section.config}"
            config()  # every field has a default: a node declares it with that default
            if section.build:
                assert callable(graph.resolve(section.build))


def test_the_graph_names_are_unique_and_every_started_node_has_a_module() -> None:
    assert len(graph.NAMES) == len(graph.NODES)
    for role in graph.Role:
        for process in (graph.Process.CONTAINER, graph.Process.OWN):
            assert all(node.module for node in graph.started(role, process))
