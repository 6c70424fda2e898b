"""The layers of docs/architecture.md, enforced: a module imports only from its own layer and those below."""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "src" / "advsim_ros" / "advsim_ros"
# layer -> the layers it may import (itself included)
ALLOWED = {
    "core": {"core"},
    "contract": {"core", "contract"},
    "io": {"core", "contract", "io"},
    "ros": {"core", "contract", "ros"},
    "stacks": {"core", "contract", "io", "ros", "stacks"},
    "adapters": {"core", "contract", "adapters"},
    "nodes": {"core", "contract", "io", "ros", "adapters", "nodes"},
    "attack": {"core", "contract", "io", "ros", "nodes", "viz", "adapters", "attack"},
    "labelling": {"core", "contract", "io", "stacks", "labelling"},
    "viz": {"core", "contract", "io", "viz"},
    "export": {"core", "contract", "io", "viz", "adapters", "export"},
    "campaign": {"core", "contract", "io", "ros", "attack", "viz", "adapters", "campaign"},
}


def _layer(module: str) -> str | None:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 and parts[0] == "advsim_ros" else None


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
        layer = path.relative_to(PACKAGE).parts[0] if len(path.relative_to(PACKAGE).parts) > 1 else None
        if layer not in ALLOWED:
            continue
        for imported in _imports(path):
            target = _layer(imported)
            if imported.split(".")[0] == "rclpy" and layer in ("core", "contract", "io"):
                violations.append(f"{path.relative_to(PACKAGE)} imports rclpy")
            if target is not None and target in ALLOWED and target not in ALLOWED[layer]:
                violations.append(f"{path.relative_to(PACKAGE)} ({layer}) imports {imported}")
    assert violations == []
