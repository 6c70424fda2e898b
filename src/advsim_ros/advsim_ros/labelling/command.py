"""What `advsim label` does: a bag with LiDAR (and maybe ego poses) in, a scenario bag with actor tracks out.

- Ego poses: the bag's own (odometry or /tf, per params/bag.yaml) when it has them, else
  KISS-ICP LiDAR odometry (``labelling.odometry``), written as /ego/odom and /tf.
- The LiDAR mount: ``--mount`` when given, else the bag's /tf_static (or ScenarioInfo).
- Tracks: auto-labelled from the LiDAR (``labelling.pipeline``), or, with ``--tracks-topic``,
  taken from a perception topic already in the bag (``labelling.perception``).
- The output bag has the contract's topics and frames, whatever the input's were (``--bag-params``
  describes the input only), so curate, attack, replay and report read it without a description.
- Beside the output bag, ``<bag>.labels.json`` lists every track with its class, confidence and
  the quality gates it failed (only tracks that pass all gates are actors in the bag).
"""

from __future__ import annotations

import dataclasses
import json
import os
import tempfile
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from advsim_ros.core.types import EgoTrajectory, FloatArray, Scenario, ScenarioError, Sweep
from advsim_ros.io.bag import BagConfig, iter_bag_sweeps, read_scenario_bag, summarize_bag, write_scenario_bag
from advsim_ros.labelling.config import LabellingConfig, load_labelling_config
from advsim_ros.labelling.odometry import OdometryConfig, ego_poses_from_sensor, lidar_odometry, trajectory_errors
from advsim_ros.labelling.perception import read_bag_static_transforms, tracks_from_topic
from advsim_ros.labelling.pipeline import LabellingResult, label_sweeps


class LabelError(ScenarioError):
    """A bag that cannot be labelled; the message names the bag and the problem."""


@dataclass(frozen=True)
class LabelReport:
    output: Path
    report: Path
    scenario_id: str
    num_frames: int
    num_actors: int
    poses: str  # "bag" or "kiss-icp"
    tracks: str  # "auto-labelled" or the perception topic
    summary: dict[str, Any]
    seconds: float

    def describe(self) -> str:
        return (
            f"wrote {self.output}: {self.scenario_id}, {self.num_frames} frames, {self.num_actors} actors "
            f"({self.tracks}; ego poses: {self.poses}); per-track confidence and gates in {self.report} "
            f"in {self.seconds:.1f} s"
        )


def _has_poses(bag: Path, config: BagConfig) -> bool:
    topics = summarize_bag(bag).topics
    topic = config.tf_topic if config.ego_pose_source == "tf" else config.odom_topic
    return topic in topics and topics[topic].message_count > 0


def _mount_from_bag(bag: Path, config: BagConfig, sensor_frame: str) -> FloatArray | None:
    from advsim_ros.io.bag.poses import static_transform

    return static_transform(read_bag_static_transforms(bag, config.tf_static_topic), config.ego_frame, sensor_frame)


def _scenario_with_poses(bag: Path, config: BagConfig, mount: FloatArray | None) -> Scenario:
    """The bag's own scenario (its ego poses); a given mount replaces the bag's."""
    if mount is None:
        return read_scenario_bag(bag, config=config)
    # The ego frame as "sensor frame" makes the reader take an identity mount; the given one replaces it.
    scenario = read_scenario_bag(bag, config=dataclasses.replace(config, sensor_frame=config.ego_frame))
    index = {stamp: row for row, stamp in enumerate(scenario.frame_stamps_ns.tolist())}
    sweeps = tuple(
        dataclasses.replace(sweep, sensor_pose=scenario.ego.poses[index[sweep.stamp_ns]] @ mount)
        for sweep in scenario.sweeps
    )
    return dataclasses.replace(scenario, sweeps=sweeps, ego_T_sensor=mount)


def _scenario_from_odometry(
    bag: Path, config: BagConfig, mount: FloatArray | None, odometry: OdometryConfig
) -> Scenario:
    clouds = list(iter_bag_sweeps(bag, config))
    if not clouds:
        raise LabelError(f"bag {bag}: the LiDAR topic {config.lidar_topic} holds no messages")
    clouds.sort(key=lambda cloud: cloud[0])
    stamps = np.array([stamp for stamp, _, _ in clouds], dtype=np.int64)
    if np.any(np.diff(stamps) <= 0):
        raise LabelError(f"bag {bag}: two sweeps on {config.lidar_topic} share a header stamp")
    frame_ids = {frame for _, frame, _ in clouds}
    if len(frame_ids) != 1:
        raise LabelError(f"bag {bag}: sweeps come in several frames {sorted(frame_ids)}")
    sensor_frame = config.sensor_frame or frame_ids.pop()
    if mount is None:
        mount = _mount_from_bag(bag, config, sensor_frame)
    if mount is None:
        raise LabelError(
            f"bag {bag}: no transform {config.ego_frame} -> {sensor_frame} on {config.tf_static_topic}; "
            "give the LiDAR mount with --mount x,y,z,roll,pitch,yaw"
        )
    xyz = [np.stack([points[name].astype(np.float64) for name in ("x", "y", "z")], axis=-1) for _, _, points in clouds]
    world_T_sensor = lidar_odometry(xyz, odometry)
    ego = ego_poses_from_sensor(world_T_sensor, mount)
    sweeps = tuple(
        Sweep(stamp_ns=int(stamp), frame_id=frame, points=points, sensor_pose=ego[row] @ mount)
        for row, (stamp, frame, points) in enumerate(clouds)
    )
    return Scenario(
        scenario_id=bag.name,
        frame_stamps_ns=stamps,
        ego=EgoTrajectory(stamps_ns=stamps, poses=ego),
        actors=(),
        sweeps=sweeps,
        ego_T_sensor=mount,
    )


def _write_json(path: Path, payload: dict[str, Any]) -> None:
    handle, staged = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    with os.fdopen(handle, "w", encoding="utf-8") as stream:
        json.dump(payload, stream, indent=2)
    os.replace(staged, path)


def _track_rows(result: LabellingResult) -> list[dict[str, Any]]:
    return [
        {
            "actor_id": item.track.actor_id,
            "class": item.track.actor_class.value,
            "confidence": round(item.confidence, 4),
            "accepted": item.accepted,
            "rejected_by": list(item.rejected),
            "static": item.static,
            "detections": item.detections,
            "span": item.span,
            "size": [round(float(value), 3) for value in item.track.size],
        }
        for item in result.tracks
    ]


def label_bag(
    bag: Path,
    output: Path,
    *,
    tracks_topic: str | None = None,
    mount: FloatArray | None = None,
    params: Path | None = None,
    bag_config: BagConfig | None = None,
    odometry: OdometryConfig | None = None,
    overwrite: bool = False,
    check_odometry: bool = False,
) -> LabelReport:
    """Label ``bag`` and write the scenario bag ``output`` (and ``output``.labels.json beside it).

    ``check_odometry``: a bag with its own poses also gets KISS-ICP's, and the summary's
    ``odometry_check`` compares the two (path length ratio, translation errors): how far KISS-ICP's
    scale can be trusted on this sensor before labelling a bag without poses.
    """
    started = time.perf_counter()
    bag, output = Path(bag), Path(output)
    config = bag_config or BagConfig()
    labelling = load_labelling_config(params) if params is not None else LabellingConfig()
    report_path = output.with_name(f"{output.name}.labels.json")
    if (output.exists() or report_path.exists()) and not overwrite:
        raise LabelError(f"{output} exists already; remove it or choose another output path")
    if not (bag / "metadata.yaml").is_file() and not bag.is_file():
        raise LabelError(f"{bag} has no metadata.yaml: not a rosbag2 folder")
    own_poses = _has_poses(bag, config)
    scenario = (
        _scenario_with_poses(bag, config, mount)
        if own_poses
        else _scenario_from_odometry(bag, config, mount, odometry or OdometryConfig())
    )
    if tracks_topic is not None:
        actors = tracks_from_topic(bag, tracks_topic, scenario, config)
        rows: list[dict[str, Any]] = [
            {"actor_id": actor.actor_id, "class": actor.actor_class.value, "accepted": True} for actor in actors
        ]
        summary: dict[str, Any] = {"tracks_topic": tracks_topic, "actors": len(actors)}
        described = f"tracks from {tracks_topic}"
    else:
        result = label_sweeps(
            _sweeps_by_frame(scenario), scenario.frame_stamps_ns, scenario.ego.poses, scenario.ego_T_sensor, labelling
        )
        actors = result.actors
        rows = _track_rows(result)
        summary = result.summary()
        described = "auto-labelled from the LiDAR"
    if check_odometry and own_poses:
        summary["odometry_check"] = odometry_check(scenario, odometry or OdometryConfig())
    poses = "bag" if own_poses else "kiss-icp"
    source = f"labelled/{bag.name}: actor tracks {described}" + (
        "" if own_poses else "; ego poses from KISS-ICP LiDAR odometry"
    )
    # written in the contract's topics and frames (the sensor frame kept): every later command reads it as it is
    written = BagConfig(sensor_frame=config.sensor_frame, storage=config.storage, compress=config.compress)
    write_scenario_bag(
        dataclasses.replace(scenario, actors=actors), output, config=written, source=source, overwrite=overwrite
    )
    _write_json(report_path, {"bag": str(output), "source": source, "summary": summary, "tracks": rows})
    return LabelReport(
        output=output,
        report=report_path,
        scenario_id=scenario.scenario_id,
        num_frames=scenario.num_frames,
        num_actors=len(actors),
        poses=poses,
        tracks=described,
        summary=summary,
        seconds=time.perf_counter() - started,
    )


def odometry_check(scenario: Scenario, config: OdometryConfig, tolerance: float = 0.02) -> dict[str, Any]:
    """KISS-ICP on the scenario's sweeps against its own sensor poses: path length ratio and errors."""
    estimate = lidar_odometry((sweep.xyz for sweep in scenario.sweeps), config)
    logged = np.stack([sweep.sensor_pose for sweep in scenario.sweeps])
    errors = trajectory_errors(estimate, logged)
    return errors | {"scale_within_tolerance": bool(abs(errors["path_length_ratio"] - 1.0) <= tolerance)}


def _sweeps_by_frame(scenario: Scenario) -> Iterator[tuple[int, FloatArray]]:
    index = {stamp: row for row, stamp in enumerate(scenario.frame_stamps_ns.tolist())}
    return ((index[sweep.stamp_ns], sweep.xyz) for sweep in scenario.sweeps)
