"""Clustering detector: oriented 3-D boxes from the object returns of one sweep.

1. Object returns are rasterised into a BEV occupancy grid; 8-connected components are
   the clusters (scipy.ndimage.label), so clustering costs one pass over the grid.
2. Each cluster's heading comes from L-shape fitting with the closeness criterion
   (X. Zhang, W. Xu, C. Dong, J. M. Dolan, "Efficient L-shape fitting for vehicle
   detection using laser scanners", IV 2017), evaluated for every cluster and every
   candidate heading at once on the cluster's occupied cells.
3. A vehicle seen from one side shows only part of its outline: its box is grown to the
   prior car size away from the sensor (the hidden side is the far one).
4. Classes come from the box size and height; a vehicle's confidence from its number of
   returns, how much of its box was seen and how close its height is to a car's (walls
   and hedges cut into car-sized pieces are taller or flatter).
Everything works in the ego frame; the stack moves the boxes into the world frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy import ndimage

from advsim_ros.core.types import ActorClass, FloatArray
from advsim_ros.stacks.modular.config import DetectorConfig, GroundConfig
from advsim_ros.stacks.modular.ground import GroundSplit

IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]

CLASS_ORDER = (ActorClass.VEHICLE, ActorClass.PEDESTRIAN, ActorClass.CYCLIST, ActorClass.OTHER)
_CLASS_CODE = {actor_class: code for code, actor_class in enumerate(CLASS_ORDER)}
_EIGHT_CONNECTED = np.ones((3, 3), dtype=bool)


@dataclass(frozen=True, eq=False)
class Detections:
    """Boxes found in one sweep, in the ego frame."""

    boxes: FloatArray  # (K, 5) [x, y, yaw, length, width] [m, m, rad, m, m]
    z: FloatArray  # (K,) box centre height [m]
    heights: FloatArray  # (K,) box height (ground to highest return) [m]
    classes: IntArray  # (K,) index into CLASS_ORDER
    confidences: FloatArray  # (K,) scores in [0, 1]
    num_points: IntArray  # (K,) returns in the cluster

    @property
    def count(self) -> int:
        return int(self.boxes.shape[0])

    def actor_classes(self) -> tuple[ActorClass, ...]:
        return tuple(CLASS_ORDER[int(code)] for code in self.classes)

    def select(self, keep: BoolArray) -> Detections:
        return Detections(
            self.boxes[keep],
            self.z[keep],
            self.heights[keep],
            self.classes[keep],
            self.confidences[keep],
            self.num_points[keep],
        )

    @staticmethod
    def empty() -> Detections:
        return Detections(
            np.zeros((0, 5)), np.zeros(0), np.zeros(0), np.zeros(0, np.int64), np.zeros(0), np.zeros(0, np.int64)
        )


def _to_edge(values: FloatArray, low: FloatArray, high: FloatArray, sizes: IntArray) -> FloatArray:
    """(M, A) distance of each value to the nearer end of its cluster's [low, high] (clusters of `sizes` rows)."""
    result: FloatArray = np.repeat(high, sizes, axis=0)
    result -= values
    np.minimum(result, values - np.repeat(low, sizes, axis=0), out=result)
    return result


def _fit_headings(
    cell_xy: FloatArray, cluster: IntArray, count: int, config: DetectorConfig
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Per cluster: heading of the first box axis [rad] in [0, pi/2), box centre (K, 2) [m], extents (K, 2) [m].

    cell_xy (M, 2) are occupied cell centres sorted by cluster (M, ints 0..K-1, every one present).
    """
    starts = np.flatnonzero(np.r_[True, cluster[1:] != cluster[:-1]])
    sizes = np.diff(np.r_[starts, cluster.shape[0]])
    mean = np.add.reduceat(cell_xy, starts, axis=0) / sizes[:, None]
    # Clusters are contiguous runs of rows: per-cluster values reach their rows by np.repeat (cheaper than
    # gathering), and the (M, A) intermediates are reused in place.
    local = cell_xy - np.repeat(mean, sizes, axis=0)  # centred per cluster, for precision
    angles = np.arange(config.angle_steps) * (0.5 * np.pi / config.angle_steps)
    cos, sin = np.cos(angles), np.sin(angles)
    along = local[:, :1] * cos + local[:, 1:] * sin  # (M, A) coordinate on the first axis
    across = -local[:, :1] * sin + local[:, 1:] * cos  # (M, A) on the second axis
    low_along = np.minimum.reduceat(along, starts, axis=0)
    high_along = np.maximum.reduceat(along, starts, axis=0)
    low_across = np.minimum.reduceat(across, starts, axis=0)
    high_across = np.maximum.reduceat(across, starts, axis=0)
    closeness = _to_edge(along, low_along, high_along, sizes)
    np.minimum(closeness, _to_edge(across, low_across, high_across, sizes), out=closeness)
    np.maximum(closeness, config.closeness_floor, out=closeness)
    np.divide(1.0, closeness, out=closeness)
    score = np.add.reduceat(closeness, starts, axis=0)  # (K, A)
    best = np.argmax(score, axis=1)
    rows = np.arange(count)
    heading = angles[best]
    middle_along = 0.5 * (low_along[rows, best] + high_along[rows, best])
    middle_across = 0.5 * (low_across[rows, best] + high_across[rows, best])
    centre = mean + np.stack(
        [middle_along * cos[best] - middle_across * sin[best], middle_along * sin[best] + middle_across * cos[best]],
        axis=1,
    )
    # Cell centres span one cell less than the returns they stand for.
    extent = np.stack(
        [high_along[rows, best] - low_along[rows, best], high_across[rows, best] - low_across[rows, best]]
    )
    return heading, centre, extent.T + config.cell_size


def _complete(
    centre: FloatArray, axis: FloatArray, extent: FloatArray, prior: float | FloatArray, sensor_xy: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Grow extents (K,) along unit axes (K, 2) to at least `prior`, keeping the edge facing the sensor."""
    grown = np.maximum(extent, prior)
    sensor_side = np.sign(np.sum((sensor_xy - centre) * axis, axis=1))  # +1: the sensor is on the +axis side
    shift = -sensor_side * 0.5 * (grown - extent)
    return centre + shift[:, None] * axis, grown


def _in(values: FloatArray, bounds: tuple[float, ...]) -> BoolArray:
    result: BoolArray = (values >= bounds[0]) & (values <= bounds[1])
    return result


def detect(split: GroundSplit, ground: GroundConfig, config: DetectorConfig, sensor_xy: FloatArray) -> Detections:
    """Boxes of the clusters of object returns (ego frame); sensor_xy (2,) is the LiDAR's position [m]."""
    # take() of the object returns: boolean indexing of the (N, 3) sweep is several times slower.
    objects = np.flatnonzero(split.is_object)
    if objects.shape[0] == 0:
        return Detections.empty()
    points = split.xyz.take(objects, axis=0)
    heights = split.height.take(objects)
    cell = config.cell_size
    x_min, y_min = ground.range_x[0], ground.range_y[0]
    columns = int(np.ceil((ground.range_x[1] - x_min) / cell))
    rows = int(np.ceil((ground.range_y[1] - y_min) / cell))
    column = np.minimum(((points[:, 0] - x_min) / cell).astype(np.int64), columns - 1)
    row = np.minimum(((points[:, 1] - y_min) / cell).astype(np.int64), rows - 1)
    point_cell = row * columns + column
    occupied = np.zeros(rows * columns, dtype=bool)
    occupied[point_cell] = True
    labels, num_labels = ndimage.label(occupied.reshape(rows, columns), structure=_EIGHT_CONNECTED)
    flat_labels = labels.ravel()
    point_label = flat_labels.take(point_cell)
    counts = np.bincount(point_label, minlength=num_labels + 1)
    top = np.zeros(num_labels + 1, dtype=np.float32)
    np.maximum.at(top, point_label, heights)
    ground_z = np.bincount(point_label, weights=points[:, 2] - heights, minlength=num_labels + 1) / np.maximum(
        counts, 1
    )
    # The occupied cells in row-major order (the few thousand that are labelled, not the whole grid) and
    # each label's bounding box from them, as ndimage.find_objects would give it.
    cells = np.flatnonzero(occupied)
    cell_label = flat_labels.take(cells)
    cell_rows, cell_columns = np.divmod(cells, columns)
    low = np.full((num_labels + 1, 2), max(rows, columns), dtype=np.int64)
    high = np.full((num_labels + 1, 2), -1, dtype=np.int64)
    np.minimum.at(low, cell_label, np.column_stack([cell_rows, cell_columns]))
    np.maximum.at(high, cell_label, np.column_stack([cell_rows, cell_columns]))
    spans = np.zeros((num_labels + 1, 2))
    spans[1:] = (high[1:] - low[1:] + 1) * cell
    candidate = (counts >= config.min_points) & (top >= config.min_top_height)
    candidate &= np.hypot(spans[:, 0], spans[:, 1]) <= config.max_footprint
    candidate[0] = False
    candidate_ids = np.flatnonzero(candidate)
    count = int(candidate_ids.shape[0])
    if count == 0:
        return Detections.empty()
    remap = np.full(num_labels + 1, -1, dtype=np.int64)
    remap[candidate_ids] = np.arange(count)
    cell_cluster = remap[cell_label]
    keep = cell_cluster >= 0
    order = np.argsort(cell_cluster[keep], kind="stable")
    cell_cluster = cell_cluster[keep][order]
    cell_xy = np.stack(
        [x_min + (cell_columns[keep][order] + 0.5) * cell, y_min + (cell_rows[keep][order] + 0.5) * cell], axis=1
    )
    heading, centre, extent = _fit_headings(cell_xy, cell_cluster, count, config)

    # Which fitted axis is the length: the longer one when it is longer than a car is wide,
    # else (a car seen end-on) the one pointing along the line of sight.
    first_axis = np.stack([np.cos(heading), np.sin(heading)], axis=1)
    second_axis = np.stack([-np.sin(heading), np.cos(heading)], axis=1)
    sight = centre - sensor_xy
    sight /= np.maximum(np.linalg.norm(sight, axis=1, keepdims=True), 1e-6)
    long_first = np.where(
        np.max(extent, axis=1) > config.vehicle_prior[1] + 0.5,
        extent[:, 0] >= extent[:, 1],
        np.abs(np.sum(first_axis * sight, axis=1)) >= np.abs(np.sum(second_axis * sight, axis=1)),
    )
    yaw = np.where(long_first, heading, heading + 0.5 * np.pi)
    length_axis = np.where(long_first[:, None], first_axis, second_axis)
    width_axis = np.where(long_first[:, None], second_axis, -first_axis)
    seen_length = np.where(long_first, extent[:, 0], extent[:, 1])
    seen_width = np.where(long_first, extent[:, 1], extent[:, 0])

    top_k = top[candidate_ids].astype(np.float64)
    points_k = counts[candidate_ids]
    vehicle_shape = _in(top_k, config.vehicle_height) & (seen_length <= config.vehicle_length[1])
    vehicle_shape &= seen_width <= config.vehicle_width[1]
    vehicle_shape &= (points_k >= config.vehicle_min_points) & (seen_length >= config.vehicle_min_extent)
    # A bicycle seen end-on or from the side is narrow; a car shows its width unless seen broadside.
    vehicle_shape &= (seen_width >= config.vehicle_min_seen_width) | (seen_length > config.cyclist_length[1])
    length, width = seen_length.copy(), seen_width.copy()
    if config.complete_vehicles:
        grown_centre, grown_length = _complete(centre, length_axis, seen_length, config.vehicle_prior[0], sensor_xy)
        grown_centre, grown_width = _complete(grown_centre, width_axis, seen_width, config.vehicle_prior[1], sensor_xy)
        centre = np.where(vehicle_shape[:, None], grown_centre, centre)
        length = np.where(vehicle_shape, grown_length, length)
        width = np.where(vehicle_shape, grown_width, width)
    is_vehicle = vehicle_shape & _in(length, config.vehicle_length) & _in(width, config.vehicle_width)
    person_height = _in(top_k, config.pedestrian_height)
    is_pedestrian = ~is_vehicle & person_height & (np.maximum(length, width) <= config.pedestrian_footprint)
    is_cyclist = ~is_vehicle & ~is_pedestrian & person_height & _in(length, config.cyclist_length)
    is_cyclist &= width <= config.pedestrian_footprint
    classes = np.full(count, _CLASS_CODE[ActorClass.OTHER], dtype=np.int64)
    classes[is_vehicle] = _CLASS_CODE[ActorClass.VEHICLE]
    classes[is_pedestrian] = _CLASS_CODE[ActorClass.PEDESTRIAN]
    classes[is_cyclist] = _CLASS_CODE[ActorClass.CYCLIST]

    point_score = points_k / (points_k + config.confidence_points)
    seen_fraction = np.clip(seen_length * seen_width / np.maximum(length * width, 1e-6), 0.0, 1.0)
    # Cars are about 1.5 m tall: clusters much taller (walls, hedges, vans) or flatter score lower.
    height_score = np.exp(-0.5 * ((top_k - config.vehicle_typical_height[0]) / config.vehicle_typical_height[1]) ** 2)
    vehicle_score = point_score * (0.5 + 0.5 * np.sqrt(seen_fraction)) * height_score
    confidence = np.where(is_vehicle, vehicle_score, point_score)
    detections = Detections(
        boxes=np.stack([centre[:, 0], centre[:, 1], np.angle(np.exp(1j * yaw)), length, width], axis=1),
        z=ground_z[candidate_ids] + 0.5 * top_k,
        heights=top_k,
        classes=classes,
        confidences=confidence,
        num_points=points_k.astype(np.int64),
    )
    wanted = np.isin(classes, [_CLASS_CODE[ActorClass(name)] for name in config.only_classes])
    return detections.select(wanted)
