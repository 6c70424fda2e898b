"""A stack's answer in any shape becomes the contract's plan by the stated rules (adapters.plans)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from advsim_ros.adapters.messages import plan_poses
from advsim_ros.adapters.plans import (
    PlanarTransform,
    Poses,
    contract_plan,
    enu_of,
    frame_transform,
    geodetic_of,
)
from advsim_ros.adapters.profile import Datum, PlanOutput
from advsim_ros.contract import names
from advsim_ros.contract.codec import header_msg, message

S = 5_000_000_000  # the sweep's stamp [ns]
STEP = 100_000_000


def _line(length: float, spacing: float = 1.0, yaw: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    d = np.arange(0.0, length + 1e-9, spacing)
    return np.column_stack([d * math.cos(yaw), d * math.sin(yaw)]), np.full(d.shape, yaw)


def test_a_timed_plan_on_the_contract_grid_is_kept_as_it_is() -> None:
    stamps = S + STEP * np.arange(1, 51)
    xy = np.column_stack([np.arange(1, 51) * 0.7, np.zeros(50)])
    plan = contract_plan(Poses(xy, np.zeros(50), stamps_ns=stamps), S, S, 0.0, PlanOutput(), PlanarTransform())
    np.testing.assert_array_equal(plan.stamps_ns, stamps)
    np.testing.assert_allclose(plan.xy, xy)


def test_a_spatial_path_is_driven_at_the_egos_speed_and_stops_where_it_ends() -> None:
    xy, yaws = _line(20.0)
    plan = contract_plan(Poses(xy, yaws), S, S, 8.0, PlanOutput(), PlanarTransform())
    times = (plan.stamps_ns - S) / 1e9
    expected = np.minimum(8.0 * times, 20.0)
    np.testing.assert_allclose(plan.xy[:, 0], expected, atol=1e-6)
    assert plan.xy.shape == (50, 2)


def test_the_speed_rule_accelerates_from_the_egos_speed_up_to_the_limit() -> None:
    xy, yaws = _line(200.0, 0.5)
    output = PlanOutput(acceleration=2.0, max_speed=6.0)
    plan = contract_plan(Poses(xy, yaws), S, S, 0.0, output, PlanarTransform())
    times = (plan.stamps_ns - S) / 1e9
    accelerating = times <= 3.0  # 2 m/s^2 for 3 s reaches 6 m/s
    np.testing.assert_allclose(plan.xy[accelerating, 0], times[accelerating] ** 2, atol=1e-3)
    np.testing.assert_allclose(plan.xy[~accelerating, 0], 9.0 + 6.0 * (times[~accelerating] - 3.0), atol=1e-3)


def test_the_stacks_own_speeds_set_the_times_and_a_zero_speed_is_a_stop() -> None:
    xy, yaws = _line(30.0)
    speeds = np.full(31, 5.0)
    speeds[10:] = 0.0  # stops at 10 m
    plan = contract_plan(Poses(xy, yaws, speeds=speeds), S, S, 99.0, PlanOutput(), PlanarTransform())
    times = (plan.stamps_ns - S) / 1e9
    before = times <= 1.8  # 9 m at 5 m/s; the last metre is braked (mean speed 2.5 m/s)
    np.testing.assert_allclose(plan.xy[before, 0], 5.0 * times[before], atol=1e-6)
    assert plan.xy[-1, 0] == pytest.approx(10.0)


def test_a_plan_made_after_the_sweep_is_read_from_its_own_time() -> None:
    xy, yaws = _line(60.0)
    made = S + 50_000_000  # a timer-driven stack planned 50 ms after the sweep
    plan = contract_plan(Poses(xy, yaws), made, S, 10.0, PlanOutput(), PlanarTransform())
    assert plan.stamps_ns[0] == S + STEP
    assert plan.xy[0, 0] == pytest.approx(0.5)  # 50 ms into the plan at 10 m/s
    assert plan.xy[9, 0] == pytest.approx(9.5)


def test_a_plan_in_another_frame_is_moved_into_the_world() -> None:
    xy, yaws = _line(60.0)
    output = PlanOutput(frame_id="map", frame_origin="static", origin_pose=(100.0, -20.0, math.pi / 2))
    transform = frame_transform(output, None, None)
    plan = contract_plan(Poses(xy, yaws), S, S, 10.0, output, transform)
    assert plan.xy[0] == pytest.approx([100.0, -19.0])
    assert plan.yaws[0] == pytest.approx(math.pi / 2)


def test_geodetic_points_round_trip_and_the_first_fix_anchors_the_frame() -> None:
    datum = Datum(49.011, 8.4168, 112.0)
    latitude, longitude, altitude = geodetic_of(datum, 120.0, -45.0, 1.5)
    np.testing.assert_allclose(enu_of(datum, latitude, longitude, altitude), [120.0, -45.0, 1.5], atol=1e-6)
    first = frame_transform(PlanOutput(frame_id="map", frame_origin="first_fix"), datum, np.array([120.0, -45.0]))
    assert (first.x, first.y, first.yaw) == (120.0, -45.0, 0.0)
    other = Datum(latitude, longitude, altitude)
    anchored = frame_transform(PlanOutput(frame_id="enu", frame_origin="datum", origin_datum=other), datum, None)
    assert (anchored.x, anchored.y) == (pytest.approx(120.0, abs=1e-6), pytest.approx(-45.0, abs=1e-6))


def test_unusable_answers_are_refused() -> None:
    with pytest.raises(ValueError, match="no poses"):
        Poses(np.zeros((0, 2)), np.zeros(0))
    with pytest.raises(ValueError, match="NaN"):
        Poses(np.array([[0.0, math.nan]]), np.zeros(1))
    with pytest.raises(ValueError, match="not strictly increasing"):
        Poses(np.zeros((2, 2)), np.zeros(2), stamps_ns=np.array([5, 5]))
    with pytest.raises(ValueError, match="no fix was sent"):
        frame_transform(PlanOutput(frame_id="map", frame_origin="first_fix"), Datum(0.0, 0.0), None)


def test_a_plan_frame_is_found_through_tf_in_either_direction_and_over_several_links() -> None:
    from advsim_ros.adapters.plans import chained

    def pose(x: float, y: float, yaw: float) -> np.ndarray:
        matrix = np.eye(4)
        matrix[:2, :2] = [[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]]
        matrix[:2, 3] = [x, y]
        return matrix

    edges = {("map", "world"): pose(-10.0, 0.0, 0.0), ("map", "odom"): pose(0.0, 5.0, math.pi / 2)}
    found = chained(edges, "world", "odom")
    assert found is not None
    np.testing.assert_allclose(found[:2, 3], [10.0, 5.0], atol=1e-9)
    output = PlanOutput(frame_id="odom", frame_origin="tf")
    transform = frame_transform(output, None, None, ("world", edges))
    assert (transform.x, transform.y, transform.yaw) == pytest.approx((10.0, 5.0, math.pi / 2))
    with pytest.raises(ValueError, match="no transform between world and base"):
        frame_transform(PlanOutput(frame_id="base", frame_origin="tf"), None, None, ("world", edges))


def _quarter_circle(radius: float = 20.0, spacing: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Poses every `spacing` metres of arc on a left-turning quarter circle from the origin heading +x."""
    angle = np.arange(0.0, math.pi / 2 + 1e-9, spacing / radius)
    return radius * np.column_stack([np.sin(angle), 1.0 - np.cos(angle)]), angle


def _path_msg(xy: np.ndarray, yaws: np.ndarray | None) -> object:
    """A spatial nav_msgs/Path (poses unstamped); yaws None: positions only (identity orientations)."""
    headings = np.zeros(xy.shape[0]) if yaws is None else yaws
    poses = [
        message(
            names.POSE_STAMPED,
            header=header_msg(0, "map"),
            pose=message(
                names.POSE,
                position=message(names.POINT, x=float(x), y=float(y), z=0.0),
                orientation=message(names.QUATERNION, x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2)),
            ),
        )
        for (x, y), yaw in zip(xy.tolist(), headings.tolist(), strict=True)
    ]
    return message(names.PATH, header=header_msg(S, "map"), poses=poses)


def test_a_spatial_path_without_orientations_gets_the_tangent_headings_of_its_curve() -> None:
    xy, _ = _quarter_circle()
    poses = plan_poses("spatial_path", _path_msg(xy, None))
    assert not poses.oriented
    plan = contract_plan(poses, S, S, 5.0, PlanOutput(type="spatial_path"), PlanarTransform())
    driven = 5.0 * (plan.stamps_ns - S) / 1e9  # [m] along the arc; the heading of a circle is arc / radius
    past_first_pose = driven >= 1.0  # the first pose takes its segment's direction: half a step's turn off
    np.testing.assert_allclose(plan.yaws[past_first_pose], driven[past_first_pose] / 20.0, atol=1e-3)
    assert plan.yaws[0] == pytest.approx(0.0375, abs=1e-3)  # halfway between 0.025 and the exact 0.05 at 1 m
    assert plan.yaws[-1] == pytest.approx(1.25, abs=1e-3)  # 25 m into the turn: not the yaw 0 of identity quaternions


def test_real_orientations_are_kept_unless_the_profile_asks_for_the_tangent() -> None:
    xy, _ = _quarter_circle()
    crabbing = np.full(xy.shape[0], 0.5)  # orientations the stack did give, not the tangent's
    poses = plan_poses("spatial_path", _path_msg(xy, crabbing))
    assert poses.oriented
    kept = contract_plan(poses, S, S, 5.0, PlanOutput(type="spatial_path"), PlanarTransform())
    np.testing.assert_allclose(kept.yaws, 0.5, atol=1e-12)
    forced = contract_plan(poses, S, S, 5.0, PlanOutput(type="spatial_path", headings="tangent"), PlanarTransform())
    driven = 5.0 * (forced.stamps_ns - S) / 1e9
    np.testing.assert_allclose(forced.yaws[driven >= 1.0], driven[driven >= 1.0] / 20.0, atol=1e-3)
