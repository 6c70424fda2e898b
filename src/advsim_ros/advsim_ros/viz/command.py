"""`advsim report OUTDIR`: draw an attack's bev.gif and report.html again (logic in advsim_ros.viz.outputs)."""

from __future__ import annotations

import argparse
from pathlib import Path

from advsim_ros.io.bag import add_bag_params_option, bag_params_config


def add_viz_commands(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    report = subparsers.add_parser(
        "report", help="write an attack's animated BEV (bev.gif) and report.html from its bag and summary.json"
    )
    report.add_argument("out", type=Path, help="the attack's output folder (OUTDIR with adversarial/ and summary.json)")
    add_bag_params_option(report)
    report.set_defaults(run=_run_report)


def _run_report(args: argparse.Namespace) -> int:
    from advsim_ros.viz.outputs import write_viz_outputs

    bag_config = bag_params_config(args.bag_params)  # else the layout the attack recorded in summary.json
    written = write_viz_outputs(args.out, bag_config=bag_config)
    print(f"wrote {written['bev_animation']} and {written['report']}")
    return 0
