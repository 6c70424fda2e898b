"""docs/architecture.md drawn from the code: every package of advsim_ros has its row, every path it cites exists."""

from __future__ import annotations

import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PACKAGE = REPO / "src" / "advsim_ros" / "advsim_ros"
DOC = REPO / "docs" / "architecture.md"
REPO_FOLDERS = ("params", "msg_defs", "tests", "src", "docs", "scripts", "bench")  # paths cited from the repository


def _packages() -> list[str]:
    """Every package (a folder with __init__.py) under advsim_ros, as a path relative to it ('' for the root)."""
    return sorted(
        str(init.parent.relative_to(PACKAGE)) for init in PACKAGE.rglob("__init__.py") if init.parent != PACKAGE
    )


def _cited() -> list[str]:
    """The paths the document cites in backticks: with a folder, or a file name of a known kind."""
    tokens = re.findall(r"`([^`\s]+)`", DOC.read_text(encoding="utf-8"))
    return [t for t in tokens if "<" not in t and ("/" in t or re.search(r"\.(py|yaml|md|msg)$", t))]


def _table_rows() -> list[tuple[str, list[str]]]:
    """(package cell, backticked file names in the row) of each row of the layers table."""
    rows = []
    for line in DOC.read_text(encoding="utf-8").splitlines():
        cells = [cell.strip() for cell in line.strip().strip("|").split("|")]
        if line.startswith("|") and len(cells) == 4 and cells[1].startswith("`"):
            rows.append((cells[1].strip("`"), re.findall(r"`([\w.]+\.py)`", cells[2])))
    return rows


def test_every_package_has_its_row_in_the_architecture() -> None:
    text = DOC.read_text(encoding="utf-8")
    missing = []
    for package in _packages():
        top_level = "/" not in package
        cited = f"`advsim_ros.{package}`" if top_level else f"`{package}/`"
        if cited not in text:
            missing.append(cited)
    assert not missing, f"docs/architecture.md does not name these packages: {missing}"


def test_every_path_the_architecture_cites_exists() -> None:
    top_level = {path.name for path in PACKAGE.iterdir() if not path.name.startswith("_")}
    missing = []
    for token in _cited():
        first = token.split("/")[0]
        if first in REPO_FOLDERS:
            where = REPO / token
        elif first in top_level:
            where = PACKAGE / token
        else:
            continue  # a bare file name: its row's package (below)
        if not (any(where.parent.glob(where.name)) if "*" in where.name else where.exists()):  # stack_*.yaml
            missing.append(token)
    for package, files in _table_rows():
        folder = PACKAGE / (package.removeprefix("advsim_ros.").replace(".", "/") if "/" not in package else package)
        # a file of the row's package (launch_files.py, beside cli/, lies in the package's root)
        missing += [
            f"{package}: {name}" for name in files if not (folder / name).exists() and not (PACKAGE / name).exists()
        ]
    assert not missing, f"docs/architecture.md cites paths that do not exist: {sorted(set(missing))}"


def test_the_check_reads_the_table_and_the_paths() -> None:
    rows = dict(_table_rows())
    assert "journal.py" in rows["advsim_ros.core"]
    assert "projection.py" in rows["core/feasibility/"]
    assert "core/lidar/query.py" in _cited()
    assert "" not in _packages()
    assert "core/search" in _packages()
