"""Auto-labelling and LiDAR odometry on every labelled LiDAR source the project reads, its labels hidden.

Run as ``python bench/bench_labelling.py [--sources kitti,av2,synthetic] [--frames N] [--seed S]``;
prints one JSON object with one entry per source:

- ``kitti_0000``: KITTI tracking 0000 (real HDL-64E). A bag of its sweeps and LiDAR mount only (no
  tracks, no ego poses) is labelled with ``advsim label`` (``labelling.command.label_bag``: KISS-ICP
  poses); labelled boxes are checked only where
  KITTI labels (the camera's field of view outside DontCare areas). ``per_sweep_detector``: the
  detector alone, every sweep on its own, scored the same way at frame level.
- ``av2/<log>``: each Argoverse 2 log under ../shared/data/av2 with its LiDAR simulated at every
  annotated frame (``io.av2_lidar``, seed 0), no tracks, no ego poses; scored against AV2's labels all
  around the ego at the frames where the sweep has >= 10 returns in the labelled box.
- ``synthetic/<family>``: each synthetic family (``io.synthetic``, seed ``--seed``) the same way.

Every source is labelled twice: without ego poses (KISS-ICP odometry, the figures at the top of its
entry) and with its own poses in the bag (``with_bag_poses``: the labeller without odometry).

Figures per source (``labelling.evaluation``): vehicles and pedestrians/cyclists within 40 m (BEV IoU
>= 0.5 per frame, a track found / correct when >= 60 % of its frames match): track and frame recall and
precision; ``long_vehicles``: the same for vehicles >= 7.5 m long; ``duplicate_tracks`` (of accepted
tracks, those whose centre lies inside another track of one class at some frame, and their share);
``pedestrians_inside_vehicles`` (accepted pedestrians / cyclists whose centre lies inside an accepted
vehicle's box at some frame); ``odometry``: KISS-ICP against the log's own poses (path length ratio,
mean / max translation error, drift per 100 m; KITTI also against the independent ORB-SLAM3 stereo
poses). Needs ../shared/data for KITTI and AV2 (a source whose data is absent is reported as skipped).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from advsim_ros.core.types import ActorClass, ActorTrack, FloatArray, Scenario
from advsim_ros.io.bag import BagConfig, read_scenario_bag, write_scenario_bag
from advsim_ros.labelling.command import LabelReport, label_bag
from advsim_ros.labelling.config import LabellingConfig
from advsim_ros.labelling.detection import detect_sweep
from advsim_ros.labelling.evaluation import (
    EvaluationConfig,
    LabellingScores,
    Region,
    duplicate_tracks,
    evaluate_tracks,
    kitti_sequence_region,
    small_inside_vehicles,
    static_track_scale,
    visible_frames,
)
from advsim_ros.labelling.odometry import trajectory_errors
from advsim_ros.stacks.modular.detector import CLASS_ORDER

SHARED_DATA = Path(__file__).resolve().parents[1] / "../shared/data"
KITTI = SHARED_DATA / "kitti_tracking_0000"
AV2 = SHARED_DATA / "av2"
# A bag "straight off the vehicle": the recorder's odometry, tf and tracks go to topics the labeller does not read.
NO_POSES = BagConfig(odom_topic="/recorded/odom", tf_topic="/recorded/tf", info_topic="/recorded/info")
LONG_VEHICLE = 7.5  # vehicles at least this long count as long (the old size cap) [m]
MIN_VISIBLE_POINTS = 10  # simulated sources: a labelled box is in scope at frames with this many returns in it


def _scores(scores: LabellingScores) -> dict[str, Any]:
    return {
        key: (list(value) if isinstance(value, tuple) else value) for key, value in dataclasses.asdict(scores).items()
    }


def _evaluate(
    truth: Scenario, labelled: tuple[ActorTrack, ...], classes: tuple[str, ...], region: Region | None
) -> LabellingScores:
    sensor_poses = np.stack([sweep.sensor_pose for sweep in truth.sweeps])
    return evaluate_tracks(
        truth.actors, labelled, truth.frame_stamps_ns, sensor_poses[:, :2, 3], EvaluationConfig(classes=classes), region
    )


def _sensor_poses(scenario: Scenario) -> FloatArray:
    poses: FloatArray = scenario.ego.poses @ scenario.ego_T_sensor
    return poses


def _path_length(poses: FloatArray) -> float:
    return float(np.sum(np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1)))


def _odometry(estimated: FloatArray, reference: FloatArray) -> dict[str, float]:
    """trajectory_errors, with the path length ratio (estimate / reference) first."""
    ratio = _path_length(estimated) / max(_path_length(reference), 1e-9)
    return {"path_length_ratio": ratio} | trajectory_errors(estimated, reference)


def _static_scale(truth: Scenario, estimated: FloatArray, label: str) -> dict[str, Any]:
    scale, count = static_track_scale(estimated, _sensor_poses(truth), truth.frame_stamps_ns, truth.actors)
    return {f"{label}_scale_from_parked_labels": scale, "parked_labelled_vehicles": count}


def _figures(truth: Scenario, labelled: Scenario, report: LabelReport, region: Region | None) -> dict[str, Any]:
    actors = labelled.actors
    vehicles = _evaluate(truth, actors, ("vehicle",), region)
    small = _evaluate(truth, actors, ("pedestrian", "cyclist"), region)
    duplicates = duplicate_tracks(actors)
    estimated, logged = _sensor_poses(labelled), _sensor_poses(truth)
    return {
        "seconds": report.seconds,
        "poses": report.poses,
        "summary": report.summary,
        "vehicles_within_40m": _scores(vehicles),
        "pedestrians_and_cyclists_within_40m": _scores(small),
        "long_vehicles_within_40m": _long_vehicles(truth, actors, region),
        "duplicate_tracks": {"count": duplicates, "rate": duplicates / max(len(actors), 1), "actors": len(actors)},
        "pedestrians_inside_vehicles": small_inside_vehicles(actors),
        "odometry_vs_logged_poses": _odometry(estimated, logged) | _static_scale(truth, estimated, "odometry"),
    }


def _visible_truth(scenario: Scenario) -> Scenario:
    """The scenario's labels at the frames where its sweep has MIN_VISIBLE_POINTS returns in the box."""

    def world(frame: int) -> FloatArray:
        sweep = scenario.sweeps[frame]
        points: FloatArray = sweep.xyz.astype(np.float64) @ sweep.sensor_pose[:3, :3].T + sweep.sensor_pose[:3, 3]
        return points

    kept = (visible_frames(actor, scenario.frame_stamps_ns, world, MIN_VISIBLE_POINTS) for actor in scenario.actors)
    return dataclasses.replace(scenario, actors=tuple(actor for actor in kept if actor is not None))


def _label_without_poses(truth: Scenario, work: Path, name: str, source: str) -> tuple[Scenario, LabelReport]:
    """Labelled without poses; its world (the first ego pose) put onto the truth's by the first ego poses."""
    hidden = dataclasses.replace(truth, actors=())
    write_scenario_bag(hidden, work / f"{name}_in", config=NO_POSES, source=source)
    report = label_bag(work / f"{name}_in", work / f"{name}_out")
    labelled = read_scenario_bag(work / f"{name}_out", load_sweeps=False)
    align = truth.ego.poses[0] @ np.linalg.inv(labelled.ego.poses[0])
    yaw = float(np.arctan2(align[1, 0], align[0, 0]))
    actors = tuple(
        dataclasses.replace(
            actor,
            centers=actor.centers @ align[:3, :3].T + align[:3, 3],
            yaws=np.angle(np.exp(1j * (actor.yaws + yaw))),
        )
        for actor in labelled.actors
    )
    ego = dataclasses.replace(labelled.ego, poses=align @ labelled.ego.poses)
    return dataclasses.replace(labelled, actors=actors, ego=ego), report


def _with_bag_poses(truth: Scenario, work: Path, name: str, region: Region | None) -> dict[str, Any]:
    """The same log with its own ego poses in the bag: the labeller without odometry."""
    write_scenario_bag(dataclasses.replace(truth, actors=()), work / f"{name}_posed", source=f"bench: {name}")
    report = label_bag(work / f"{name}_posed", work / f"{name}_posed_out")
    actors = read_scenario_bag(work / f"{name}_posed_out", load_sweeps=False).actors
    duplicates = duplicate_tracks(actors)
    return {
        "seconds": report.seconds,
        "vehicles_within_40m": _scores(_evaluate(truth, actors, ("vehicle",), region)),
        "pedestrians_and_cyclists_within_40m": _scores(_evaluate(truth, actors, ("pedestrian", "cyclist"), region)),
        "long_vehicles_within_40m": _long_vehicles(truth, actors, region),
        "duplicate_tracks": {"count": duplicates, "rate": duplicates / max(len(actors), 1), "actors": len(actors)},
        "pedestrians_inside_vehicles": small_inside_vehicles(actors),
    }


def _long_vehicles(truth: Scenario, actors: tuple[ActorTrack, ...], region: Region | None) -> dict[str, Any]:
    long_truth = dataclasses.replace(
        truth, actors=tuple(actor for actor in truth.actors if actor.length >= LONG_VEHICLE)
    )
    scores = _evaluate(long_truth, actors, ("vehicle",), region)
    return {
        "truth_tracks": scores.truth_tracks,
        "track_recall": scores.track_recall,
        "labelled_longer_than_7_5m": sum(
            1 for actor in actors if actor.actor_class is ActorClass.VEHICLE and actor.length >= LONG_VEHICLE
        ),
    }


def _per_sweep_detector(truth: Scenario, region: Region) -> dict[str, Any]:
    config = LabellingConfig()
    boxes: list[ActorTrack] = []
    started = time.perf_counter()
    for frame, sweep in enumerate(truth.sweeps):
        found = detect_sweep(sweep.xyz, truth.ego.poses[frame], truth.ego_T_sensor, frame, config)
        for row in range(found.count):
            if CLASS_ORDER[int(found.classes[row])].value != "vehicle":
                continue
            box = found.boxes[row]
            boxes.append(
                ActorTrack(
                    actor_id=f"{frame}_{row}",
                    actor_class=ActorClass.VEHICLE,
                    size=np.array([box[3], box[4], 1.5]),
                    stamps_ns=truth.frame_stamps_ns[[frame]],
                    centers=np.array([[box[0], box[1], 0.0]]),
                    yaws=np.array([box[2]]),
                )
            )
    seconds = time.perf_counter() - started
    scores = _evaluate(truth, tuple(boxes), ("vehicle",), region)
    return {
        "frame_precision": scores.frame_precision,
        "frame_recall": scores.frame_recall,
        "median_center_error_m": scores.median_center_error,
        "median_heading_error_deg": scores.median_heading_error_deg,
        "seconds": seconds,
    }


def _first_frames(truth: Scenario, count: int) -> Scenario:
    if not count or count >= truth.num_frames:
        return truth
    keep = truth.frame_stamps_ns[:count]
    return dataclasses.replace(
        truth,
        frame_stamps_ns=keep,
        ego=dataclasses.replace(truth.ego, stamps_ns=keep, poses=truth.ego.poses[:count]),
        actors=tuple(
            dataclasses.replace(
                actor, stamps_ns=actor.stamps_ns[mask], centers=actor.centers[mask], yaws=actor.yaws[mask]
            )
            for actor in truth.actors
            if (mask := actor.stamps_ns <= keep[-1]).any()
        ),
        sweeps=truth.sweeps[:count],
    )


def _kitti(work: Path, frames: int) -> dict[str, Any]:
    from advsim_ros.io.kitti import load_kitti_tracking, read_kitti_calibration, read_kitti_poses

    truth = _first_frames(load_kitti_tracking(KITTI, "0000"), frames)
    region = kitti_sequence_region(KITTI, "0000", _sensor_poses(truth))
    labelled, report = _label_without_poses(truth, work, "kitti", "bench: KITTI 0000 LiDAR + mount only")
    result = {"data": "KITTI tracking 0000 (CC BY-NC-SA 3.0)", "frames": truth.num_frames}
    result |= _figures(truth, labelled, report, region)
    calibration = read_kitti_calibration(KITTI / "calib" / "0000.txt")
    orbslam = read_kitti_poses(KITTI / "poses" / "0000_orbslam3_stereo_cam0.txt", "cam0", calibration)
    orbslam = orbslam[: truth.num_frames]
    result["odometry_vs_orbslam3_stereo"] = _odometry(_sensor_poses(labelled), orbslam)
    result["logged_poses_vs_orbslam3_stereo"] = _odometry(_sensor_poses(truth), orbslam)
    result["orbslam3_stereo_scale"] = _static_scale(truth, orbslam, "orbslam3")
    result["with_bag_poses"] = _with_bag_poses(truth, work, "kitti", region)
    result["per_sweep_detector"] = _per_sweep_detector(truth, region)
    return result


def _av2(work: Path, frames: int) -> dict[str, Any]:
    from advsim_ros.io.av2 import load_av2_log
    from advsim_ros.io.av2_lidar import simulate_av2_lidar

    result: dict[str, Any] = {}
    for log in sorted(path for path in AV2.glob("*-*-*-*-*") if path.is_dir()):
        started = time.perf_counter()
        scenario = simulate_av2_lidar(load_av2_log(log), log, np.random.default_rng(0))
        truth = _visible_truth(_first_frames(scenario, frames))
        simulated = time.perf_counter() - started
        labelled, report = _label_without_poses(truth, work, f"av2_{log.name[:8]}", f"bench: AV2 {log.name}")
        entry = {"data": "Argoverse 2 (CC BY-NC-SA 4.0), LiDAR SIMULATED", "frames": truth.num_frames}
        entry["seconds_simulate"] = simulated
        entry |= _figures(truth, labelled, report, None)
        entry["with_bag_poses"] = _with_bag_poses(truth, work, f"av2_{log.name[:8]}", None)
        result[f"av2/{log.name}"] = entry
    return result


def _synthetic(work: Path, frames: int, seed: int) -> dict[str, Any]:
    from advsim_ros.io.synthetic import SyntheticConfig, generate_synthetic_log
    from advsim_ros.io.synthetic_families import FAMILY_NAMES

    result: dict[str, Any] = {}
    for family in FAMILY_NAMES:
        log = generate_synthetic_log(np.random.default_rng(seed), SyntheticConfig(family=family), family)
        truth = _visible_truth(_first_frames(log.scenario, frames))
        labelled, report = _label_without_poses(truth, work, f"synthetic_{family}", f"bench: synthetic {family}")
        entry = {"data": f"synthetic {family}, seed {seed}", "frames": truth.num_frames}
        entry |= _figures(truth, labelled, report, None)
        result[f"synthetic/{family}"] = entry | {"with_bag_poses": _with_bag_poses(truth, work, family, None)}
    return result


def _headline(results: dict[str, Any]) -> dict[str, Any]:
    """Per source: the figures the targets are stated in."""
    table = {}
    for name, entry in results.items():
        if "vehicles_within_40m" not in entry:
            continue
        vehicles = entry["vehicles_within_40m"]
        table[name] = {
            "vehicle_track_recall": vehicles["track_recall"],
            "vehicle_track_precision": vehicles["track_precision"],
            "vehicle_frame_recall": vehicles["frame_recall"],
            "vehicle_frame_precision": vehicles["frame_precision"],
            "duplicate_rate": entry["duplicate_tracks"]["rate"],
            "pedestrians_inside_vehicles": entry["pedestrians_inside_vehicles"],
            "long_vehicle_recall": entry["long_vehicles_within_40m"]["track_recall"],
            "path_length_ratio": entry["odometry_vs_logged_poses"]["path_length_ratio"],
            "odometry_scale_from_parked_labels": entry["odometry_vs_logged_poses"]["odometry_scale_from_parked_labels"],
        }
        posed = entry["with_bag_poses"]
        table[name] |= {
            "bag_poses_vehicle_track_recall": posed["vehicles_within_40m"]["track_recall"],
            "bag_poses_vehicle_track_precision": posed["vehicles_within_40m"]["track_precision"],
            "bag_poses_duplicate_rate": posed["duplicate_tracks"]["rate"],
            "bag_poses_pedestrians_inside_vehicles": posed["pedestrians_inside_vehicles"],
            "bag_poses_long_vehicle_recall": posed["long_vehicles_within_40m"]["track_recall"],
        }
        if "odometry_vs_orbslam3_stereo" in entry:
            table[name]["path_length_ratio_vs_orbslam3"] = entry["odometry_vs_orbslam3_stereo"]["path_length_ratio"]
            table[name]["orbslam3_scale_from_parked_labels"] = entry["orbslam3_stereo_scale"][
                "orbslam3_scale_from_parked_labels"
            ]
    return table


def main() -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--sources", default="kitti,av2,synthetic", help="comma-separated: kitti, av2, synthetic")
    parser.add_argument("--frames", type=int, default=0, help="first N frames of each log only (default: all)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the synthetic logs")
    args = parser.parse_args()
    sources = [name.strip() for name in args.sources.split(",") if name.strip()]
    runs: dict[str, Callable[[Path], dict[str, Any]]] = {
        "kitti": lambda work: _kitti(work, args.frames) if KITTI.is_dir() else {"kitti_0000": "skipped: no data"},
        "av2": lambda work: _av2(work, args.frames) if AV2.is_dir() else {"av2": "skipped: no data"},
        "synthetic": lambda work: _synthetic(work, args.frames, args.seed),
    }
    unknown = sorted(set(sources) - set(runs))
    if unknown:
        print(f"bench_labelling: unknown source(s) {unknown}; known: {sorted(runs)}", file=sys.stderr)
        return 2
    results: dict[str, Any] = {}
    with tempfile.TemporaryDirectory(prefix="bench_labelling_") as folder:
        for source in sources:
            produced = runs[source](Path(folder))
            results |= {"kitti_0000": produced} if source == "kitti" and "frames" in produced else produced
            print(f"bench_labelling: {source} done", file=sys.stderr, flush=True)
    print(json.dumps({"headline": _headline(results), "sources": results}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
