"""Feasible-set sampling and pruning, projection, and actor selection on real logs.

Run as ``python bench/bench_feasibility.py [--repeat N] [--no-reports]``; prints one JSON object:

- ``build``: seconds to sample and prune config.num_candidates (2e5) candidates for one actor
  over 6 s at 10 Hz (median and minimum of N runs) and the candidates left after each step, on
  a generated street with 15 other actors (always) and on KITTI tracking 0000 and the
  Argoverse 2 logs (when ../shared/data is there);
- ``peak_memory_mb``: the largest memory numpy and Python held during one build (tracemalloc),
  and the process's peak resident size;
- ``projection``: milliseconds per query (median, 95th percentile) for one and for two actors;
- ``selection``: which actors are perturbed in several windows of every real log and how many
  candidates survive each pruning step (skipped with --no-reports).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import platform
import resource
import time
import tracemalloc
from pathlib import Path
from typing import Any

import numpy as np

from advsim_ros import graph
from advsim_ros.core.drivable import DrivableConfig, drivable_area_for
from advsim_ros.core.feasibility import (
    FeasibleSet,
    InfeasibleError,
    PerturberConfig,
    Window,
    build_feasible_set,
    load_perturber_config,
    project,
    select_actors,
    window_obstacles,
)
from advsim_ros.core.types import ActorTrack, DrivableArea, EgoTrajectory, RoadMap, Scenario

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO / "../shared/data"
FRAMES = 80
STAMPS = 1_000_000_000 + 100_000_000 * np.arange(FRAMES, dtype=np.int64)


def generated_street() -> Scenario:
    """A straight four-lane street: the SDV, 7 moving cars and 8 parked cars (15 other actors)."""
    times = np.arange(FRAMES) * 0.1
    poses = np.tile(np.eye(4), (FRAMES, 1, 1))
    poses[:, 0, 3], poses[:, 1, 3] = 8.0 * times, -1.75
    actors = []
    moving = [(20.0, -1.75, 0.0, 7.0), (-15.0, -1.75, 0.0, 9.0), (10.0, -5.25, 0.0, 10.0), (-5.0, -5.25, 0.0, 6.0)]
    moving += [(110.0, 1.75, math.pi, 9.0), (70.0, 1.75, math.pi, 8.0), (140.0, 5.25, math.pi, 10.0)]
    for index, (x, y, yaw, speed) in enumerate(moving):
        xs = x + math.cos(yaw) * speed * times
        centers = np.column_stack([xs, np.full(FRAMES, y), np.full(FRAMES, 0.8)])
        actors.append(
            ActorTrack(f"car{index}", "vehicle", np.array([4.5, 1.9, 1.6]), STAMPS, centers, np.full(FRAMES, yaw))
        )
    for index in range(8):
        side = 8.6 if index % 2 else -8.6
        centers = np.tile([15.0 + 9.0 * index, side, 0.75], (FRAMES, 1))
        actors.append(
            ActorTrack(f"parked{index}", "vehicle", np.array([4.2, 1.8, 1.5]), STAMPS, centers, np.zeros(FRAMES))
        )
    road = np.array([[-80.0, -10.0], [260.0, -10.0], [260.0, 10.0], [-80.0, 10.0]])
    return Scenario(
        scenario_id="generated_street",
        frame_stamps_ns=STAMPS,
        ego=EgoTrajectory(STAMPS, poses),
        actors=tuple(actors),
        road_map=RoadMap(drivable_areas=(road,)),
    )


def _time_builds(
    scenario: Scenario, window: Window, actor_id: str, config: PerturberConfig, drivable: DrivableArea, repeat: int
) -> dict[str, Any]:
    obstacles = window_obstacles(scenario, window, config)
    seconds = []
    feasible: FeasibleSet | None = None
    for run in range(repeat):
        started = time.perf_counter()
        feasible = build_feasible_set(
            scenario, window, actor_id, config, np.random.default_rng(run), drivable=drivable, obstacles=obstacles
        )
        seconds.append(time.perf_counter() - started)
    assert feasible is not None
    present = int(np.count_nonzero(obstacles.without(actor_id).present.any(axis=0)))
    return {
        "scenario": scenario.scenario_id,
        "window_start": window.start_frame,
        "actor": actor_id,
        "other_obstacles": present,  # the SDV plus every other actor present in the window
        "median_s": round(float(np.median(seconds)), 4),
        "min_s": round(float(np.min(seconds)), 4),
        "counts": feasible.counts.as_dict(),
    }


def _peak_memory(
    scenario: Scenario, window: Window, actor_id: str, config: PerturberConfig, drivable: DrivableArea
) -> float:
    obstacles = window_obstacles(scenario, window, config)
    tracemalloc.start()
    tracemalloc.reset_peak()
    build_feasible_set(
        scenario, window, actor_id, config, np.random.default_rng(0), drivable=drivable, obstacles=obstacles
    )
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return round(peak / 2**20, 1)


def _time_projection(sets: list[FeasibleSet], queries: int) -> dict[str, Any]:
    rng = np.random.default_rng(11)
    dim = sets[0].config.perturbation_dim * len(sets)
    project(sets, np.zeros(dim))  # builds the projection indices once
    seconds = []
    for _ in range(queries):
        delta = rng.uniform(-1.0, 1.0, dim)
        started = time.perf_counter()
        project(sets, delta)
        seconds.append(time.perf_counter() - started)
    milliseconds = np.array(seconds) * 1e3
    return {
        "actors": [feasible.actor_id for feasible in sets],
        "feasible_candidates": [feasible.size for feasible in sets],
        "queries": queries,
        "median_ms": round(float(np.median(milliseconds)), 3),
        "p95_ms": round(float(np.percentile(milliseconds, 95)), 3),
        "max_ms": round(float(np.max(milliseconds)), 3),
    }


def _selection_report(scenario: Scenario, starts: list[int], config: PerturberConfig) -> list[dict[str, Any]]:
    drivable = drivable_area_for(scenario, DrivableConfig())
    rows = []
    for start in starts:
        window = Window(start, config.horizon_steps)
        started = time.perf_counter()
        try:
            selection = select_actors(scenario, window, config, np.random.default_rng(config.seed), drivable=drivable)
            reports, selected, error = selection.reports, list(selection.actor_ids), None
        except InfeasibleError as failure:
            reports, selected, error = failure.reports, [], str(failure)
        rows.append(
            {
                "scenario": scenario.scenario_id,
                "window_start": start,
                "drivable_source": drivable.source,
                "selected": selected,
                "error": error,
                "seconds": round(time.perf_counter() - started, 2),
                "actors_tried": [
                    {
                        "actor": report.actor_id,
                        "class": report.actor_class,
                        "gap_to_sdv_m": round(report.min_distance, 2),
                        "outcome": report.reason,
                        "counts": report.counts.as_dict() if report.counts else None,
                        "fit_rmse_m": None if report.fit_rmse is None else round(report.fit_rmse, 3),
                    }
                    for report in reports
                    if report.counts is not None or "not needed" not in report.reason
                ],
            }
        )
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5, help="builds per measurement (median reported)")
    parser.add_argument("--queries", type=int, default=200, help="projection queries per measurement")
    parser.add_argument("--no-reports", action="store_true", help="skip the selection reports on real logs")
    args = parser.parse_args()
    config = load_perturber_config(REPO / "params" / "perturber.yaml", node=graph.PERTURBER.name)
    figures: dict[str, Any] = {
        "machine": {"cpus": len(__import__("os").sched_getaffinity(0)), "python": platform.python_version()},
        "num_candidates": config.num_candidates,
        "horizon_steps": config.horizon_steps,
        "perturbation_dim_per_actor": config.perturbation_dim,
        "build": [],
    }
    street = generated_street()
    street_area = drivable_area_for(street, DrivableConfig())
    window = Window(0, config.horizon_steps)
    for actor_id in ("car0", "parked2"):
        figures["build"].append(_time_builds(street, window, actor_id, config, street_area, args.repeat))
    figures["peak_memory_mb"] = {
        "tracemalloc_build_parked2": _peak_memory(street, window, "parked2", config, street_area)
    }
    sets = [
        build_feasible_set(street, window, actor_id, config, np.random.default_rng(0), drivable=street_area)
        for actor_id in ("car0", "parked2")
    ]
    figures["projection"] = [_time_projection(sets[:1], args.queries), _time_projection(sets, args.queries)]
    if SHARED_DATA.is_dir():
        from advsim_ros.io.av2 import load_av2_log
        from advsim_ros.io.kitti import load_kitti_tracking

        kitti = load_kitti_tracking(SHARED_DATA / "kitti_tracking_0000", "0000")
        started = time.perf_counter()
        kitti_area = drivable_area_for(kitti, DrivableConfig())
        figures["kitti_drivable_estimate_s"] = round(time.perf_counter() - started, 2)
        for actor_id in ("0", "5"):  # a moving van and a parked car, against 14 other actors and the SDV
            figures["build"].append(
                _time_builds(kitti, Window(90, config.horizon_steps), actor_id, config, kitti_area, args.repeat)
            )
        figures["peak_memory_mb"]["tracemalloc_build_kitti_5"] = _peak_memory(
            kitti, Window(90, 60), "5", config, kitti_area
        )
        logs = sorted(path for path in (SHARED_DATA / "av2").glob("*-*-*-*-*") if path.is_dir())
        av2 = [load_av2_log(log) for log in logs]
        if not args.no_reports:
            two = dataclasses.replace(config, num_actors=2)
            figures["selection"] = _selection_report(kitti, [0, 20, 40, 60, 80, 94], config)
            figures["selection_two_actors"] = _selection_report(kitti, [0, 90], two)
            for scenario in av2:
                figures["selection"] += _selection_report(scenario, [0, 48, 95], config)
                figures["selection_two_actors"] += _selection_report(scenario, [0], two)
    else:
        figures["note"] = f"no real data at {SHARED_DATA.resolve()}: generated street only"
    figures["peak_memory_mb"]["process_max_rss"] = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)
    print(json.dumps(figures, indent=1))


if __name__ == "__main__":
    main()
