"""Benchmark of drawing and exporting an attack's outputs: load, bev.png, bev.gif, report.html, OpenSCENARIO.

Reads an attack's OUTDIR (from `advsim attack` or `advsim demo`: adversarial/ and summary.json)
and writes into a temporary folder, so OUTDIR is left as it is. Each step runs --repeats times;
medians are printed with the sizes of what was written.

Usage: python bench/bench_viz.py OUTDIR [--repeats 3]
Prints one JSON object.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

from advsim_ros.export.openscenario import export_openscenario
from advsim_ros.viz.animation import write_bev_animation
from advsim_ros.viz.attack_view import load_attack_view
from advsim_ros.viz.bev import write_bev_still
from advsim_ros.viz.report import write_report


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path, help="an attack's output folder")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    bag, summary = args.out / "adversarial", args.out / "summary.json"
    if not (bag / "metadata.yaml").is_file() or not summary.is_file():
        print(f"bench_viz: {args.out} has no adversarial/ bag or summary.json (run an attack first)", file=sys.stderr)
        return 1
    times: dict[str, list[float]] = {
        "load_s": [],
        "bev_png_s": [],
        "bev_gif_s": [],
        "report_s": [],
        "openscenario_s": [],
    }
    with tempfile.TemporaryDirectory() as scratch:
        work = Path(scratch)
        for _ in range(args.repeats):
            started = time.perf_counter()
            view = load_attack_view(bag, summary)
            times["load_s"].append(time.perf_counter() - started)
            started = time.perf_counter()
            write_bev_still(view, work / "bev.png")  # the report inlines it
            times["bev_png_s"].append(time.perf_counter() - started)
            started = time.perf_counter()
            write_bev_animation(view, work / "bev.gif")
            times["bev_gif_s"].append(time.perf_counter() - started)
            started = time.perf_counter()
            write_report(view, work)
            times["report_s"].append(time.perf_counter() - started)
            started = time.perf_counter()
            export_openscenario(bag, work / "scenario.xosc", overwrite=True)
            times["openscenario_s"].append(time.perf_counter() - started)
        sizes = {
            f"{name}_bytes": (work / name).stat().st_size
            for name in ("bev.png", "bev.gif", "report.html", "scenario.xosc")
        }
    result = {
        "out": str(args.out),
        "scenario_id": view.summary["scenario"]["scenario_id"],
        "frames": view.adversarial.num_frames,
        "repeats": args.repeats,
        **{f"median_{key}": round(statistics.median(values), 3) for key, values in times.items()},
        **sizes,
    }
    print(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
