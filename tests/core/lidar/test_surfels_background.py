"""Surfels from merged points, the ground grid and its fill, carving what moved, the on-disk cache."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from advsim_ros.core.digest import Digest
from advsim_ros.core.lidar.background import SweepDepth, build_background, carve_moving
from advsim_ros.core.lidar.cache import load_arrays, save_arrays
from advsim_ros.core.lidar.config import ResimConfig
from advsim_ros.core.lidar.raycast import SurfaceCaster
from advsim_ros.core.lidar.sensor import BeamRows, azimuth_columns, spherical
from advsim_ros.core.lidar.surfels import PointSamples, surfels_from_samples, voxel_merge
from advsim_ros.core.types import SensorModel

UP = np.array([0.0, 0.0, 1.0])


def _plane(rng: np.random.Generator, count: int, size: float, hole: float = 0.0) -> PointSamples:
    xy = rng.uniform(-size, size, (count, 2))
    xy = xy[np.max(np.abs(xy), axis=1) >= hole]  # a square hole in the middle
    xyz = np.column_stack([xy, rng.normal(0.0, 0.005, xy.shape[0])])
    normals = np.tile(UP, (xy.shape[0], 1)) + rng.normal(0.0, 0.05, (xy.shape[0], 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    return PointSamples.of_points(xyz, np.full(xy.shape[0], 0.3), normals, np.array([0.0, 0.0, 1.7]))


def test_voxel_merge_keeps_weighted_means_so_merging_in_chunks_changes_nothing() -> None:
    rng = np.random.default_rng(0)
    samples = _plane(rng, 4000, 1.0)
    at_once = voxel_merge(samples, 0.1)
    half = samples.count // 2
    first = PointSamples(
        samples.xyz[:half],
        samples.intensity[:half],
        samples.normal_sum[:half],
        samples.view_sum[:half],
        samples.weight[:half],
    )
    second = PointSamples(
        samples.xyz[half:],
        samples.intensity[half:],
        samples.normal_sum[half:],
        samples.view_sum[half:],
        samples.weight[half:],
    )
    in_chunks = voxel_merge(PointSamples.concatenate([voxel_merge(first, 0.1), voxel_merge(second, 0.1)]), 0.1)
    order_a, order_b = np.lexsort(at_once.xyz.T), np.lexsort(in_chunks.xyz.T)
    assert np.allclose(at_once.xyz[order_a], in_chunks.xyz[order_b])
    assert np.allclose(at_once.weight[order_a], in_chunks.weight[order_b])
    assert at_once.weight.sum() == samples.count


def test_surfels_of_a_plane_face_up_and_close_its_gaps() -> None:
    rng = np.random.default_rng(1)
    surfels = surfels_from_samples(_plane(rng, 20000, 2.0), voxel_size=0.08, size_scale=0.85, max_half_size=0.25)
    assert np.median(np.abs(surfels.normals[:, 2])) > 0.99
    caster = SurfaceCaster(surfels.surface())
    targets = np.column_stack([rng.uniform(-1.5, 1.5, (500, 2)), np.zeros(500)])
    origin = np.array([0.0, 0.0, 1.7])
    directions = targets - origin
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    hits = caster.cast(origin, directions)
    hit = np.isfinite(hits.ranges)
    assert np.mean(hit) > 0.99
    assert np.max(np.abs(hits.ranges[hit] - np.linalg.norm(targets - origin, axis=1)[hit])) < 0.05


def test_a_lone_return_gets_no_surfel() -> None:
    rng = np.random.default_rng(2)
    plane = _plane(rng, 5000, 1.0)
    stray = PointSamples.of_points(
        np.array([[0.0, 0.0, 3.0]]), np.array([0.5]), np.array([[0.0, 0.0, 0.0]]), np.zeros(3)
    )
    surfels = surfels_from_samples(PointSamples.concatenate([plane, stray]), 0.08, 0.75, 0.25)
    assert surfels.centers[:, 2].max() < 0.1


def test_ground_hidden_under_a_parked_car_is_filled_at_the_ground_height() -> None:
    rng = np.random.default_rng(3)
    config = ResimConfig()
    background = build_background(_plane(rng, 60000, 6.0, hole=1.2), [], _beam_rows(), config)
    assert background.fill_count > 0
    assert background.ground.height_at(np.array([[0.0, 0.0]]))[0] == pytest.approx(0.0, abs=0.02)
    caster = SurfaceCaster(background.surfels.surface())
    hits = caster.cast(np.array([3.0, 0.0, 1.7]), np.array([[-3.0, 0.2, -1.7]]) / np.linalg.norm([-3.0, 0.2, -1.7]))
    assert hits.ranges[0] == pytest.approx(np.linalg.norm([3.0, 0.2, 1.7]), abs=0.05)


def _beam_rows() -> BeamRows:
    sensor = SensorModel(np.deg2rad(np.linspace(10.0, -30.0, 80)), np.deg2rad(0.5), 0.5, 100.0)
    return BeamRows(
        sensor=sensor, source="elevation", ring_to_row=np.zeros(0, dtype=np.int64), beam_heights=np.zeros(80)
    )


def test_surfels_that_later_sweeps_see_through_are_carved_and_walls_stay() -> None:
    beam_rows = _beam_rows()
    sensor = beam_rows.sensor
    wall = np.column_stack([np.full(400, 10.0), np.linspace(-2, 2, 20).repeat(20), np.tile(np.linspace(-1, 1, 20), 20)])
    ghost = np.array([[6.0, 0.0, 0.0]])  # something stood here once, between the sensor and the wall
    geometry = spherical(wall)
    rows = np.clip(np.round((sensor.beam_elevations[0] - geometry.elevations) / np.deg2rad(0.5)).astype(int), 0, 79)
    columns = azimuth_columns(geometry.azimuths, sensor)
    depths = [SweepDepth.of_points(np.eye(4), geometry.ranges, rows, columns, sensor) for _ in range(3)]
    keep = carve_moving(np.concatenate([wall, ghost]), depths, beam_rows, ResimConfig())
    assert not keep[-1]
    assert np.mean(keep[:-1]) > 0.95


def test_cache_files_are_written_atomically_and_bad_files_read_as_missing(tmp_path: Path) -> None:
    path = tmp_path / "models" / "model.npz"
    save_arrays(path, {"a": np.arange(3), "b/c": np.ones((2, 2))})
    assert [entry.name for entry in path.parent.iterdir()] == ["model.npz"]  # no temporary file left behind
    loaded = load_arrays(path)
    assert loaded is not None
    assert np.array_equal(loaded["a"], np.arange(3))
    path.write_bytes(b"not a zip file")
    assert load_arrays(path) is None
    assert load_arrays(tmp_path / "missing.npz") is None


def test_digests_change_with_content_shape_and_type() -> None:
    def digest(*values: np.ndarray) -> str:
        hashed = Digest("test")
        for value in values:
            hashed.array(value)
        return hashed.hexdigest()

    base = digest(np.arange(4, dtype=np.int64))
    assert base == digest(np.arange(4, dtype=np.int64))
    assert base != digest(np.arange(4, dtype=np.int32))
    assert base != digest(np.arange(4, dtype=np.int64).reshape(2, 2))
    assert base != digest(np.array([0, 1, 2, 4]))


def test_surfels_built_in_blocks_equal_one_pass_over_all(monkeypatch: pytest.MonkeyPatch) -> None:
    """The block-wise neighbourhood pass (it bounds a whole log's memory) changes no bit of the surfels."""
    from advsim_ros.core.lidar import surfels as surfels_module

    rng = np.random.default_rng(4)
    samples = PointSamples.concatenate([_plane(rng, 20000, 6.0, hole=1.0), _plane(rng, 3000, 1.0)])
    monkeypatch.setattr(surfels_module, "_BLOCK", 1 << 30)
    whole = surfels_from_samples(samples, 0.1, 1.2, 0.3)
    monkeypatch.setattr(surfels_module, "_BLOCK", 777)  # blocks whose neighbours lie in other blocks
    blocked = surfels_from_samples(samples, 0.1, 1.2, 0.3)
    assert whole.count > 10 * 777
    for name in ("centers", "normals", "half_sizes", "intensity"):
        np.testing.assert_array_equal(getattr(blocked, name), getattr(whole, name))


def test_gathering_point_samples_equals_concatenating_them_and_empties_the_list() -> None:
    rng = np.random.default_rng(5)
    parts = [_plane(rng, count, 2.0) for count in (10, 0, 250, 3)]
    expected = PointSamples.concatenate(parts)
    gathered = PointSamples.gather(parts)
    assert parts == []
    for name in ("xyz", "intensity", "normal_sum", "view_sum", "weight"):
        np.testing.assert_array_equal(getattr(gathered, name), getattr(expected, name))
