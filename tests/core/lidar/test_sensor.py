"""Sensor model from the sweeps, beam rows, range images and normals."""

from __future__ import annotations

import numpy as np
import pytest

from advsim_ros.core.lidar.sensor import RangeImage, point_normals, scan_order_segments, spherical, xyz_of
from advsim_ros.core.lidar.sensor_estimation import SensorEstimationError, estimate_sensor_model
from advsim_ros.core.types import Scenario, Sweep
from advsim_ros.io.synthetic import SyntheticLog


def _without_ring(sweep: Sweep, rng: np.random.Generator | None = None) -> Sweep:
    names = [name for name in (sweep.points.dtype.names or ()) if name != "ring"]
    points = np.ascontiguousarray(sweep.points[names])
    if rng is not None:
        points = points[rng.permutation(points.shape[0])]
    return Sweep(sweep.stamp_ns, sweep.frame_id, points, sweep.sensor_pose)


def test_beams_and_azimuth_step_of_synthetic_sweeps_are_recovered_from_the_ring_field(
    synthetic_log: SyntheticLog,
) -> None:
    truth = synthetic_log.sensor
    beam_rows = estimate_sensor_model(synthetic_log.scenario.sweeps)
    estimated = beam_rows.sensor
    assert beam_rows.source == "ring_field"
    assert estimated.num_beams == truth.num_beams
    assert np.max(np.abs(np.rad2deg(estimated.beam_elevations - truth.beam_elevations))) < 0.01
    assert estimated.azimuth_resolution == pytest.approx(truth.azimuth_resolution, rel=1e-3)
    assert np.max(np.abs(beam_rows.beam_heights)) < 0.01  # one origin for every synthetic beam


def test_firing_order_gives_the_beams_when_there_is_no_ring_field(synthetic_log: SyntheticLog) -> None:
    sweeps = [_without_ring(sweep) for sweep in synthetic_log.scenario.sweeps[:8]]
    beam_rows = estimate_sensor_model(sweeps)
    assert beam_rows.source == "scan_order"
    assert beam_rows.sensor.num_beams == synthetic_log.sensor.num_beams
    rows = beam_rows.rows(sweeps[0].points, spherical(xyz_of(sweeps[0].points)))
    assert np.array_equal(rows, synthetic_log.scenario.sweeps[0].points["ring"])


def test_elevation_histogram_finds_the_beams_of_shuffled_sweeps(synthetic_log: SyntheticLog) -> None:
    rng = np.random.default_rng(0)
    sweeps = [_without_ring(sweep, rng) for sweep in synthetic_log.scenario.sweeps[:8]]
    beam_rows = estimate_sensor_model(sweeps)
    assert beam_rows.source == "elevation"
    truth = np.rad2deg(synthetic_log.sensor.beam_elevations)
    assert beam_rows.sensor.num_beams == truth.shape[0]
    assert np.max(np.abs(np.rad2deg(beam_rows.sensor.beam_elevations) - truth)) < 0.05


def test_kitti_sweeps_show_the_hdl64e_with_its_two_laser_blocks(kitti_scenario: Scenario) -> None:
    beam_rows = estimate_sensor_model(kitti_scenario.sweeps)
    sensor = beam_rows.sensor
    assert beam_rows.source == "scan_order"  # KITTI .bin files list the points beam after beam
    assert sensor.num_beams == 64
    assert np.rad2deg(sensor.beam_elevations[0]) == pytest.approx(2.0, abs=0.5)
    assert np.rad2deg(sensor.beam_elevations[-1]) == pytest.approx(-24.8, abs=0.5)
    assert np.rad2deg(sensor.azimuth_resolution) == pytest.approx(0.18, abs=0.01)
    # The upper and lower blocks' lasers sit at different heights (about 0.2 m and 0.12 m).
    assert np.median(beam_rows.beam_heights[:32]) == pytest.approx(0.2, abs=0.05)
    assert np.median(beam_rows.beam_heights[32:]) == pytest.approx(0.12, abs=0.05)


def test_estimation_refuses_sweeps_without_enough_points() -> None:
    with pytest.raises(SensorEstimationError, match="no sweeps"):
        estimate_sensor_model([])
    points = np.zeros(10, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4")])
    with pytest.raises(SensorEstimationError, match="valid points"):
        estimate_sensor_model([Sweep(0, "lidar", points, np.eye(4))])


def test_scan_order_cuts_one_beam_per_turn_from_the_start_angle() -> None:
    assert scan_order_segments(np.linspace(-1.0, 1.0, 100), scan_start=np.pi) is None  # less than a turn
    turn = np.linspace(0.0, 2.0 * np.pi, 50, endpoint=False) + 0.5
    azimuths = np.mod(np.concatenate([turn[5:], turn, turn]) + np.pi, 2.0 * np.pi) - np.pi  # the first turn starts late
    segments = scan_order_segments(azimuths, scan_start=0.45)
    assert segments is not None
    assert np.array_equal(np.bincount(segments), [45, 50, 50])
    valid = np.ones(azimuths.shape[0], dtype=bool)
    valid[60] = False  # a missing return at (0, 0, 0) has azimuth 0: it must not start a turn
    azimuths[60] = 0.0
    with_gap = scan_order_segments(azimuths, scan_start=0.45, valid=valid)
    assert with_gap is not None
    assert np.array_equal(np.bincount(with_gap), [45, 50, 50])


def test_range_image_keeps_every_point_and_field(synthetic_log: SyntheticLog) -> None:
    sweep = synthetic_log.scenario.sweeps[0]
    beam_rows = estimate_sensor_model(synthetic_log.scenario.sweeps)
    doubled = np.concatenate([sweep.points, sweep.points[:500]])  # two returns in the same cells
    for name in ("x", "y", "z"):
        doubled[name][-500:] *= 1.5  # farther along the same rays
    image = RangeImage.from_points(doubled, beam_rows)
    assert np.array_equal(np.sort(image.source_indices), np.arange(doubled.shape[0]))
    assert image.overflow.shape[0] == 500
    assert np.array_equal(
        np.sort(image.to_points(doubled), order=["ring", "x", "y", "z"]),
        np.sort(doubled, order=["ring", "x", "y", "z"]),
    )


def test_range_image_changes_move_points_along_their_own_ray(synthetic_log: SyntheticLog) -> None:
    sweep = synthetic_log.scenario.sweeps[0]
    beam_rows = estimate_sensor_model(synthetic_log.scenario.sweeps)
    image = RangeImage.from_points(sweep.points, beam_rows)
    row, column = np.argwhere(np.isfinite(image.ranges))[100]
    index = image.point_index[row, column]
    image.ranges[row, column] *= 2.0
    image.intensities[row, column] = 0.9
    other = tuple(np.argwhere(np.isfinite(image.ranges))[200])
    image.ranges[other] = np.inf  # a cell set to inf drops its point
    rebuilt = image.to_points(sweep.points)
    assert rebuilt.shape[0] == sweep.points.shape[0] - 1
    original = xyz_of(sweep.points[index : index + 1])[0]
    moved = rebuilt[np.flatnonzero(np.isclose(rebuilt["intensity"], 0.9))]
    assert moved.shape[0] >= 1
    candidates = xyz_of(moved)
    assert np.min(np.linalg.norm(candidates - 2.0 * original, axis=1)) < 1e-3
    assert moved["ring"][0] == sweep.points["ring"][index]


def test_normals_of_a_flat_road_point_up(synthetic_log: SyntheticLog) -> None:
    sweep = synthetic_log.scenario.sweeps[0]
    beam_rows = estimate_sensor_model(synthetic_log.scenario.sweeps)
    geometry = spherical(xyz_of(sweep.points))
    normals = point_normals(geometry, beam_rows.rows(sweep.points, geometry), beam_rows.sensor, geometry.ranges > 0)
    road = (np.abs(geometry.xyz[:, 2] + 1.73) < 0.03) & (geometry.ranges < 15.0) & (np.abs(geometry.xyz[:, 1]) < 3.0)
    known = np.linalg.norm(normals, axis=1) > 0.5
    assert np.count_nonzero(road & known) > 1000
    assert np.median(normals[road & known, 2]) > 0.99


def test_back_projected_cells_land_on_their_points(synthetic_log: SyntheticLog) -> None:
    sweep = synthetic_log.scenario.sweeps[0]  # rendered at cell centres, so back-projection is exact up to noise
    beam_rows = estimate_sensor_model(synthetic_log.scenario.sweeps)
    image = RangeImage.from_points(sweep.points, beam_rows)
    xyz, rows, columns = image.back_project()
    original = xyz_of(sweep.points[image.point_index[rows, columns]])
    assert xyz.shape[0] == np.count_nonzero(np.isfinite(image.ranges))
    assert np.percentile(np.linalg.norm(xyz - original, axis=1), 99) < 0.01
