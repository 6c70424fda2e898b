"""Benchmark of the attack graph on a 6 s KITTI tracking 0000 window (real node processes over DDS).

1. framework overhead per query: an attack with the example stack (a constant-velocity planner
   whose own compute is a few milliseconds per sweep), random search; the median wall time of a
   query (perturb, replay 10 frames with re-simulation, plan, score) is the graph's overhead;
2. a full attack: BO with 75 queries against the reference (modular) stack, end to end.

Usage: python bench/bench_attack.py [--queries 10] [--bo-queries 75] [--skip-full]
Prints one JSON object. Needs ../shared/data/kitti_tracking_0000.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

from advsim_ros.attack import AttackOptions, StackSpec, run_attack
from advsim_ros.core.curation import CurationConfig, crop_scenario, evaluate_window
from advsim_ros.io.bag import write_scenario_bag
from advsim_ros.io.cache import cache_root
from advsim_ros.io.kitti import load_kitti_tracking
from advsim_ros.ros.launcher import python_module_command

KITTI = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "kitti_tracking_0000"


def window_bag(start_frame: int) -> Path:
    """KITTI 0000 frames start..start+59 as a scenario bag, cached."""
    path = cache_root() / "bench" / f"kitti_0000_window_{start_frame}"
    if not (path / "metadata.yaml").exists():
        scenario = load_kitti_tracking(KITTI.resolve(), "0000")
        window = crop_scenario(scenario, evaluate_window(scenario, start_frame, CurationConfig()))
        path.parent.mkdir(parents=True, exist_ok=True)
        write_scenario_bag(window, path, source="kitti_tracking/0000", overwrite=True)
    return path


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--queries", type=int, default=10, help="queries of the overhead run")
    parser.add_argument("--bo-queries", type=int, default=75, help="queries of the full BO attack")
    parser.add_argument("--skip-full", action="store_true", help="only the overhead run")
    args = parser.parse_args()
    if not KITTI.is_dir():
        print(json.dumps({"error": f"KITTI tracking 0000 not found at {KITTI.resolve()}"}))
        return 1
    bag = window_bag(0)
    figures: dict[str, object] = {"scenario": "KITTI tracking 0000, frames 0..59"}
    with tempfile.TemporaryDirectory() as scratch:
        example = StackSpec("example_stack", python_module_command("advsim_ros.stacks.example"))
        started = time.monotonic()
        overhead = run_attack(
            AttackOptions(
                bag=bag,
                out_dir=Path(scratch) / "overhead",
                stack=example,
                algorithm="random",
                queries=args.queries,
                window_start_frame=0,
            )
        ).summary
        walls = [q["score"]["wall_time"] for q in overhead["queries"] if q["query_id"] > 0 and q["score"]["wall_time"]]
        figures["overhead"] = {
            "queries": len(walls),
            "median_query_s": statistics.median(walls),
            "max_query_s": max(walls),
            "run_wall_s": time.monotonic() - started,
            "note": "includes the example stack's own compute (a few ms per sweep)",
        }
        if not args.skip_full:
            started = time.monotonic()
            full = run_attack(
                AttackOptions(
                    bag=bag,
                    out_dir=Path(scratch) / "full",
                    stack=StackSpec.reference(),
                    algorithm="bo",
                    queries=args.bo_queries,
                    window_start_frame=0,
                )
            ).summary
            figures["bo_attack_reference_stack"] = {
                "queries": args.bo_queries,
                "wall_s": time.monotonic() - started,
                "original_adversarial_loss": (full["original"] or {}).get("adversarial_loss"),
                "best_adversarial_loss": ((full["best"] or {}).get("score") or {}).get("adversarial_loss"),
                "failed_queries": full["failed_queries"],
            }
    json.dump(figures, sys.stdout, indent=2)
    print()
    return 0


if __name__ == "__main__":
    sys.exit(main())
