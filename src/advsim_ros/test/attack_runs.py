"""What the tests of `advsim attack` as a process share: its command line, reading its journal and its processes.

(The test folder is on sys.path through conftest.py; pytest's importlib mode does not put it there.)
"""

from __future__ import annotations

import json
import os
import re
import sys
from pathlib import Path
from typing import Any

QUERIES = 6  # searched queries
# all queries: the original, the search's, two re-runs of the best, then the controls (the original twice more and
# the identity control)
ALL_QUERIES = 1 + QUERIES + 2 + 3
FAST = ("--param", "perturber.num_candidates=20000")


def attack_argv(bag: Path, out: Path, stack: str, *extra: str) -> list[str]:
    return [
        sys.executable, "-m", "advsim_ros.cli", "attack", str(bag), "--stack", stack, "--algo", "random",
        "--queries", str(QUERIES), "--window-start", "0", "-o", str(out), *FAST, *extra,
    ]  # fmt: skip


def journaled(out: Path) -> list[int]:
    """Query ids of the complete lines of the journal."""
    path = out / "queries.jsonl"
    if not path.exists():
        return []
    ids = []
    for line in path.read_text().splitlines()[1:]:
        try:
            record = json.loads(line)
        except ValueError:
            break
        if "query_id" in record:
            ids.append(int(record["query_id"]))
    return ids


def started(log: Path, offset: int) -> set[int]:
    """Queries the scenario player began to replay, in the part of its log after ``offset``."""
    text = log.read_bytes()[offset:].decode(errors="replace") if log.exists() else ""
    return {int(match) for match in re.findall(r"query (\d+): replay starts", text)}


def children(pid: int) -> list[int]:
    """Processes whose parent is ``pid`` (the graph's nodes, the stack, the reaper)."""
    found = []
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                fields = Path(f"/proc/{entry}/stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(fields[1]) == pid:
                found.append(int(entry))
    return found


def alive(pid: int) -> bool:
    """Running, not a zombie (the reaper of this container may not collect orphans)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


def measured(summary: dict[str, Any]) -> list[tuple[Any, ...]]:
    keys = ("status", "adversarial_loss", "input_digest", "plan_digest")
    return [(q["query_id"], q["algorithm"], q["delta"], *(q["score"][k] for k in keys)) for q in summary["queries"]]
