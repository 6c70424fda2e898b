"""Per-frame compute of the reference stacks on real KITTI sweeps (target: modular <= 100 ms median).

Runs the modular stack over every sweep of KITTI tracking 0000 in order (as the topics
deliver them: ground removal, detection, tracking, prediction, planning) and the learned
stack over the same sweeps (raster + network), and prints one JSON object: median, 90th
percentile and mean wall time per sweep, the modular stack's median CPU time per sweep, its
median per stage and the median time its node takes to write the sweep's outputs as CDR (plan,
detections, predictions).
``--digest`` adds a SHA-256 of everything the modular stack published over the run (the CDR of
its plans, detections and predictions): equal digests from two checkouts mean a change left the
stack's outputs bit for bit as they were.
Usage: python bench/bench_stack.py [--kitti FOLDER] [--sweeps N] [--digest]
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

from advsim_ros.io.kitti import load_kitti_tracking
from advsim_ros.stacks.learned.stack import LearnedStack
from advsim_ros.stacks.modular.stack import ModularStack
from advsim_ros.stacks.replay import scenario_frames
from advsim_ros.stacks.ros_io import output_messages

DEFAULT_KITTI = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "kitti_tracking_0000"


def _figures(seconds: list[float]) -> dict[str, float]:
    values = 1000.0 * np.asarray(seconds)
    return {
        "median_ms": round(float(np.median(values)), 2),
        "p90_ms": round(float(np.percentile(values, 90)), 2),
        "mean_ms": round(float(np.mean(values)), 2),
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--kitti", type=Path, default=DEFAULT_KITTI, help="KITTI tracking folder (sequence 0000)")
    parser.add_argument("--sweeps", type=int, default=154, help="sweeps to run (default: all 154)")
    parser.add_argument("--digest", action="store_true", help="also print a SHA-256 of the modular stack's outputs")
    args = parser.parse_args()
    if not args.kitti.is_dir():
        print(f"bench_stack: KITTI data not found at {args.kitti.resolve()}", file=sys.stderr)
        return 1
    scenario = load_kitti_tracking(args.kitti, "0000")
    frames = [frame for _, frame in scenario_frames(scenario, range(min(args.sweeps, scenario.num_frames)))]
    results: dict[str, object] = {"sweeps": len(frames), "cpu_count": os.cpu_count()}

    modular = ModularStack()
    modular.step(frames[0])  # first call pays for imports and caches, as a started node would
    modular.reset()
    totals, cpu, stages, writing = [], [], {}, []
    digest = hashlib.sha256()
    for frame in frames:
        started, cpu_started = time.perf_counter(), time.process_time()
        output = modular.step(frame)
        totals.append(time.perf_counter() - started)
        cpu.append(time.process_time() - cpu_started)
        for stage, seconds in output.timings_s.items():
            stages.setdefault(stage, []).append(seconds)
        started = time.perf_counter()
        messages = output_messages(output, frame.stamp_ns, "world")
        writing.append(time.perf_counter() - started)
        for raw in messages:
            digest.update(b"" if raw is None else raw)
    results["modular"] = {
        **_figures(totals),
        "stage_median_ms": {
            stage: round(1000.0 * float(np.median(values)), 2) for stage, values in stages.items() if stage != "total"
        },
        # CPU time of this process: on a machine shared with other jobs, steadier than wall time.
        "cpu_median_ms": round(1000.0 * float(np.median(cpu)), 2),
        "messages_median_ms": round(1000.0 * float(np.median(writing)), 2),
        "points_per_sweep": int(np.median([frame.xyz.shape[0] for frame in frames])),
    }
    if args.digest:
        results["modular"]["outputs_sha256"] = digest.hexdigest()

    learned = LearnedStack()
    learned.step(frames[0])
    learned.reset()
    totals, inference = [], []
    for frame in frames:
        started = time.perf_counter()
        output = learned.step(frame)
        totals.append(time.perf_counter() - started)
        inference.append(output.timings_s["inference"])
    results["learned"] = {**_figures(totals), "network_median_ms": round(1000.0 * float(np.median(inference)), 2)}
    print(json.dumps(results))
    return 0


if __name__ == "__main__":
    sys.exit(main())
