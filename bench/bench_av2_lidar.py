"""Simulated LiDAR for the Argoverse 2 logs: rendering time, and agreement with the real sweeps.

Run as ``python bench/bench_av2_lidar.py``; prints one JSON object with, per log in
../shared/data/av2: frames, actors, seconds to simulate every frame, mean points per sweep;
and, for the logs that have real sweeps, per real sweep: the median over actors (>= 20 real
returns) of simulated / real returns inside the actor's box, the Chamfer distance over
everything within 50 m of the sensor and over the returns inside actor boxes only
(``io.av2_lidar.compare_with_real``). Exits 2 naming the folder when the data is absent.
"""

from __future__ import annotations

import dataclasses
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from advsim_ros.io.av2 import load_av2_log
from advsim_ros.io.av2_lidar import compare_with_real, simulate_av2_lidar, simulated_vlp32c_pair

AV2 = Path(__file__).resolve().parents[1] / "../shared/data/av2"


def main() -> int:
    logs = sorted(path for path in AV2.glob("*-*-*-*-*") if path.is_dir())
    if not logs:
        print(f"bench_av2_lidar: Argoverse 2 logs not found under {AV2.resolve()}", file=sys.stderr)
        return 2
    sensor = simulated_vlp32c_pair()
    result: dict[str, Any] = {
        "data": "Argoverse 2 (CC BY-NC-SA 4.0)",
        "sensor": {"beams": sensor.num_beams, "azimuths": sensor.num_azimuths, "rays_per_sweep": sensor.num_beams
                   * sensor.num_azimuths},
        "logs": {},
    }  # fmt: skip
    for log in logs:
        scenario = load_av2_log(log)
        started = time.perf_counter()
        simulated = simulate_av2_lidar(scenario, log, np.random.default_rng(0))
        seconds = time.perf_counter() - started
        entry: dict[str, Any] = {
            "frames": scenario.num_frames,
            "actors": len(scenario.actors),
            "real_sweeps": len(scenario.sweeps),
            "seconds": seconds,
            "frames_per_second": scenario.num_frames / seconds,
            "mean_points_per_sweep": float(np.mean([sweep.num_points for sweep in simulated.sweeps])),
        }
        if scenario.sweeps:
            entry["mean_points_per_real_sweep"] = float(np.mean([sweep.num_points for sweep in scenario.sweeps]))
            entry["against_real_sweeps"] = [dataclasses.asdict(item) for item in compare_with_real(scenario, simulated)]
        result["logs"][log.name] = entry
    print(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
