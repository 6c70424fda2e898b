"""LiDAR re-simulation speed and fidelity on KITTI tracking 0000 and on synthetic logs.

Run as ``python bench/bench_resim.py [--build-only]``; prints one JSON object of figures:

- model build per log (sensor model, background, assets; from scratch, no cache) [s, wall and
  CPU], in a process of its own, and that process's peak memory [MB];
- median time per re-simulated KITTI sweep (about 120,000 points) with 1 and with 5 moved
  actors, model cached: "first" is a sweep seen for the first time (its per-point geometry
  computed), "again" a sweep re-simulated before (the geometry cached, as the second and
  later queries of an attack see it) [ms];
- KITTI identity (every actor re-inserted where it was): per-actor point-count ratio and
  median Chamfer distance of actor points; KITTI removal: share of freed rays filled;
- synthetic exact ground truth: share of rays through the moved actor's old or new box
  that agree with a direct render of the moved world within 0.1 m, over a grid of cases;
  synthetic log generation time.

Without ../shared/data the KITTI figures are left out (and the JSON says so).
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import platform
import resource
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from advsim_ros.core.curation import crop_frames
from advsim_ros.core.lidar.boxes import (
    actor_region,
    inside,
    invert_rigid,
    rays_hit_region,
    removal_region,
    to_box_frame,
    track_pose_at,
    yaw_pose,
)
from advsim_ros.core.lidar.render import grid_rays
from advsim_ros.core.lidar.resim import ResimModel
from advsim_ros.core.lidar.sensor import RangeImage, xyz_of
from advsim_ros.core.types import ActorTrack, Scenario, Sweep
from advsim_ros.io.kitti import load_kitti_tracking
from advsim_ros.io.synthetic import SyntheticConfig, SyntheticLog, generate_synthetic_log

SHARED_DATA = Path(__file__).resolve().parents[1] / "../shared/data"
MOVE = (2.0, 1.0, 0.2)  # the benchmark's perturbation of each moved actor: dx, dy [m], dyaw [rad]


def _pose(track: ActorTrack, stamp_ns: int) -> np.ndarray:
    """T_world_box at a stamp the track was labelled at."""
    pose = track_pose_at(track, stamp_ns)
    assert pose is not None
    return pose


def _peak_memory_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _build_in_fresh_process(root: Path, cache: Path, frames: tuple[int, int] | None = None) -> dict[str, float]:
    """Load KITTI 0000 (``frames``: only that window, first and last, as an attack's bag has it) and build its
    model into ``cache``: wall and CPU time, peak memory before and after."""
    scenario = load_kitti_tracking(root, "0000")
    if frames is not None:
        scenario = crop_frames(scenario, *frames)
    loaded = _peak_memory_mb()
    started, cpu = time.perf_counter(), time.process_time()
    ResimModel.build(scenario, cache)
    return {
        "model_build_s": round(time.perf_counter() - started, 1),
        "model_build_cpu_s": round(time.process_time() - cpu, 1),
        "build_process_peak_memory_mb": round(_peak_memory_mb(), 0),
        "build_process_memory_with_log_loaded_mb": round(loaded, 0),
    }


def _moved(tracks: tuple[ActorTrack, ...], actor_ids: set[str], dx: float, dy: float, dyaw: float) -> list[ActorTrack]:
    moved = []
    for track in tracks:
        if track.actor_id in actor_ids:
            centers = track.centers + np.array([dx, dy, 0.0])
            track = ActorTrack(
                track.actor_id, track.actor_class, track.size, track.stamps_ns, centers, track.yaws + dyaw
            )
        moved.append(track)
    return moved


def _nearest_actors(scenario: Scenario, sweep: Sweep, count: int) -> list[str]:
    present = [track for track in scenario.actors if track_pose_at(track, sweep.stamp_ns) is not None]
    distance = {
        track.actor_id: float(np.linalg.norm(_pose(track, sweep.stamp_ns)[:3, 3] - sweep.sensor_pose[:3, 3]))
        for track in present
    }
    return sorted(distance, key=distance.__getitem__)[:count]


def _timings(model: ResimModel, scenario: Scenario, count: int) -> dict[str, Any]:
    first, again, points = [], [], []
    for sweep in scenario.sweeps:
        chosen = _nearest_actors(scenario, sweep, count)
        if len(chosen) < count:
            continue
        perturbed = _moved(scenario.actors, set(chosen), *MOVE)
        started = time.perf_counter()
        model.resimulate(sweep, scenario.actors, perturbed, rng=np.random.default_rng(0))
        first.append(time.perf_counter() - started)
        started = time.perf_counter()
        model.resimulate(sweep, scenario.actors, perturbed, rng=np.random.default_rng(0))
        again.append(time.perf_counter() - started)
        points.append(sweep.num_points)
    return {
        "sweeps": len(first),
        "median_points": int(np.median(points)) if points else 0,
        "median_ms_first": round(1e3 * float(np.median(first)), 1) if first else None,
        "median_ms_again": round(1e3 * float(np.median(again)), 1) if again else None,
        "p90_ms_first": round(1e3 * float(np.percentile(first, 90)), 1) if first else None,
    }


def _kitti_identity(model: ResimModel, scenario: Scenario) -> dict[str, Any]:
    counts: dict[str, list[int]] = {}
    chamfers = []
    rng = np.random.default_rng(0)
    for sweep in scenario.sweeps[::7]:
        present = [track for track in scenario.actors if track_pose_at(track, sweep.stamp_ns) is not None]
        points = model.resimulate(sweep, scenario.actors, scenario.actors, rng=rng, moved=[t.actor_id for t in present])
        before_all, after_all = xyz_of(sweep.points), xyz_of(points)
        for track in present:
            pose = invert_rigid(sweep.sensor_pose) @ _pose(track, sweep.stamp_ns)
            region = actor_region(track.size, model.config.box_margin, 0.15)
            before = before_all[inside(to_box_frame(before_all, pose), region)]
            after = after_all[inside(to_box_frame(after_all, pose), region)]
            total = counts.setdefault(track.actor_id, [0, 0])
            total[0] += before.shape[0]
            total[1] += after.shape[0]
            if before.shape[0] >= 10 and after.shape[0] >= 10:
                chamfers.append(0.5 * (cKDTree(after).query(before)[0].mean() + cKDTree(before).query(after)[0].mean()))
    ratios = {key: round(after / before, 3) for key, (before, after) in counts.items() if before}
    return {
        "count_ratio_per_actor": ratios,
        "count_ratio_range": [min(ratios.values()), max(ratios.values())],
        "median_chamfer_m": round(float(np.median(chamfers)), 4),
    }


def _kitti_removal(model: ResimModel, scenario: Scenario) -> dict[str, Any]:
    freed = filled = 0
    for sweep in scenario.sweeps[::14]:
        for track in scenario.actors:
            if track_pose_at(track, sweep.stamp_ns) is None:
                continue
            others = [other for other in scenario.actors if other.actor_id != track.actor_id]
            _, stats = model.resimulate_with_stats(sweep, scenario.actors, others, rng=np.random.default_rng(0))
            freed += stats.actors[track.actor_id].freed_rays
            filled += stats.actors[track.actor_id].filled_rays
    return {"freed_rays": freed, "fill_fraction": round(filled / freed, 4)}


def _synthetic_agreement(log: SyntheticLog, model: ResimModel) -> dict[str, Any]:
    scenario = log.scenario
    directions, _, _ = grid_rays(model.sensor)
    shape = (model.sensor.num_beams, model.sensor.num_azimuths)
    cases = {}
    for frame in (10, 40, 70):
        for actor_id in ("lead", "oncoming", "parked_2", "parked_7", "pedestrian"):
            for move in ((3.0, 1.5, 0.3), (-2.0, -1.0, -0.2)):
                sweep = scenario.sweeps[frame]
                perturbed = _moved(scenario.actors, {actor_id}, *move)
                poses = {t.actor_id: yaw_pose(t.centers[frame], float(t.yaws[frame])) for t in perturbed}
                truth = RangeImage.from_points(
                    log.render(sweep.sensor_pose, poses, np.random.default_rng(1)), model.beam_rows
                )
                points = model.resimulate(sweep, scenario.actors, perturbed, rng=np.random.default_rng(0))
                got = RangeImage.from_points(points, model.beam_rows)
                actor = scenario.actor(actor_id)
                to_sensor = invert_rigid(sweep.sensor_pose)
                box = removal_region(actor.size, 0.0)
                touched = rays_hit_region(np.zeros(3), directions, to_sensor @ _pose(actor, sweep.stamp_ns), box)
                touched |= rays_hit_region(np.zeros(3), directions, to_sensor @ poses[actor_id], box)
                with np.errstate(invalid="ignore"):
                    same = (np.isinf(truth.ranges) & np.isinf(got.ranges)) | (np.abs(truth.ranges - got.ranges) <= 0.1)
                cases[f"{actor_id}@{frame}{move}"] = (
                    float(np.mean(same[touched.reshape(shape)])),
                    float(np.mean(same)),
                )
    box_rays = [value[0] for value in cases.values()]
    return {
        "cases": len(cases),
        "box_rays_agreement_median": round(float(np.median(box_rays)), 4),
        "box_rays_agreement_min": round(min(box_rays), 4),
        "box_rays_agreement_lead": round(float(np.median([v[0] for k, v in cases.items() if k.startswith("lead")])), 4),
        "all_rays_agreement_min": round(min(value[1] for value in cases.values()), 4),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--build-only", action="store_true", help="only the KITTI model builds: whole log, 6 s window")
    args = parser.parse_args()
    figures: dict[str, Any] = {
        "machine": f"{platform.machine()}, {os.cpu_count()} cores (shared with other work while measured)",
        "move": {"dx_m": MOVE[0], "dy_m": MOVE[1], "dyaw_rad": MOVE[2]},
    }
    root = SHARED_DATA / "kitti_tracking_0000"
    if args.build_only:
        if not root.is_dir():
            raise SystemExit(f"bench_resim: KITTI data not found at {root.resolve()}")
        with tempfile.TemporaryDirectory() as cache, multiprocessing.get_context("spawn").Pool(1) as pool:
            figures["kitti"] = pool.apply(_build_in_fresh_process, (root.resolve(), Path(cache)))
        with tempfile.TemporaryDirectory() as cache, multiprocessing.get_context("spawn").Pool(1) as pool:
            # what `advsim attack` builds from a 6 s window bag (the benchmark attacks' frames 0..59)
            figures["kitti_window_0_59"] = pool.apply(_build_in_fresh_process, (root.resolve(), Path(cache), (0, 59)))
        print(json.dumps(figures, indent=2))
        return
    started = time.perf_counter()
    log = generate_synthetic_log(np.random.default_rng(7), SyntheticConfig(), "synthetic_7")
    figures["synthetic_generation_s"] = round(time.perf_counter() - started, 2)
    with tempfile.TemporaryDirectory() as cache:
        started = time.perf_counter()
        synthetic_model = ResimModel.build(log.scenario, Path(cache))
        figures["synthetic_build_s"] = round(time.perf_counter() - started, 1)
    figures["synthetic_ground_truth"] = _synthetic_agreement(log, synthetic_model)
    if not root.is_dir():
        figures["kitti"] = f"skipped: {root.resolve()} not found"
        print(json.dumps(figures, indent=2))
        return
    with tempfile.TemporaryDirectory() as cache:
        # The build runs in a process of its own, as lidar_resim's would: its peak is the build's, not this
        # benchmark's (which holds the synthetic model and, below, the KITTI one).
        with multiprocessing.get_context("spawn").Pool(1) as pool:
            build = pool.apply(_build_in_fresh_process, (root.resolve(), Path(cache)))
        scenario = load_kitti_tracking(root.resolve(), "0000")
        started = time.perf_counter()
        model = ResimModel.build(scenario, Path(cache))
        cached = time.perf_counter() - started
    figures["kitti"] = {
        "sweeps": len(scenario.sweeps),
        **build,
        "model_load_from_cache_s": round(cached, 2),
        "background_surfels": model.background.surfels.count,
        "asset_surfels": {key: asset.surfels.count for key, asset in model.assets.items()},
        "resim_1_actor": _timings(model, scenario, 1),
        "resim_5_actors": _timings(model, scenario, 5),
        "identity": _kitti_identity(model, scenario),
        "removal": _kitti_removal(model, scenario),
    }
    print(json.dumps(figures, indent=2))


if __name__ == "__main__":
    main()
