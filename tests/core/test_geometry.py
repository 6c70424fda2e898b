"""Oriented-box geometry checked against shapely polygons (an independent implementation)."""

from __future__ import annotations

import numpy as np
import pytest
import shapely
from hypothesis import given, settings
from hypothesis import strategies as st

from advsim_ros.core.geometry import box_corners, box_distance, boxes_overlap, circumradius, wrap_angle
from advsim_ros.core.types import ScenarioError

finite = st.floats(min_value=-20.0, max_value=20.0, allow_nan=False)
angle = st.floats(min_value=-10.0, max_value=10.0, allow_nan=False)
extent = st.floats(min_value=0.2, max_value=8.0, allow_nan=False)
box_strategy = st.tuples(finite, finite, angle, extent, extent)


def _polygon(box: np.ndarray) -> shapely.Polygon:
    x, y, yaw, length, width = box
    outline = shapely.box(-length / 2, -width / 2, length / 2, width / 2)
    rotated = shapely.affinity.rotate(outline, yaw, origin=(0.0, 0.0), use_radians=True)
    return shapely.affinity.translate(rotated, x, y)


def test_wrap_angle_maps_into_minus_pi_to_pi_and_keeps_the_direction() -> None:
    angles = np.linspace(-20.0, 20.0, 401)
    wrapped = wrap_angle(angles)
    assert np.all(wrapped >= -np.pi)
    assert np.all(wrapped < np.pi)
    np.testing.assert_allclose(np.cos(wrapped), np.cos(angles), atol=1e-12)
    np.testing.assert_allclose(np.sin(wrapped), np.sin(angles), atol=1e-12)


def test_box_corners_of_an_axis_aligned_box_are_counter_clockwise_from_front_left() -> None:
    corners = box_corners(np.array([1.0, 2.0, 0.0, 4.0, 2.0]))
    np.testing.assert_allclose(corners, [[3.0, 3.0], [-1.0, 3.0], [-1.0, 1.0], [3.0, 1.0]])


@settings(max_examples=200, deadline=None)
@given(box_strategy)
def test_box_corners_match_the_shapely_outline(values: tuple[float, ...]) -> None:
    box = np.array(values)
    corners = box_corners(box)
    polygon = shapely.Polygon(corners)
    assert polygon.is_valid
    assert polygon.exterior.is_ccw
    # Hausdorff distance, not the area of the symmetric difference: GEOS overlays of two coincident
    # polygons can fail (a square at yaw 8.757 rad gave 38 m^2 for identical outlines)
    assert shapely.hausdorff_distance(polygon, _polygon(box)) == pytest.approx(0.0, abs=1e-9)


@settings(max_examples=400, deadline=None)
@given(box_strategy, box_strategy)
def test_boxes_overlap_and_box_distance_agree_with_shapely(first: tuple[float, ...], second: tuple[float, ...]) -> None:
    a, b = np.array(first), np.array(second)
    poly_a, poly_b = _polygon(a), _polygon(b)
    gap = poly_a.distance(poly_b)
    # Skip numerically ambiguous near-touching pairs: either answer is right there.
    if 1e-7 < gap < 1e-6 or (gap == 0.0 and poly_a.intersection(poly_b).area < 1e-9):
        return
    assert bool(boxes_overlap(a, b)) == (gap == 0.0)
    assert float(box_distance(a, b)) == pytest.approx(gap, abs=1e-9)


def test_boxes_overlap_broadcasts_many_boxes_against_one() -> None:
    rng = np.random.default_rng(3)
    many = np.column_stack(
        [
            rng.uniform(-10, 10, 500),
            rng.uniform(-10, 10, 500),
            rng.uniform(-np.pi, np.pi, 500),
            rng.uniform(1, 6, 500),
            rng.uniform(0.5, 2.5, 500),
        ]
    )
    one = np.array([0.0, 0.0, 0.3, 4.5, 1.9])
    overlap = boxes_overlap(many, one[None, :])
    distance = box_distance(many, one)
    assert overlap.shape == (500,)
    assert distance.shape == (500,)
    expected = np.array([_polygon(box).intersects(_polygon(one)) for box in many])
    np.testing.assert_array_equal(overlap, expected)
    np.testing.assert_array_equal(distance == 0.0, expected)
    grid = boxes_overlap(many[:, None, :], many[None, :10, :])
    assert grid.shape == (500, 10)


def test_float32_boxes_stay_float32() -> None:
    boxes = np.array([[0.0, 0.0, 0.1, 4.0, 2.0], [3.0, 0.5, 1.0, 4.0, 2.0]], dtype=np.float32)
    assert box_corners(boxes).dtype == np.float32
    assert box_distance(boxes[0], boxes[1]).dtype == np.float32
    assert bool(boxes_overlap(boxes[0], boxes[1]))


def test_touching_boxes_overlap_and_have_zero_distance() -> None:
    a = np.array([0.0, 0.0, 0.0, 2.0, 2.0])
    b = np.array([2.0, 0.0, 0.0, 2.0, 2.0])
    assert bool(boxes_overlap(a, b))
    assert float(box_distance(a, b)) == 0.0


def test_circumradius_contains_every_corner() -> None:
    box = np.array([5.0, -3.0, 0.7, 4.0, 1.5])
    radius = circumradius(box)
    assert np.all(np.linalg.norm(box_corners(box) - box[:2], axis=-1) <= radius + 1e-12)


def test_boxes_with_the_wrong_last_dimension_are_rejected_by_name() -> None:
    with pytest.raises(ScenarioError, match=r"shape \(\.\.\., 5\)"):
        boxes_overlap(np.zeros((3, 4)), np.zeros(5))
