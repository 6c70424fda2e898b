"""The plan on the wire: a nav_msgs/Path without orientations gets its headings from its tangent."""

from __future__ import annotations

import math

import numpy as np

from advsim_ros.contract import codec, names
from advsim_ros.contract.plan import path_msg, plan_from_path
from advsim_ros.core.geometry import tangent_headings
from advsim_ros.core.types import Plan

S = 5_000_000_000  # the sweep's stamp [ns]
RADIUS = 20.0  # [m]
COUNT = 11  # poses on the quarter circle: 9 degrees apart
STEP_ANGLE = (math.pi / 2) / (COUNT - 1)  # [rad]


def _quarter_circle() -> tuple[np.ndarray, np.ndarray]:
    """Positions on a left-turning quarter circle from the origin heading +x, and the true headings there."""
    angle = np.linspace(0.0, math.pi / 2, COUNT)
    return RADIUS * np.column_stack([np.sin(angle), 1.0 - np.cos(angle)]), angle


def _wire(xy: np.ndarray, yaws: np.ndarray) -> object:
    """The path as the scorer receives it: built, CDR-encoded and decoded."""
    stamps = S + 100_000_000 * np.arange(1, xy.shape[0] + 1, dtype=np.int64)
    return codec.decode(codec.encode(path_msg(Plan(stamps, xy, yaws), S, "world")), names.PATH)


def test_a_path_whose_orientations_are_all_identity_gets_tangent_headings() -> None:
    xy, truth = _quarter_circle()
    plan = plan_from_path(_wire(xy, np.zeros(COUNT)))  # yaw 0 everywhere: identity quaternions
    # inner poses: the chord from the pose before to the one after is parallel to the circle's tangent
    np.testing.assert_allclose(plan.yaws[1:-1], truth[1:-1], atol=1e-9)
    # the ends take their end segment's direction: half a step's turn off
    np.testing.assert_allclose(plan.yaws[[0, -1]], truth[[0, -1]] + [0.5, -0.5] * np.array(STEP_ANGLE), atol=1e-9)


def test_a_path_with_real_orientations_keeps_them() -> None:
    xy, truth = _quarter_circle()
    crabbing = np.full(COUNT, 0.3)  # headings that are not the tangent's: the stack's word stands
    np.testing.assert_allclose(plan_from_path(_wire(xy, crabbing)).yaws, crabbing, atol=1e-12)
    np.testing.assert_allclose(plan_from_path(_wire(xy, truth)).yaws, truth, atol=1e-12)


def test_a_standstill_inside_a_path_takes_the_nearest_heading_and_a_path_that_never_moves_keeps_its_own() -> None:
    xy = np.array([[0.0, 0.0], [0.0, 0.0], [1.0, 1.0], [2.0, 2.0], [2.0, 2.0], [2.0, 2.0], [2.0, 3.0]])
    np.testing.assert_allclose(
        tangent_headings(xy, np.zeros(7)), [math.pi / 4] * 4 + [math.pi / 4, math.pi / 2, math.pi / 2], atol=1e-12
    )
    np.testing.assert_array_equal(plan_from_path(_wire(np.zeros((4, 2)), np.zeros(4))).yaws, np.zeros(4))
