"""`advsim report OUTDIR`: draw an attack's bev.gif and report.html again (logic in advsim_ros.viz.outputs)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any


def add_viz_commands(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    report = subparsers.add_parser(
        "report", help="write an attack's animated BEV (bev.gif) and report.html from its bag and summary.json"
    )
    report.add_argument("out", type=Path, help="the attack's output folder (OUTDIR with adversarial/ and summary.json)")
    report.set_defaults(run=_run_report)


def _run_report(args: Any) -> int:
    from advsim_ros.viz.outputs import write_viz_outputs

    written = write_viz_outputs(args.out)
    print(f"wrote {written['bev_animation']} and {written['report']}")
    return 0
