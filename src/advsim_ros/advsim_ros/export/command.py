"""`advsim export openscenario BAG -o FILE.xosc` (logic in advsim_ros.export.openscenario)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any


def add_export_commands(
    subparsers: argparse._SubParsersAction[argparse.ArgumentParser],
) -> argparse._SubParsersAction[argparse.ArgumentParser]:
    """`advsim export openscenario`; returns the formats so that other layers add theirs (training)."""
    export = subparsers.add_parser(
        "export", help="write scenarios in another tool's format (OpenSCENARIO) or as training data"
    )
    formats = export.add_subparsers(dest="format", required=True, metavar="FORMAT")
    xosc = formats.add_parser(
        "openscenario", help="ego and actors as trajectory-following entities, ASAM OpenSCENARIO 1.3 (validated)"
    )
    xosc.add_argument("bag", type=Path, help="scenario bag, e.g. OUTDIR/adversarial of an attack")
    xosc.add_argument("-o", "--output", type=Path, required=True, help="file to write, e.g. scenario.xosc")
    xosc.add_argument("--overwrite", action="store_true", help="replace an existing output file")
    xosc.set_defaults(run=_run_openscenario)
    return formats


def _run_openscenario(args: Any) -> int:
    from advsim_ros.export.openscenario import export_openscenario

    print(export_openscenario(args.bag, args.output, overwrite=args.overwrite).describe())
    return 0
