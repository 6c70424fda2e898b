"""Auto-labelling and LiDAR odometry on KITTI tracking 0000 with its labels hidden.

Run as ``python bench/bench_labelling.py [--frames N]``; prints one JSON object:

- ``labelled``: a bag of the sweeps and the shipped ego poses without tracks is labelled with
  ``advsim label`` (``labelling.command.label_bag``) and the result is compared with KITTI's own labels
  (``labelling.evaluation``: BEV IoU >= 0.5 per frame, a track found when >= 60 % of its frames
  match, vehicles within 40 m of the sensor, labelled boxes checked only where KITTI labels:
  the camera's field of view outside DontCare areas); pedestrians and cyclists as well.
- ``per_sweep_detector``: the reference stack's detector alone, every sweep on its own (the
  candidates the offline labeller starts from), scored the same way at frame level.
- ``odometry``: a bag of the sweeps and the LiDAR mount only (no ego poses) is labelled; the
  KISS-ICP trajectory it writes is compared with the shipped KISS-ICP poses and with the
  independent ORB-SLAM3 stereo poses: mean / max translation error and drift per 100 m.
Needs ../shared/data (exits 2 naming the folder when it is absent).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from advsim_ros.core.types import ActorTrack, Scenario
from advsim_ros.io.bag import BagConfig, read_scenario_bag, write_scenario_bag
from advsim_ros.io.kitti import load_kitti_tracking, read_kitti_calibration, read_kitti_poses
from advsim_ros.labelling.command import label_bag
from advsim_ros.labelling.config import LabellingConfig
from advsim_ros.labelling.detection import detect_sweep
from advsim_ros.labelling.evaluation import EvaluationConfig, LabellingScores, evaluate_tracks, kitti_sequence_region
from advsim_ros.labelling.odometry import trajectory_errors
from advsim_ros.stacks.modular.detector import CLASS_ORDER

SHARED_DATA = Path(__file__).resolve().parents[1] / "../shared/data"
KITTI = SHARED_DATA / "kitti_tracking_0000"
# A bag "straight off the vehicle": the recorder's odometry, tf and tracks go to topics the labeller does not read.
NO_POSES = BagConfig(odom_topic="/recorded/odom", tf_topic="/recorded/tf", info_topic="/recorded/info")


def _scores(scores: LabellingScores) -> dict[str, Any]:
    return {
        key: (list(value) if isinstance(value, tuple) else value) for key, value in dataclasses.asdict(scores).items()
    }


def _evaluate(truth: Scenario, labelled: tuple[ActorTrack, ...], classes: tuple[str, ...]) -> LabellingScores:
    sensor_poses = np.stack([sweep.sensor_pose for sweep in truth.sweeps])
    return evaluate_tracks(
        truth.actors,
        labelled,
        truth.frame_stamps_ns,
        sensor_poses[:, :2, 3],
        EvaluationConfig(classes=classes),
        kitti_sequence_region(KITTI, "0000", sensor_poses),
    )


def _per_sweep_detector(truth: Scenario) -> dict[str, Any]:
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
                    actor_class="vehicle",
                    size=np.array([box[3], box[4], 1.5]),
                    stamps_ns=truth.frame_stamps_ns[[frame]],
                    centers=np.array([[box[0], box[1], 0.0]]),
                    yaws=np.array([box[2]]),
                )
            )
    seconds = time.perf_counter() - started
    scores = _evaluate(truth, tuple(boxes), ("vehicle",))
    return {
        "frame_precision": scores.frame_precision,
        "frame_recall": scores.frame_recall,
        "median_center_error_m": scores.median_center_error,
        "median_heading_error_deg": scores.median_heading_error_deg,
        "seconds": seconds,
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=0, help="first N frames only (default: all 154)")
    args = parser.parse_args()
    if not KITTI.is_dir():
        print(f"bench_labelling: KITTI tracking 0000 not found at {KITTI.resolve()}", file=sys.stderr)
        return 2
    truth = load_kitti_tracking(KITTI, "0000")
    if args.frames:
        keep = truth.frame_stamps_ns[: args.frames]
        truth = dataclasses.replace(
            truth,
            frame_stamps_ns=keep,
            ego=dataclasses.replace(truth.ego, stamps_ns=keep, poses=truth.ego.poses[: args.frames]),
            actors=tuple(
                dataclasses.replace(
                    actor, stamps_ns=actor.stamps_ns[mask], centers=actor.centers[mask], yaws=actor.yaws[mask]
                )
                for actor in truth.actors
                if (mask := actor.stamps_ns <= keep[-1]).any()
            ),
            sweeps=truth.sweeps[: args.frames],
        )
    hidden = dataclasses.replace(truth, actors=())
    result: dict[str, Any] = {"data": "KITTI tracking 0000 (CC BY-NC-SA 3.0)", "frames": truth.num_frames}
    with tempfile.TemporaryDirectory(prefix="bench_labelling_") as folder:
        work = Path(folder)
        write_scenario_bag(hidden, work / "unlabelled", source="bench: KITTI 0000, labels hidden")
        started = time.perf_counter()
        report = label_bag(work / "unlabelled", work / "labelled")
        seconds = time.perf_counter() - started
        labelled = read_scenario_bag(work / "labelled", load_sweeps=False).actors
        result["labelled"] = {
            "seconds": seconds,
            "summary": report.summary,
            "vehicles_within_40m": _scores(_evaluate(truth, labelled, ("vehicle",))),
            "pedestrians_and_cyclists_within_40m": _scores(_evaluate(truth, labelled, ("pedestrian", "cyclist"))),
        }
        result["per_sweep_detector"] = _per_sweep_detector(truth)

        write_scenario_bag(hidden, work / "no_poses", config=NO_POSES, source="bench: KITTI 0000 LiDAR + mount only")
        started = time.perf_counter()
        odometry_report = label_bag(work / "no_poses", work / "odometry")
        seconds = time.perf_counter() - started
        estimated = read_scenario_bag(work / "odometry", load_sweeps=False)
        sensor_estimate = estimated.ego.poses @ estimated.ego_T_sensor
        shipped = np.stack([sweep.sensor_pose for sweep in truth.sweeps])
        calibration = read_kitti_calibration(KITTI / "calib" / "0000.txt")
        orbslam = read_kitti_poses(KITTI / "poses" / "0000_orbslam3_stereo_cam0.txt", "cam0", calibration)
        result["odometry"] = {
            "seconds_label_with_odometry": seconds,
            "poses": odometry_report.poses,
            "vs_shipped_kissicp_1.3.0": trajectory_errors(sensor_estimate, shipped),
            "vs_orbslam3_stereo": trajectory_errors(sensor_estimate, orbslam[: truth.num_frames]),
            "shipped_kissicp_vs_orbslam3_stereo": trajectory_errors(shipped, orbslam[: truth.num_frames]),
            "labelled_vehicles_within_40m": _scores(
                _evaluate(truth, read_scenario_bag(work / "odometry", load_sweeps=False).actors, ("vehicle",))
            ),
        }
    print(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
