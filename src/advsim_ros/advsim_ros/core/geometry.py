"""Planar geometry of oriented boxes in bird's-eye view.

A box is a float array of shape (..., 5) = [x, y, yaw, length, width]: centre x, y [m],
heading counter-clockwise from +x [rad], extent along the heading and across it [m].
Every function broadcasts over the leading dimensions, keeps float32 inputs in float32
(the feasibility pruning runs on millions of boxes), and treats boxes as closed sets:
touching boxes overlap and are at distance 0.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from advsim_ros.core.types import FloatArray, ScenarioError

AnyFloatArray = npt.NDArray[np.floating[Any]]
BoolArray = npt.NDArray[np.bool_]

BOX_DIM = 5  # [x, y, yaw, length, width]

# Corner order counter-clockwise starting front-left, in units of (length / 2, width / 2).
_CORNER_SIGNS = np.array([[1.0, 1.0], [-1.0, 1.0], [-1.0, -1.0], [1.0, -1.0]])


def _as_float(values: npt.ArrayLike) -> AnyFloatArray:
    array = np.asarray(values)
    if not np.issubdtype(array.dtype, np.floating):
        array = array.astype(np.float64)
    return array


def _as_boxes(name: str, boxes: npt.ArrayLike) -> AnyFloatArray:
    array = _as_float(boxes)
    if array.ndim < 1 or array.shape[-1] != BOX_DIM:
        raise ScenarioError(f"{name}: boxes must have shape (..., 5) = [x, y, yaw, length, width], got {array.shape}")
    return array


def wrap_angle(angles: npt.ArrayLike) -> AnyFloatArray:
    """Angles wrapped into [-pi, pi) [rad]."""
    array = _as_float(angles)
    result: AnyFloatArray = np.mod(array + np.pi, 2.0 * np.pi) - np.pi
    return result


def box_corners(boxes: npt.ArrayLike) -> AnyFloatArray:
    """(..., 4, 2) corner coordinates [m], counter-clockwise from the front-left corner."""
    array = _as_boxes("box_corners", boxes)
    cos, sin = np.cos(array[..., 2]), np.sin(array[..., 2])
    signs = _CORNER_SIGNS.astype(array.dtype)
    local_x = signs[:, 0] * (0.5 * array[..., 3, None])  # (..., 4)
    local_y = signs[:, 1] * (0.5 * array[..., 4, None])
    world_x = array[..., 0, None] + cos[..., None] * local_x - sin[..., None] * local_y
    world_y = array[..., 1, None] + sin[..., None] * local_x + cos[..., None] * local_y
    return np.stack([world_x, world_y], axis=-1)


def boxes_overlap(a: npt.ArrayLike, b: npt.ArrayLike) -> BoolArray:
    """Whether box a and box b intersect (separating-axis test; touching counts as overlap).

    Uses the four face normals of the two rectangles; a and b broadcast against each other.
    """
    box_a = _as_boxes("boxes_overlap a", a)
    box_b = _as_boxes("boxes_overlap b", b)
    return overlap_from_components(
        box_b[..., 0] - box_a[..., 0],
        box_b[..., 1] - box_a[..., 1],
        np.cos(box_a[..., 2]),
        np.sin(box_a[..., 2]),
        np.cos(box_b[..., 2]),
        np.sin(box_b[..., 2]),
        0.5 * box_a[..., 3],
        0.5 * box_a[..., 4],
        0.5 * box_b[..., 3],
        0.5 * box_b[..., 4],
    )


def overlap_from_components(
    dx: AnyFloatArray,
    dy: AnyFloatArray,
    cos_a: AnyFloatArray,
    sin_a: AnyFloatArray,
    cos_b: AnyFloatArray,
    sin_b: AnyFloatArray,
    half_length_a: AnyFloatArray | float,
    half_width_a: AnyFloatArray | float,
    half_length_b: AnyFloatArray | float,
    half_width_b: AnyFloatArray | float,
) -> BoolArray:
    """Separating-axis test on precomputed parts: centre offset b - a [m], headings as cos/sin, half extents [m].

    The building block of boxes_overlap, exposed so that callers testing many boxes
    against the same few boxes can reuse the cosines and sines.
    """
    # Relative rotation of b in a's frame: |cos| and |sin| of (yaw_b - yaw_a).
    cos_rel = np.abs(cos_a * cos_b + sin_a * sin_b)
    sin_rel = np.abs(cos_a * sin_b - sin_a * cos_b)
    along_a = np.abs(dx * cos_a + dy * sin_a)  # centre offset on a's axes
    across_a = np.abs(-dx * sin_a + dy * cos_a)
    along_b = np.abs(dx * cos_b + dy * sin_b)  # centre offset on b's axes
    across_b = np.abs(-dx * sin_b + dy * cos_b)
    separated = along_a > half_length_a + half_length_b * cos_rel + half_width_b * sin_rel
    separated |= across_a > half_width_a + half_length_b * sin_rel + half_width_b * cos_rel
    separated |= along_b > half_length_b + half_length_a * cos_rel + half_width_a * sin_rel
    separated |= across_b > half_width_b + half_length_a * sin_rel + half_width_a * cos_rel
    return np.logical_not(separated)


def _point_segment_distance(points: AnyFloatArray, starts: AnyFloatArray, ends: AnyFloatArray) -> AnyFloatArray:
    """Euclidean distance [m] from points (..., 2) to segments starts/ends (..., 2), broadcasting."""
    segment = ends - starts
    offset = points - starts
    length_sq = np.sum(segment * segment, axis=-1)
    safe_length_sq = np.where(length_sq > 0.0, length_sq, 1.0)
    fraction = np.clip(np.sum(offset * segment, axis=-1) / safe_length_sq, 0.0, 1.0)
    closest = starts + fraction[..., None] * segment
    result: AnyFloatArray = np.linalg.norm(points - closest, axis=-1)
    return result


def box_distance(a: npt.ArrayLike, b: npt.ArrayLike) -> AnyFloatArray:
    """Exact Euclidean gap [m] between the rectangles a and b; 0 when they overlap or touch.

    For two disjoint convex polygons the gap is attained between a vertex of one and an
    edge of the other, so the minimum over the 32 vertex-edge distances is exact.
    """
    box_a = _as_boxes("box_distance a", a)
    box_b = _as_boxes("box_distance b", b)
    corners_a = box_corners(box_a)  # (..., 4, 2)
    corners_b = box_corners(box_b)
    next_a = np.roll(corners_a, -1, axis=-2)
    next_b = np.roll(corners_b, -1, axis=-2)
    # Vertices of a (..., 4, 1, 2) against edges of b (..., 1, 4, 2), and the other way round.
    a_to_b = _point_segment_distance(corners_a[..., :, None, :], corners_b[..., None, :, :], next_b[..., None, :, :])
    b_to_a = _point_segment_distance(corners_b[..., :, None, :], corners_a[..., None, :, :], next_a[..., None, :, :])
    gap = np.minimum(a_to_b.min(axis=(-2, -1)), b_to_a.min(axis=(-2, -1)))
    result: AnyFloatArray = np.where(boxes_overlap(box_a, box_b), np.zeros_like(gap), gap)
    return result


def circumradius(boxes: npt.ArrayLike) -> AnyFloatArray:
    """(...,) radius [m] of the circle about the box centre that contains the whole box."""
    array = _as_boxes("circumradius", boxes)
    result: AnyFloatArray = 0.5 * np.hypot(array[..., 3], array[..., 4])
    return result


def bev_iou(a: npt.ArrayLike, b: npt.ArrayLike) -> AnyFloatArray:
    """(...,) bird's-eye-view intersection over union of boxes a and b [1], broadcasting; 0 for disjoint boxes.

    Exact polygon clipping (shapely), run only on the pairs that overlap.
    """
    import shapely  # only the IoU needs polygon clipping

    box_a = _as_boxes("bev_iou a", a)
    box_b = _as_boxes("bev_iou b", b)
    box_a, box_b = np.broadcast_arrays(box_a, box_b)
    iou = np.zeros(box_a.shape[:-1], dtype=np.result_type(box_a.dtype, box_b.dtype))
    overlapping = boxes_overlap(box_a, box_b)
    if not np.any(overlapping):
        return iou
    polygons_a = shapely.polygons(box_corners(box_a[overlapping]).astype(np.float64))
    polygons_b = shapely.polygons(box_corners(box_b[overlapping]).astype(np.float64))
    intersection = shapely.area(shapely.intersection(polygons_a, polygons_b))
    areas_a = box_a[overlapping][:, 3] * box_a[overlapping][:, 4]
    areas_b = box_b[overlapping][:, 3] * box_b[overlapping][:, 4]
    iou[overlapping] = intersection / (areas_a + areas_b - intersection)
    return iou


SAME_POINT = 1e-6  # points of a path closer than this do not give it a direction [m]


def tangent_headings(xy: npt.ArrayLike, fallback: npt.ArrayLike) -> FloatArray:
    """(N,) heading of a path's tangent at each of its (N, 2) points [rad], for poses that carry none.

    At an inner point the direction from the point before to the point after (exact on an evenly
    sampled circle or line), at the ends that of the end segment. A point the path does not move
    around (a standstill) takes the heading of the nearest point that has one, the earlier on a tie;
    a path that never moves keeps ``fallback`` (N,). The path is taken as driven forwards: a
    reversing stretch gets headings a half turn from the vehicle's.
    """
    points = np.asarray(xy, dtype=np.float64)
    kept = np.array(fallback, dtype=np.float64)
    count = points.shape[0]
    if count < 2:
        return kept
    after = np.vstack([points[1:], points[-1:]])
    before = np.vstack([points[:1], points[:-1]])
    chord = after - before
    moving = np.hypot(chord[:, 0], chord[:, 1]) > SAME_POINT
    if not np.any(moving):
        return kept
    headings = np.arctan2(chord[:, 1], chord[:, 0])
    index = np.arange(count)
    earlier = np.maximum.accumulate(np.where(moving, index, -1))  # nearest moving point at or before
    later = np.minimum.accumulate(np.where(moving, index, count)[::-1])[::-1]  # ... at or after
    use_later = (earlier < 0) | ((later < count) & (later - index < index - earlier))
    nearest = np.where(use_later, later, earlier)
    result: FloatArray = headings[nearest]
    return result
