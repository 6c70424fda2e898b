"""No two modules of the package import each other, directly or around a loop, even from inside a function.

Every `import advsim_ros...` and `from advsim_ros... import ...` (or relative import) anywhere in a
file counts, at module level or inside a function: an import moved into a function hides a cycle
from Python, not from the design. `from advsim_ros.pkg import name` is an import of the module
`advsim_ros.pkg.name` when there is one, else of `advsim_ros.pkg`. Imports under `if TYPE_CHECKING:`
are left out: they never run, and they are how an annotation names a class whose module imports this
one (core.lidar.optics and core.lidar.rewrite name core.lidar.resim's ResimModel so).
"""

from __future__ import annotations

import ast
from collections.abc import Iterator
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "src" / "advsim_ros" / "advsim_ros"


def _modules() -> dict[str, Path]:
    """Dotted module name -> file, a package as its __init__.py."""
    modules = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        modules[".".join(parts)] = path
    return modules


def _type_checking_only(tree: ast.Module) -> set[int]:
    """ids of the import nodes inside `if TYPE_CHECKING:` (or `if typing.TYPE_CHECKING:`) blocks."""
    skipped = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If):
            test = node.test
            name = test.id if isinstance(test, ast.Name) else test.attr if isinstance(test, ast.Attribute) else ""
            if name == "TYPE_CHECKING":
                skipped.update(id(inner) for statement in node.body for inner in ast.walk(statement))
    return skipped


def _imported(module: str, path: Path, modules: dict[str, Path]) -> Iterator[str]:
    """The package's modules that `module` imports anywhere in its file."""

    def known(name: str) -> str | None:  # the module itself, else the nearest package holding it
        while name and name not in modules:
            name = name.rpartition(".")[0]
        return name or None

    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
    skipped = _type_checking_only(tree)
    for node in ast.walk(tree):
        if id(node) in skipped:
            continue
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.split(".")[0] == "advsim_ros" and (found := known(alias.name)):
                    yield found
        elif isinstance(node, ast.ImportFrom):
            if node.level:  # relative: from the package, up level - 1
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                source = ".".join([*base, *([node.module] if node.module else [])])
            else:
                source = node.module or ""
            if source.split(".")[0] != "advsim_ros":
                continue
            for alias in node.names:
                submodule = f"{source}.{alias.name}"
                found = submodule if submodule in modules else known(source)
                if found:
                    yield found


def import_graph() -> dict[str, set[str]]:
    modules = _modules()
    return {
        module: {imported for imported in _imported(module, path, modules) if imported != module}
        for module, path in modules.items()
    }


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """One cycle (a list of modules, the first repeated at the end) per strongly connected group of modules."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    groups: list[set[str]] = []

    def visit(start: str) -> None:  # Tarjan's algorithm, iterative (no recursion limit on long import chains)
        work = [(start, iter(sorted(graph[start])))]
        index[start] = low[start] = len(index)
        stack.append(start)
        while work:
            node, successors = work[-1]
            for successor in successors:
                if successor not in index:
                    index[successor] = low[successor] = len(index)
                    stack.append(successor)
                    work.append((successor, iter(sorted(graph[successor]))))
                    break
                if successor in stack:
                    low[node] = min(low[node], index[successor])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    group = set()
                    while True:
                        member = stack.pop()
                        group.add(member)
                        if member == node:
                            break
                    if len(group) > 1:
                        groups.append(group)

    for module in sorted(graph):
        if module not in index:
            visit(module)
    return [_loop(graph, group) for group in groups]


def _loop(graph: dict[str, set[str]], group: set[str]) -> list[str]:
    """A shortest import loop through the group's first module (breadth first, inside the group)."""
    start = min(group)
    paths = {start: [start]}
    frontier = [start]
    while frontier:
        following = []
        for node in frontier:
            for successor in sorted(graph[node] & group):
                if successor == start:
                    return [*paths[node], start]
                if successor not in paths:
                    paths[successor] = [*paths[node], successor]
                    following.append(successor)
        frontier = following
    raise AssertionError(f"{sorted(group)} is not a cycle")


def test_the_package_has_no_import_cycles() -> None:
    found = cycles(import_graph())
    assert not found, "import cycles:\n" + "\n".join(" -> ".join(loop) for loop in found)


def test_the_check_sees_imports_inside_functions_and_names_the_cycle() -> None:
    graph = import_graph()
    assert "advsim_ros.core.search.registry" in graph["advsim_ros.core.search.synthetic"]  # imported in a function
    assert "advsim_ros.core.search.simba" not in graph["advsim_ros.core.search.registry"]  # by name, at run time
    made_up = {"a": {"b"}, "b": {"c"}, "c": {"a", "d"}, "d": set(), "e": {"e2"}, "e2": {"e"}}
    assert cycles(made_up) == [["a", "b", "c", "a"], ["e", "e2", "e"]]
