"""How long synthetic scenario logs take to draw: layouts, rendered 64-beam LiDAR, written bags.

Run as ``python bench/bench_synthetic.py [--seeds N] [--workers W]``; prints one JSON object:
per scene family the median seconds to lay out, to render and to write one default 8-s log
(80 sweeps), and the wall time of a campaign-sized draw — every family times ``--seeds``
seeds (7 x 15 = 105 logs by default) written as bags by ``W`` processes, as `advsim campaign`
would before its attacks.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from advsim_ros.io.bag import write_scenario_bag
from advsim_ros.io.synthetic import SyntheticConfig, generate_synthetic_log, write_synthetic_bag
from advsim_ros.io.synthetic_families import FAMILY_NAMES, scene_layout


def _one(family: str, seed: int, folder: Path) -> dict[str, float]:
    config = SyntheticConfig(family=family)
    times = np.arange(config.num_frames) * 0.1
    started = time.perf_counter()
    scene_layout(family, np.random.default_rng(seed), times, config.ego_speed, config.parked_cars_per_side)
    laid_out = time.perf_counter()
    log = generate_synthetic_log(np.random.default_rng(seed), config)
    rendered = time.perf_counter()
    write_scenario_bag(log.scenario, folder / f"{family}_{seed}", source="bench")
    written = time.perf_counter()
    return {"layout_s": laid_out - started, "render_s": rendered - laid_out, "write_s": written - rendered}


def _write(job: tuple[str, int, str]) -> None:
    family, seed, folder = job
    write_synthetic_bag(Path(folder) / f"{family}_{seed}", seed=seed, config=SyntheticConfig(family=family))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=15, help="seeds per family in the campaign-sized draw")
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1, help="processes writing the draw")
    args = parser.parse_args()
    per_family: dict[str, dict[str, float]] = {}
    with tempfile.TemporaryDirectory() as scratch:
        for family in FAMILY_NAMES:
            runs = [_one(family, seed, Path(scratch)) for seed in range(3)]
            per_family[family] = {key: round(statistics.median(r[key] for r in runs), 4) for key in runs[0]}
    with tempfile.TemporaryDirectory() as scratch:
        jobs = [(family, seed, scratch) for family in FAMILY_NAMES for seed in range(args.seeds)]
        started = time.perf_counter()
        with ProcessPoolExecutor(args.workers) as pool:
            list(pool.map(_write, jobs))
        draw = time.perf_counter() - started
    print(json.dumps({
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version()},
        "per_family_median_s": per_family,
        "campaign_draw": {"logs": len(jobs), "workers": args.workers, "wall_s": round(draw, 1),
                          "per_log_s": round(draw / len(jobs), 2)},
    }, indent=2))  # fmt: skip


if __name__ == "__main__":
    main()
