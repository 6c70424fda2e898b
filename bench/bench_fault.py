"""Time per fault-and-avoidability classification (core.fault.classify_collision) of a colliding query.

Queries on KITTI tracking 0000 (15 labelled actors) at decision frames 20, 40, ..., 100, each with one actor
moved into the ego's way: parked on the human's path where the human is 3 s later (the ego could brake), or
coming from 9 m behind along the human's path 8 m/s faster than the ego (rear-ended). Every query is
classified ``--repeat`` times; prints one JSON object with the median, minimum and 90th percentile [ms], the
classes found and the machine's load average around the run.

Usage: python bench/bench_fault.py [--repeat 20]. Needs ../shared/data/kitti_tracking_0000.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time
from pathlib import Path
from typing import Any

import numpy as np

from advsim_ros.core.evasion import EgoStart
from advsim_ros.core.fault import classify_collision
from advsim_ros.core.types import ActorTrack, Plan, Scenario
from advsim_ros.io.kitti import load_kitti_tracking

DATA = Path(__file__).resolve().parents[1] / "../shared/data/kitti_tracking_0000"


def _queries(scenario: Scenario) -> list[tuple[str, int, Plan, ActorTrack]]:
    """(kind, decision frame, the logged drive as the plan, the moved actor) for each query."""
    stamps, human = scenario.frame_stamps_ns, scenario.ego.xy
    along = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(human, axis=0), axis=1))])
    yaws = np.unwrap(scenario.ego.yaws)
    car = scenario.actor("0")

    def track(s: np.ndarray) -> ActorTrack:
        xy = np.stack([np.interp(s, along, human[:, 0]), np.interp(s, along, human[:, 1])], axis=-1)
        centres = np.hstack([xy, np.full((s.shape[0], 1), car.centers[0, 2])])
        return ActorTrack(car.actor_id, car.actor_class, car.size, stamps, centres, np.interp(s, along, yaws))

    queries = []
    for frame in range(20, 101, 20):
        plan = Plan(
            stamps[frame + 1 : frame + 51], human[frame + 1 : frame + 51], scenario.ego.yaws[frame + 1 : frame + 51]
        )
        elapsed = (stamps - stamps[frame]) / 1e9
        speed = EgoStart.from_log(scenario.ego, frame).speed
        queries.append(("parked", frame, plan, track(np.full(stamps.shape[0], along[frame + 30]))))
        queries.append(("rammed", frame, plan, track(along[frame] - 9.0 + (speed + 8.0) * elapsed)))
    return queries


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=20)
    args = parser.parse_args()
    if not DATA.is_dir():
        raise SystemExit(f"bench_fault: KITTI tracking 0000 not found at {DATA.resolve()}")
    scenario = load_kitti_tracking(DATA.resolve(), "0000")
    queries = _queries(scenario)
    load_before = os.getloadavg()
    times_ms: list[float] = []
    classes: dict[str, Any] = {}
    for kind, frame, plan, moved in queries:
        for _ in range(args.repeat):
            start = time.perf_counter()
            fault = classify_collision(plan, scenario, (moved,), frame)
            times_ms.append((time.perf_counter() - start) * 1e3)
        record = fault.as_json() if fault is not None else None
        classes[f"{kind}@{frame}"] = record and {key: record[key] for key in ("class", "escape")} | {
            "mover": record["contact"]["mover"],
            "side": record["contact"]["side"],
        }
    times_ms.sort()
    result = {
        "queries": len(queries),
        "repeat": args.repeat,
        "ms_median": round(statistics.median(times_ms), 2),
        "ms_min": round(times_ms[0], 2),
        "ms_p90": round(times_ms[int(0.9 * (len(times_ms) - 1))], 2),
        "classes": classes,
        "load_average": [round(value, 2) for value in (*load_before, *os.getloadavg())],
        "cpus": os.cpu_count(),
    }
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
