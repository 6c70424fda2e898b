"""`advsim export openscenario BAG -o FILE.xosc` and `advsim export route BAG -o FILE` (logic in advsim_ros.export)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from advsim_ros.io.bag import add_bag_params_option, bag_params_config


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
    add_bag_params_option(xosc)
    xosc.set_defaults(run=_run_openscenario)
    route = formats.add_parser(
        "route", help="the logged ego route from a window on, for a planner that follows one (CSV, GeoJSON, Path bag)"
    )
    route.add_argument("bag", type=Path, help="scenario bag (a converted log or an attack's adversarial/)")
    route.add_argument(
        "-o", "--output", type=Path, required=True,
        help="route.csv (x,y,yaw,speed), route.geojson (lon/lat), or a folder name: a bag with nav_msgs/Path on /route",
    )  # fmt: skip
    route.add_argument("--window-start", type=int, default=0, help="the attack's first frame (default 0)")
    route.add_argument(
        "--stack-profile", type=Path, default=None,
        help="the stack's profile: the route in its plans' frame (first fix, datum, static), GeoJSON from its datum",
    )  # fmt: skip
    route.add_argument("--overwrite", action="store_true", help="replace an existing output")
    add_bag_params_option(route)
    route.set_defaults(run=_run_route)
    return formats


def _run_route(args: Any) -> int:
    from advsim_ros.export.route import export_route

    bag_config = bag_params_config(args.bag_params)
    print(export_route(args.bag, args.output, args.window_start, args.stack_profile, args.overwrite, bag_config))
    return 0


def _run_openscenario(args: Any) -> int:
    from advsim_ros.export.openscenario import export_openscenario

    bag_config = bag_params_config(args.bag_params)
    print(export_openscenario(args.bag, args.output, overwrite=args.overwrite, bag_config=bag_config).describe())
    return 0
