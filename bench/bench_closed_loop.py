"""Closed loop, offline: sweep rendering from the ego's actual pose and whole episodes, on synthetic logs.

Run as ``python bench/bench_closed_loop.py [--repeat N]``; prints one JSON object:

- ``render_ms``: milliseconds to ray cast one full 64-beam sweep (0.2 deg azimuth steps, about
  115,000 rays) of a synthetic street from a pose off the logged one (median and minimum);
- ``episodes``: per scene family, wall seconds of a 5-s closed-loop episode with the reference stack
  (the history replayed, then 50 sweeps rendered, planned and tracked) and what the ego did.

Rendering is exact on synthetic logs (they keep their meshes), so their realism needs no figure;
rendering a real log's sweep away from its logged pose is not built yet (docs/attack.md).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time

import numpy as np

from advsim_ros.core.lidar.boxes import yaw_pose
from advsim_ros.io.synthetic import SyntheticConfig, generate_synthetic_log
from advsim_ros.stacks.closed_loop import closed_loop_episode
from advsim_ros.stacks.modular.stack import ModularStack


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=20, help="sweeps rendered for the render timing")
    args = parser.parse_args()
    log = generate_synthetic_log(np.random.default_rng(1), SyntheticConfig(family="lead_brake"))
    scenario = log.scenario
    rng = np.random.default_rng(0)
    times = []
    for index in range(args.repeat):
        frame = 10 + index % 40
        off_pose = scenario.ego.poses[frame] @ yaw_pose([0.0, 1.0, 0.0], 0.05)  # 1 m left, turned 3 degrees
        stamp = int(scenario.frame_stamps_ns[frame])
        started = time.perf_counter()
        log.render(off_pose @ scenario.ego_T_sensor, log.actor_poses_at(stamp), rng)
        times.append(1000.0 * (time.perf_counter() - started))
    episodes = {}
    for family in ("lead_brake", "cut_in", "crossing", "left_turn"):
        family_log = generate_synthetic_log(np.random.default_rng(1), SyntheticConfig(family=family))
        started = time.perf_counter()
        episode = closed_loop_episode(ModularStack(), family_log, decision_frame=9)
        metrics = episode.closed_loop
        episodes[family] = {
            "wall_s": round(time.perf_counter() - started, 2),
            "open_loop_collision_s": _finite(episode.open_loop_collision_time),
            "closed_loop_collision_s": _finite(metrics.collision_time),
            "min_gap_m": round(metrics.min_distance, 2),
            "progress_m": round(metrics.progress, 1),
        }
    print(json.dumps({
        "cpus": os.cpu_count(),
        "render_ms": {"median": round(statistics.median(times), 1), "min": round(min(times), 1),
                      "rays_per_sweep": int(64 * round(360 / 0.2))},
        "episodes": episodes,
    }, indent=2))  # fmt: skip


def _finite(value: float) -> float | None:
    """None for 'never' (JSON has no infinity)."""
    return round(value, 2) if np.isfinite(value) else None


if __name__ == "__main__":
    main()
