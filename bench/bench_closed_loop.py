"""Closed loop, offline: sweep rendering from the ego's actual pose and whole episodes, on synthetic logs.

Run as ``python bench/bench_closed_loop.py [--repeat N]``; prints one JSON object:

- ``render_ms``: milliseconds to ray cast one full 64-beam sweep (0.2 deg azimuth steps, about
  115,000 rays) of a synthetic street from a pose off the logged one (median and minimum);
- ``episodes``: per scene family, wall seconds of a 5-s closed-loop episode with the reference stack
  (the history replayed, then 50 sweeps rendered, planned and tracked) and what the ego did;
- ``realism``: sweeps rendered from a log's re-simulation model (``core.lidar.novel_view``) for
  poses away from the logged one (docs/lidar.md, "Rendering from a new pose"):

  - ``synthetic``: on a 3-s synthetic log, whose meshes give the exact sweep at any pose, the
    share of cells (beam x azimuth step) within 0.1 m of the exact sweep and the median range
    error, for the logged sweep passed on unchanged (what re-simulating the real sweep gives
    when the ego is near its logged pose) and for the sweep rendered from the model, at lateral
    offsets of 0 to 2 m;
  - ``kitti``: on KITTI tracking 0000 (``--kitti-bag``, a scenario bag; skipped with a message
    when absent), render time per full sweep (median, minimum and 90th percentile over
    ``--render-rounds`` rounds of 20 sweeps, with the machine's load average around them); at
    the logged pose, rendered vs real sweep
    (per-ray range error median, Chamfer distance, per-actor point-count ratio, precision and
    recall of the reference detector's detections on the rendered sweep against those on the
    real sweep at BEV IoU 0.5); at lateral offsets of 0.5, 1, 2 and 3 m, precision and recall
    against the labelled boxes (in the camera's view, where KITTI labels) and the share of rays
    ending in unobserved space (below the horizon yet hitting nothing, or on ground-fill surfels
    no sweep saw). Detections are those of the reference stack's detector on the one sweep
    (ground split and clustering, as ``ModularStack.step`` runs it, no tracking), in two slices:
    every road user (all classes but "other"), and vehicles scoring at least 0.5.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from advsim_ros.core.lidar.boxes import actor_region, inside, invert_rigid, to_box_frame, yaw_pose
from advsim_ros.core.lidar.novel_view import (
    GROUND_FILL,
    MISS,
    ModelRenderer,
    RenderCalibration,
    actor_poses_at,
    renderer_for,
)
from advsim_ros.core.lidar.resim import ResimModel
from advsim_ros.core.lidar.rewrite import RETURN_CLEARANCE
from advsim_ros.core.lidar.sensor import xyz_of
from advsim_ros.core.metrics import MetricsConfig, match_detections
from advsim_ros.core.types import ActorClass, Scenario, Sweep
from advsim_ros.io.bag import read_scenario_bag
from advsim_ros.io.cache import cache_root
from advsim_ros.io.synthetic import SyntheticConfig, generate_synthetic_log
from advsim_ros.stacks.closed_loop import closed_loop_episode
from advsim_ros.stacks.evaluation import in_camera_view
from advsim_ros.stacks.interface import points_xyz, transform_points, yaw_of
from advsim_ros.stacks.modular.config import ModularStackConfig
from advsim_ros.stacks.modular.detector import CLASS_ORDER, detect
from advsim_ros.stacks.modular.ground import split_ground
from advsim_ros.stacks.modular.stack import ModularStack, detections_to_world

REPO = Path(__file__).resolve().parents[1]
OFFSETS = (0.5, 1.0, 2.0, 3.0)  # lateral offsets of the ego from its logged pose, to its left [m]
NEAR_OFFSETS = (0.0, 0.05, 0.1, 0.25, 0.5, 1.0, 2.0)  # offsets of the synthetic comparison [m]
WITHIN = 0.1  # a rendered ray agrees with the exact one when both miss or their ranges differ by at most this [m]
MIN_ACTOR_POINTS = 20  # actors with fewer real points get no point-count ratio
CHAMFER_RANGE = 60.0  # Chamfer distance over points this close to the sensor (the background's reach) [m]
CONFIDENT = 0.5  # the "confident_vehicles" slice: vehicle detections scoring at least this
SLICES = ("road_users", "confident_vehicles")  # every non-"other" detection; confident vehicles only


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=20, help="sweeps rendered for the render timing")
    parser.add_argument("--kitti-bag", type=Path, default=REPO / "logs" / "kitti_0000", help="KITTI 0000 scenario bag")
    parser.add_argument("--frames", type=int, default=20, help="KITTI frames of the realism figures")
    parser.add_argument("--only-realism", action="store_true", help="leave out the render timing and the episodes")
    parser.add_argument("--render-rounds", type=int, default=3, help="rounds over the KITTI poses of the render timing")
    args = parser.parse_args()
    synthetic = synthetic_near_pose()
    realism = {"synthetic": synthetic, "kitti": kitti_realism(args.kitti_bag, args.frames, args.render_rounds)}
    if args.only_realism:
        print(json.dumps({"cpus": os.cpu_count(), "realism": realism}, indent=2))
        return
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
        "realism": realism,
    }, indent=2))  # fmt: skip


def synthetic_near_pose() -> dict[str, Any]:
    """Logged sweep passed on unchanged vs rendered from the model, against the exact sweep at small offsets."""
    log = generate_synthetic_log(np.random.default_rng(7), SyntheticConfig(duration=3.0), "short_7")
    scenario = log.scenario
    with tempfile.TemporaryDirectory() as cache:
        started = time.perf_counter()
        model = ResimModel.build(scenario, Path(cache))
        build_s = time.perf_counter() - started
    renderer = renderer_for(model)
    calibration = renderer.calibration(scenario)
    rng = np.random.default_rng(0)
    rows: dict[str, dict[str, float]] = {}
    for offset in NEAR_OFFSETS:
        logged_share: list[float] = []
        rendered_share: list[float] = []
        logged_error: list[float] = []
        rendered_error: list[float] = []
        for frame in (10, 20):
            sweep, stamp = scenario.sweeps[frame], int(scenario.frame_stamps_ns[frame])
            pose = scenario.ego.poses[frame] @ yaw_pose([0.0, offset, 0.0], 0.0) @ scenario.ego_T_sensor
            truth = renderer.cell_ranges(log.render(pose, log.actor_poses_at(stamp), rng))
            rendered = renderer.cast(pose, actor_poses_at(scenario.actors, stamp), rng, calibration).cell_ranges()
            for cells, share, error in ((renderer.cell_ranges(sweep.points), logged_share, logged_error),
                                        (rendered, rendered_share, rendered_error)):  # fmt: skip
                share_of, median = _cell_agreement(truth, cells)
                share.append(share_of)
                error.append(median)
        rows[f"{offset:g}"] = {
            "logged_sweep_agree": round(float(np.mean(logged_share)), 4),
            "rendered_agree": round(float(np.mean(rendered_share)), 4),
            "logged_sweep_median_error_m": round(float(np.mean(logged_error)), 4),
            "rendered_median_error_m": round(float(np.mean(rendered_error)), 4),
        }
    return {"model_build_s": round(build_s, 1), "frames": [10, 20], "within_m": WITHIN, "by_offset_m": rows}


def _cell_agreement(expected: np.ndarray, got: np.ndarray) -> tuple[float, float]:
    """Share of cells where both miss or both return within WITHIN, and the median range error where both return."""
    both = np.isfinite(expected) & np.isfinite(got)
    with np.errstate(invalid="ignore"):
        same = (np.isinf(expected) & np.isinf(got)) | (np.abs(expected - got) <= WITHIN)
    return float(np.mean(same)), float(np.median(np.abs(expected[both] - got[both]))) if both.any() else float("nan")


def _detections(points: np.ndarray, world_T_ego: np.ndarray, ego_T_sensor: np.ndarray,
                config: ModularStackConfig) -> dict[str, tuple[np.ndarray, np.ndarray]]:  # fmt: skip
    """Per slice (SLICES), world-frame BEV boxes (K, 5) and scores of the reference detector on one sweep."""
    split = split_ground(transform_points(points_xyz(points), ego_T_sensor), config.ground)
    found = detections_to_world(detect(split, config.ground, config.detector, ego_T_sensor[:2, 3]), world_T_ego)
    road_user = found.classes != CLASS_ORDER.index(ActorClass.OTHER)
    confident = (found.classes == CLASS_ORDER.index(ActorClass.VEHICLE)) & (found.confidences >= CONFIDENT)
    return {
        "road_users": (found.boxes[road_user], found.confidences[road_user]),
        "confident_vehicles": (found.boxes[confident], found.confidences[confident]),
    }


class _Agreement:
    """Detections matched to reference boxes (greedy, BEV IoU 0.5), pooled over sweeps."""

    def __init__(self) -> None:
        self.matched = self.detections = self.references = 0

    def add(self, boxes: np.ndarray, scores: np.ndarray, reference: np.ndarray, world_T_ego: np.ndarray) -> None:
        tally = match_detections(boxes, scores, reference, world_T_ego[:2, 3], yaw_of(world_T_ego),
                                 MetricsConfig(iou_threshold=0.5))  # fmt: skip
        self.matched += int(np.count_nonzero(tally.true_positive))
        self.detections += int(tally.scores.shape[0])
        self.references += tally.num_ground_truth

    def figures(self) -> dict[str, float | int | None]:
        return {
            "precision": round(self.matched / self.detections, 3) if self.detections else None,
            "recall": round(self.matched / self.references, 3) if self.references else None,
            "detections": self.detections,
            "references": self.references,
        }


def _in_view(boxes: np.ndarray, world_T_ego: np.ndarray) -> np.ndarray:
    """The boxes in front of the ego within +-45 deg (KITTI labels only what the camera sees)."""
    return boxes[in_camera_view(boxes[:, :2], world_T_ego, np.deg2rad(45.0))] if boxes.size else boxes


def _labelled_boxes(scenario: Scenario, stamp_ns: int) -> np.ndarray:
    poses = actor_poses_at(scenario.actors, stamp_ns)
    rows = [[*pose[:2, 3], yaw_of(pose), *scenario.actor(actor_id).size[:2]] for actor_id, pose in poses.items()]
    return np.array(rows, dtype=np.float64).reshape(-1, 5)


def kitti_realism(bag: Path, frames: int, render_rounds: int = 3) -> dict[str, Any]:
    """Item-5 figures on KITTI 0000: rendered vs real at the logged pose, detections and unobserved rays off it."""
    if not (bag / "metadata.yaml").is_file():
        return {"skipped": f"no KITTI 0000 scenario bag at {bag} (pass --kitti-bag)"}
    started = time.perf_counter()
    scenario = read_scenario_bag(bag)
    read_s = time.perf_counter() - started
    started = time.perf_counter()
    model = ResimModel.build(scenario, cache_root() / "resim")
    model_s = time.perf_counter() - started
    renderer = renderer_for(model)
    started = time.perf_counter()
    calibration = renderer.calibration(scenario)
    calibration_s = time.perf_counter() - started
    config = ModularStackConfig()
    rng = np.random.default_rng(0)
    dtype = scenario.sweeps[0].points.dtype
    picks = np.linspace(5, len(scenario.sweeps) - 6, frames).round().astype(int)
    load_before = os.getloadavg()[0]
    render_ms = _render_times(scenario, renderer, calibration, picks[:: max(1, frames // 10)], render_rounds)
    load_after = os.getloadavg()[0]
    range_errors, range_bias, chamfers, count_ratios, point_ratios = [], [], [], [], []
    rendered_vs_real = {name: _Agreement() for name in SLICES}
    real_vs_labels = {name: _Agreement() for name in SLICES}
    off_labels = {(offset, name): _Agreement() for offset in (0.0, *OFFSETS) for name in SLICES}
    unobserved: dict[float, list[tuple[float, float]]] = {offset: [] for offset in (0.0, *OFFSETS)}
    for frame in picks.tolist():
        sweep = scenario.sweeps[frame]
        stamp = sweep.stamp_ns
        index = int(np.flatnonzero(scenario.frame_stamps_ns == stamp)[0])
        world_T_ego = scenario.ego.poses[index]
        poses = actor_poses_at(scenario.actors, stamp)
        labels = _in_view(_labelled_boxes(scenario, stamp), world_T_ego)
        real = _detections(sweep.points, world_T_ego, scenario.ego_T_sensor, config)
        for name, (boxes, scores) in real.items():
            real_vs_labels[name].add(*_in_view_pair(boxes, scores, world_T_ego), labels, world_T_ego)
        for offset in (0.0, *OFFSETS):
            ego_pose = world_T_ego @ yaw_pose([0.0, offset, 0.0], 0.0)
            sensor_pose = ego_pose @ scenario.ego_T_sensor
            rays = renderer.cast(sensor_pose, poses, rng, calibration)
            points = renderer.points(rays, dtype)
            rendered = _detections(points, ego_pose, scenario.ego_T_sensor, config)
            for name, (boxes, scores) in rendered.items():
                off_labels[offset, name].add(*_in_view_pair(boxes, scores, ego_pose), labels, ego_pose)
            down = rays.kind == MISS
            below = renderer.directions[:, 2] < 0.0  # a real sensor's downward rays find the ground
            unobserved[offset].append((float(np.mean(down & below)), float(np.mean(rays.kind == GROUND_FILL))))
            if offset != 0.0:
                continue
            for name, (boxes, scores) in rendered.items():
                rendered_vs_real[name].add(boxes, scores, real[name][0], world_T_ego)
            real_cells, rendered_cells = renderer.cell_ranges(sweep.points), rays.cell_ranges()
            both = np.isfinite(real_cells) & np.isfinite(rendered_cells)
            range_errors.append(float(np.median(np.abs(real_cells[both] - rendered_cells[both]))))
            range_bias.append(float(np.median(real_cells[both] - rendered_cells[both])))
            chamfers.append(_chamfer(xyz_of(sweep.points), xyz_of(points)))
            point_ratios.append(points.shape[0] / sweep.points.shape[0])
            count_ratios += _actor_count_ratios(scenario, model, sweep, points, poses)
    ratios = np.array(count_ratios)
    return {
        "bag_read_s": round(read_s, 1),
        "model_load_s": round(model_s, 1),
        "calibration_s": round(calibration_s, 1),
        "calibration": {
            "background_drop_median": round(float(np.median(calibration.background_drop)), 3),
            "background_drop_range": [
                round(float(calibration.background_drop.min()), 3),
                round(float(calibration.background_drop.max()), 3),
            ],
            "range_noise_std_m": round(calibration.range_noise_std, 4),
        },
        "frames": picks.tolist(),
        "render_ms": {
            "median": round(statistics.median(render_ms), 1),
            "p90": round(float(np.percentile(render_ms, 90)), 1),
            "min": round(min(render_ms), 1),
            "rays_per_sweep": int(renderer.rows.shape[0]),
            "sweeps_timed": len(render_ms),
            "load_average_1min": [round(load_before, 2), round(load_after, 2)],  # the machine's other work
        },
        "logged_pose": {
            "range_error_median_m": round(float(np.median(range_errors)), 3),
            "range_bias_median_m": round(float(np.median(range_bias)), 3),
            "chamfer_m": round(float(np.median(chamfers)), 3),
            "point_count_ratio": round(float(np.median(point_ratios)), 3),
            "actor_point_count_ratio": {
                "median": round(float(np.median(ratios)), 3) if ratios.size else None,
                "p10_p90": [round(float(np.percentile(ratios, q)), 3) for q in (10, 90)] if ratios.size else None,
                "actors": int(ratios.size),
            },
            "detections_rendered_vs_real": {name: rendered_vs_real[name].figures() for name in SLICES},
        },
        "detections_vs_labels": {
            name: {
                "real_sweep": real_vs_labels[name].figures(),
                **{f"rendered_{offset:g}m": off_labels[offset, name].figures() for offset in (0.0, *OFFSETS)},
            }
            for name in SLICES
        },
        "unobserved_rays": {
            f"{offset:g}m": {
                "miss_below_horizon": round(float(np.mean([value[0] for value in values])), 4),
                "unseen_ground_fill": round(float(np.mean([value[1] for value in values])), 4),
                "total": round(float(np.mean([sum(value) for value in values])), 4),
            }
            for offset, values in unobserved.items()
        },
    }


def _render_times(
    scenario: Scenario, renderer: ModelRenderer, calibration: RenderCalibration, frames: np.ndarray, rounds: int = 3
) -> list[float]:
    """Milliseconds per full sweep (rays cast and points assembled), at the logged pose and 2 m to its left.

    `rounds` rounds over `frames` (the first sweep, warming up, is left out).
    """
    rng = np.random.default_rng(1)
    jobs = []
    for frame in frames.tolist():
        sweep = scenario.sweeps[frame]
        index = int(np.flatnonzero(scenario.frame_stamps_ns == sweep.stamp_ns)[0])
        poses = actor_poses_at(scenario.actors, sweep.stamp_ns)
        for offset in (0.0, 2.0):
            sensor_pose = scenario.ego.poses[index] @ yaw_pose([0.0, offset, 0.0], 0.0) @ scenario.ego_T_sensor
            jobs.append((sensor_pose, poses, sweep.points.dtype))
    times = []
    for sensor_pose, poses, dtype in jobs[:1] + jobs * max(1, rounds):
        began = time.perf_counter()
        renderer.points(renderer.cast(sensor_pose, poses, rng, calibration), dtype)
        times.append(1000.0 * (time.perf_counter() - began))
    return times[1:]


def _in_view_pair(boxes: np.ndarray, scores: np.ndarray, world_T_ego: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    seen = in_camera_view(boxes[:, :2], world_T_ego, np.deg2rad(45.0)) if boxes.size else np.zeros(0, dtype=bool)
    return boxes[seen], scores[seen]


def _chamfer(first: np.ndarray, second: np.ndarray) -> float:
    """Symmetric Chamfer distance [m]: the mean of both directions' mean nearest-neighbour distances."""
    first = first[np.linalg.norm(first, axis=1) <= CHAMFER_RANGE]
    second = second[np.linalg.norm(second, axis=1) <= CHAMFER_RANGE]
    there, _ = cKDTree(second).query(first, workers=-1)
    back, _ = cKDTree(first).query(second, workers=-1)
    return 0.5 * (float(np.mean(there)) + float(np.mean(back)))


def _actor_count_ratios(scenario: Scenario, model: ResimModel, sweep: Sweep, points: np.ndarray,
                        poses: dict[str, np.ndarray]) -> list[float]:  # fmt: skip
    """Rendered / real points inside each labelled actor's grown box (actors with enough real points)."""
    sensor_T_world = invert_rigid(sweep.sensor_pose)
    real, rendered = xyz_of(sweep.points), xyz_of(points)
    ratios = []
    for actor_id, pose in poses.items():
        region = actor_region(scenario.actor(actor_id).size, model.config.box_margin, RETURN_CLEARANCE)
        local_pose = sensor_T_world @ pose
        count_real = int(np.count_nonzero(inside(to_box_frame(real, local_pose), region)))
        if count_real < MIN_ACTOR_POINTS:
            continue
        count_rendered = int(np.count_nonzero(inside(to_box_frame(rendered, local_pose), region)))
        ratios.append(count_rendered / count_real)
    return ratios


def _finite(value: float) -> float | None:
    """None for 'never' (JSON has no infinity)."""
    return round(value, 2) if np.isfinite(value) else None


if __name__ == "__main__":
    main()
