"""The layers of docs/architecture.md, enforced: a module imports only from its own layer and those below.

advsim_ros/graph.py, the graph's declaration, is a layer of its own that imports nothing of the package: the
layers above the ROS side read node names from it, ros/ is handed them, core/ knows none.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

from advsim_ros import graph

PACKAGE = Path(__file__).resolve().parents[1] / "src" / "advsim_ros" / "advsim_ros"
# layer -> the layers it may import (itself included)
ALLOWED = {
    "graph": set(),  # standard library only (setup.py reads it before the dependencies are installed)
    "core": {"core"},
    "contract": {"core", "contract"},
    "io": {"core", "contract", "io"},
    "ros": {"core", "contract", "ros"},
    "stacks": {"core", "contract", "io", "ros", "stacks"},
    "adapters": {"core", "contract", "adapters"},
    "nodes": {"graph", "core", "contract", "io", "ros", "adapters", "nodes"},
    "attack": {"graph", "core", "contract", "io", "ros", "nodes", "viz", "adapters", "attack"},
    "labelling": {"core", "contract", "io", "stacks", "labelling"},
    "viz": {"core", "contract", "io", "viz"},
    "export": {"core", "contract", "io", "viz", "adapters", "export"},
    "campaign": {"graph", "core", "contract", "io", "ros", "attack", "viz", "adapters", "campaign"},
}


def _layer(module: str) -> str | None:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 and parts[0] == "advsim_ros" else None


def _layer_of(path: Path) -> str | None:
    parts = path.relative_to(PACKAGE).parts
    return parts[0] if len(parts) > 1 else path.stem  # a top-level module (graph.py) is a layer of its own


def _imports(path: Path) -> set[str]:
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.add(node.module)
    return found


def test_every_module_imports_only_its_own_layer_and_the_layers_below() -> None:
    violations = []
    for path in sorted(PACKAGE.rglob("*.py")):
        layer = _layer_of(path)
        if layer not in ALLOWED:
            continue
        for imported in _imports(path):
            target = _layer(imported)
            if imported.split(".")[0] == "rclpy" and layer in ("core", "contract", "io"):
                violations.append(f"{path.relative_to(PACKAGE)} imports rclpy")
            if target is not None and target in ALLOWED and target not in ALLOWED[layer]:
                violations.append(f"{path.relative_to(PACKAGE)} ({layer}) imports {imported}")
            if imported == "advsim_ros":  # from advsim_ros import graph: a layer imported as a module
                names = {alias.name for alias in _from_package(path)} & set(ALLOWED)
                violations += [f"{path.relative_to(PACKAGE)} ({layer}) imports {n}" for n in names - ALLOWED[layer]]
    assert violations == []


def _from_package(path: Path) -> list[ast.alias]:
    """The names of ``from advsim_ros import ...`` statements (layers imported as modules)."""
    return [
        alias
        for node in ast.walk(ast.parse(path.read_text(), str(path)))
        if isinstance(node, ast.ImportFrom) and node.module == "advsim_ros" and node.level == 0
        for alias in node.names
    ]


def _strings(tree: ast.AST) -> list[tuple[ast.Constant, bool]]:
    """String constants, docstrings aside (they may say which node reads a file); True for a piece of an f-string."""
    docstrings = {
        id(node.body[0].value)
        for node in ast.walk(tree)
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef))
        and node.body
        and isinstance(node.body[0], ast.Expr)
        and isinstance(node.body[0].value, ast.Constant)
    }
    pieces = {id(value) for node in ast.walk(tree) if isinstance(node, ast.JoinedStr) for value in node.values}
    return [
        (node, id(node) in pieces)
        for node in ast.walk(tree)
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in docstrings
    ]


def test_core_names_no_node_of_the_graph() -> None:
    """Node names live in advsim_ros/graph.py; core/ is handed them (a loader takes the node whose section it reads).

    A string that is a node's name ("perturber", "/perturber"), or an f-string naming one as ROS does
    (f"{path} /scorer"): prose such as f"search {name}" is not a node's name.
    """
    in_text = re.compile("|".join(rf"/{re.escape(name)}\b" for name in sorted(graph.NAMES)))
    found = []
    for path in sorted((PACKAGE / "core").rglob("*.py")):
        for constant, piece in _strings(ast.parse(path.read_text(), str(path))):
            if in_text.search(constant.value) if piece else constant.value.strip().lstrip("/") in graph.NAMES:
                found.append(f"{path.relative_to(PACKAGE)}:{constant.lineno} {constant.value!r}")
    assert found == []
