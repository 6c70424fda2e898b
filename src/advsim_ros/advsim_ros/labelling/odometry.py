"""Ego poses from the LiDAR alone: KISS-ICP odometry (Vizzo et al., "KISS-ICP: In Defense of
Point-to-Point ICP", RA-L 2023; the ``kiss-icp`` package, pinned in requirements/base.txt).

Each sweep (sensor frame) is registered to KISS-ICP's local voxel map; the result is
T_world_sensor with the world frame = the sensor frame of the first sweep. The ego poses
follow through the mount: T_world_ego = T_world_sensor @ inv(T_ego_sensor), re-based so that
the first ego pose is the mount's ground projection (the ego frame of sweep 0 is the world
frame, as the KITTI importer does).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from advsim_ros.core.types import FloatArray, ScenarioError


@dataclass(frozen=True)
class OdometryConfig:
    """KISS-ICP settings; units beside each field (the package's defaults for a 100 m sensor)."""

    max_range: float = 100.0  # returns farther than this are not registered [m]
    min_range: float = 0.0  # ... nor nearer than this [m]
    voxel_size: float = 1.0  # local map voxel edge (KISS-ICP: max_range / 100) [m]
    deskew: bool = False  # motion compensation needs per-point times, which sweeps rarely carry
    max_threads: int = 2  # registration threads (0: all cores)

    def __post_init__(self) -> None:
        if not 0.0 <= self.min_range < self.max_range:
            raise ScenarioError("OdometryConfig: need 0 <= min_range < max_range")
        if not self.voxel_size > 0.0:
            raise ScenarioError(f"OdometryConfig voxel_size: must be positive, got {self.voxel_size}")
        if self.max_threads < 0:
            raise ScenarioError("OdometryConfig max_threads: must be >= 0")


def lidar_odometry(sweeps: Iterable[FloatArray], config: OdometryConfig | None = None) -> FloatArray:
    """(F, 4, 4) T_world_sensor of each sweep ((N, 3) points in the sensor frame [m]); sweep 0 is the identity."""
    from kiss_icp.config import KISSConfig  # imported here: the package pulls pydantic, only odometry needs it
    from kiss_icp.kiss_icp import KissICP

    config = config or OdometryConfig()
    settings = KISSConfig()
    settings.data.max_range = config.max_range
    settings.data.min_range = config.min_range
    settings.data.deskew = config.deskew
    settings.mapping.voxel_size = config.voxel_size
    settings.registration.max_num_threads = config.max_threads
    odometry = KissICP(settings)
    poses = []
    for xyz in sweeps:
        points = np.ascontiguousarray(np.asarray(xyz, dtype=np.float64).reshape(-1, 3))
        finite = np.all(np.isfinite(points), axis=1)
        odometry.register_frame(points[finite], np.zeros(0))
        poses.append(np.array(odometry.last_pose, dtype=np.float64))
    if not poses:
        raise ScenarioError("lidar_odometry: no sweeps")
    return np.stack(poses)


def ego_poses_from_sensor(world_T_sensor: FloatArray, ego_T_sensor: FloatArray) -> FloatArray:
    """(F, 4, 4) T_world_ego with the world frame re-based to the first ego pose."""
    sensor_T_ego = np.linalg.inv(ego_T_sensor)
    ego = world_T_sensor @ sensor_T_ego
    result: FloatArray = np.linalg.inv(ego[0]) @ ego
    return result


def mount_from_string(text: str) -> FloatArray:
    """T_ego_sensor (4, 4) from "x,y,z,roll,pitch,yaw" [m, m, m, rad, rad, rad]."""
    from scipy.spatial.transform import Rotation

    try:
        values = [float(value) for value in text.split(",")]
    except ValueError:
        raise ScenarioError(f"--mount {text!r}: expected x,y,z,roll,pitch,yaw numbers") from None
    if len(values) != 6 or not np.all(np.isfinite(values)):
        raise ScenarioError(f"--mount {text!r}: expected six finite numbers x,y,z,roll,pitch,yaw")
    mount = np.eye(4)
    mount[:3, :3] = Rotation.from_euler("xyz", values[3:]).as_matrix()
    mount[:3, 3] = values[:3]
    return mount


def trajectory_errors(estimate: FloatArray, reference: FloatArray, segment: float = 50.0) -> dict[str, float]:
    """Translation errors of poses (F, 4, 4) against reference poses (F, 4, 4), both starting at the same frame.

    path length ratio: the estimate's path length over the reference's (1: the same scale; both summed
    over consecutive poses); mean / max translation error [m] after aligning the first poses; drift per 100 m [m]: the
    KITTI odometry metric's translation part (Geiger et al. 2012) over every sub-trajectory
    of ``segment`` metres of the reference path, as metres of end-point error per 100 m.
    """
    estimate = np.linalg.inv(estimate[0]) @ estimate
    reference = np.linalg.inv(reference[0]) @ reference
    error = np.linalg.norm(estimate[:, :3, 3] - reference[:, :3, 3], axis=1)
    steps = np.linalg.norm(np.diff(reference[:, :3, 3], axis=0), axis=1)
    distance = np.concatenate([[0.0], np.cumsum(steps)])
    drifts = []
    for first in range(reference.shape[0]):
        last = int(np.searchsorted(distance, distance[first] + segment))
        if last >= reference.shape[0]:
            break
        relative_reference = np.linalg.inv(reference[first]) @ reference[last]
        relative_estimate = np.linalg.inv(estimate[first]) @ estimate[last]
        delta = np.linalg.inv(relative_reference) @ relative_estimate
        drifts.append(float(np.linalg.norm(delta[:3, 3])) / (distance[last] - distance[first]) * 100.0)
    estimate_length = float(np.sum(np.linalg.norm(np.diff(estimate[:, :3, 3], axis=0), axis=1)))
    return {
        "path_length_ratio": estimate_length / max(float(distance[-1]), 1e-9),
        "estimate_path_length_m": estimate_length,
        "mean_translation_error_m": float(error.mean()),
        "max_translation_error_m": float(error.max()),
        "path_length_m": float(distance[-1]),
        "drift_m_per_100m": float(np.mean(drifts)) if drifts else float("nan"),
        "end_drift_m_per_100m": float(error[-1] / max(distance[-1], 1e-9) * 100.0),
    }
