"""Per-sweep candidate boxes for the offline tracker, in the world frame.

The candidates come from the reference stack's ground removal and clustering detector
(``stacks/modular/ground.py``, ``detector.py``: lowest-return ground grid, BEV connected
components, L-shape fitting, completion of partly seen vehicles). Measured on KITTI 0000
against the labels (bench/bench_labelling.py, ``per_sweep_detector``), it finds most
vehicles per sweep but also many car-sized pieces of hedges and walls; the offline stages
(tracking over the whole log, smoothing, per-track size and gates) are what make labels
out of them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from advsim_ros.core.geometry import wrap_angle
from advsim_ros.core.types import ActorClass, FloatArray, IntArray
from advsim_ros.labelling.config import LabellingConfig
from advsim_ros.stacks.modular.detector import CLASS_ORDER, detect
from advsim_ros.stacks.modular.ground import split_ground


@dataclass(frozen=True, eq=False)
class Candidates:
    """Every candidate box of a log, world frame, one row per box."""

    frames: IntArray  # (K,) frame index of each box
    boxes: FloatArray  # (K, 5) x, y [m], yaw [rad], length, width [m]
    z: FloatArray  # (K,) box centre height [m]
    heights: FloatArray  # (K,) box height (long vehicles: the top of every return over the footprint) [m]
    classes: IntArray  # (K,) index into stacks.modular.detector.CLASS_ORDER
    confidences: FloatArray  # (K,) detector score in [0, 1]
    num_points: IntArray  # (K,) returns in the cluster
    sensor_xy: FloatArray  # (K, 2) the sensor's world position when the box was seen [m]
    lifts: FloatArray  # (K,) vehicles: how far the cluster's ground sits above the lowest ground nearby [m]

    @property
    def count(self) -> int:
        return int(self.frames.shape[0])

    def take(self, rows: IntArray) -> Candidates:
        return Candidates(
            self.frames[rows], self.boxes[rows], self.z[rows], self.heights[rows], self.classes[rows],
            self.confidences[rows], self.num_points[rows], self.sensor_xy[rows], self.lifts[rows],
        )  # fmt: skip


def _rigid_apply(transform: FloatArray, xyz: FloatArray) -> FloatArray:
    result: FloatArray = xyz @ transform[:3, :3].T + transform[:3, 3]
    return result


def _full_tops(xyz_ego: FloatArray, boxes: FloatArray, ground_z: FloatArray) -> FloatArray:
    """(K,) the 0.98 quantile of the height above ground of every return over each box's footprint [m].

    The ground split ignores returns more than ``max_object_height`` (3 m) above the ground (canopy,
    signs), so a long cluster's top says 3 m whether it is a 4 m truck or a 10 m facade; over its
    footprint, a facade, a tree or a hedge row under trees reaches higher than any road vehicle.
    """
    tops = np.zeros(boxes.shape[0])
    for index, (x, y, yaw, length, width) in enumerate(boxes.tolist()):
        near = np.abs(xyz_ego[:, 0] - x) + np.abs(xyz_ego[:, 1] - y) <= 0.75 * (length + width)
        local = xyz_ego[near, :2] - (x, y)
        cos, sin = np.cos(yaw), np.sin(yaw)
        along, across = local[:, 0] * cos + local[:, 1] * sin, -local[:, 0] * sin + local[:, 1] * cos
        inside = (np.abs(along) <= 0.5 * length) & (np.abs(across) <= 0.5 * width)
        above = xyz_ego[near, 2][inside] - ground_z[index]
        tops[index] = float(np.quantile(above, 0.98)) if above.size else 0.0
    return tops


def _nearby_ground(ground: FloatArray, centres: FloatArray, radius: float) -> FloatArray:
    """(K,) the 0.1 quantile of the heights of the ground returns within radius of each centre (ego frame) [m].

    The ground grid takes each 2 m cell's lowest return; behind a row of parked cars the road is hidden,
    so the lowest return there is the bottom of what shows above the cars (a hedge, a wall) and that
    "ground" is 1 m or more too high. The road beside the cars, a few metres away, is visible.
    """
    result = np.full(centres.shape[0], np.nan)
    if ground.shape[0] == 0:
        return result
    tree = cKDTree(ground[:, :2])
    for index, near in enumerate(tree.query_ball_point(centres, radius)):
        if len(near) >= 5:
            result[index] = float(np.quantile(ground[near, 2], 0.1))
    return result


def detect_sweep(
    xyz_sensor: FloatArray, world_T_ego: FloatArray, ego_T_sensor: FloatArray, frame: int, config: LabellingConfig
) -> Candidates:
    """Candidate boxes of one sweep (points (N, 3) in the sensor frame [m]) in the world frame."""
    xyz_ego = _rigid_apply(ego_T_sensor, np.asarray(xyz_sensor, dtype=np.float64)).astype(np.float32)
    split = split_ground(xyz_ego, config.ground)
    found = detect(split, config.ground, config.detector, ego_T_sensor[:2, 3])
    rotation = world_T_ego[:2, :2]
    centres = found.boxes[:, :2] @ rotation.T + world_T_ego[:2, 3]
    ego_yaw = float(np.arctan2(world_T_ego[1, 0], world_T_ego[0, 0]))
    boxes = np.column_stack([centres, wrap_angle(found.boxes[:, 2] + ego_yaw), found.boxes[:, 3:5]])
    sensor_xy = (world_T_ego @ ego_T_sensor)[:2, 3]
    # The detector scores a vehicle by how close its top is to a car's (~1.5 m): a truck, bus or tanker
    # would score ~0; a long vehicle is scored by its returns only, as the detector scores other classes.
    long = (found.classes == VEHICLE_CODE) & (found.boxes[:, 3] >= config.gates.long_vehicle_length)
    confidences = np.where(
        long, found.num_points / (found.num_points + config.detector.confidence_points), found.confidences
    )
    heights = found.heights.copy()
    lifts = np.zeros(found.count)
    vehicles = np.flatnonzero(found.classes == VEHICLE_CODE)
    if vehicles.size:
        ground = split.xyz[split.is_ground].astype(np.float64)
        cluster_ground = found.z[vehicles] - 0.5 * found.heights[vehicles]
        nearby = _nearby_ground(ground, found.boxes[vehicles, :2], config.gates.ground_radius)
        lifts[vehicles] = np.nan_to_num(cluster_ground - nearby)  # no ground seen nearby: no evidence
    if np.any(long):
        ground_z = found.z[long] - 0.5 * found.heights[long]
        heights[long] = _full_tops(xyz_ego.astype(np.float64), found.boxes[long], ground_z)
    return Candidates(
        frames=np.full(found.count, frame, dtype=np.int64),
        boxes=boxes.reshape(-1, 5),
        z=found.z + world_T_ego[2, 3],
        heights=heights,
        classes=found.classes,
        confidences=confidences,
        num_points=found.num_points,
        sensor_xy=np.tile(sensor_xy, (found.count, 1)),
        lifts=lifts,
    )


def concatenate(parts: list[Candidates]) -> Candidates:
    if not parts:
        empty = np.zeros(0)
        return Candidates(
            np.zeros(0, np.int64), np.zeros((0, 5)), empty, empty, np.zeros(0, np.int64), empty,
            np.zeros(0, np.int64), np.zeros((0, 2)), empty,
        )  # fmt: skip
    return Candidates(*(np.concatenate([getattr(part, name) for part in parts]) for name in _FIELDS))


_FIELDS = ("frames", "boxes", "z", "heights", "classes", "confidences", "num_points", "sensor_xy", "lifts")
VEHICLE_CODE = CLASS_ORDER.index(ActorClass.VEHICLE)
