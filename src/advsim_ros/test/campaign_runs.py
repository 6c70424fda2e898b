"""What the tests of `advsim campaign` as a process share: the 4-attack campaign, its command line, its results.

(The test folder is on sys.path through conftest.py; pytest's importlib mode does not put it there.)
"""

from __future__ import annotations

import csv
import sys
from pathlib import Path
from typing import Any

import yaml

TIMING_COLUMNS = ("wall_s", "cpu_s", "peak_rss_mb")


def campaign_config(path: Path, bag: Path, failure: dict[str, Any] | None = None, queries: int = 4) -> Path:
    """2 windows x 2 stacks x random search: 4 attacks on the bag (every scored attack a failure by default)."""
    values = {
        "scenarios": [{"bag": str(bag), "windows": {"starts": [0, 20]}}],
        "stacks": ["reference", "learned"],
        "algorithms": {"random": queries},
        "reruns": 0,
        "transfer": False,
        "failure": failure or {"collision": True, "adversarial_loss_above": 0.0},  # every scored attack
        "parameters": {"perturber": {"num_candidates": 20000}},
    }
    path.write_text(yaml.safe_dump(values))
    return path


def campaign_argv(config: Path, out: Path, *extra: str) -> list[str]:
    return [sys.executable, "-m", "advsim_ros.cli", "campaign", str(config), "-o", str(out), *extra]


def result_rows(out: Path) -> dict[str, dict[str, str]]:
    """results.csv by attack, the timing columns aside (they differ from run to run)."""
    with (out / "results.csv").open() as stream:
        return {
            row["attack"]: {k: v for k, v in row.items() if k not in TIMING_COLUMNS} for row in csv.DictReader(stream)
        }
