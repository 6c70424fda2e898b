"""The one ray caster: triangle surfaces with intensity, poses, all crossings, nearest of several."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Callable

import numpy as np
import pytest

from advsim_ros.core.lidar.boxes import yaw_pose
from advsim_ros.core.lidar.raycast import (
    NO_TRIANGLE,
    PlacedSurface,
    Surface,
    SurfaceCaster,
    cast_nearest,
    cuboid_surface,
    surfels_to_surface,
)
from advsim_ros.core.types import ScenarioError

ALONG_X = np.array([[1.0, 0.0, 0.0]])


def test_a_ray_hits_the_near_face_of_a_cube_with_its_intensity() -> None:
    caster = SurfaceCaster(cuboid_surface([-1.0, -1.0, -1.0], [1.0, 1.0, 1.0], 0.4))
    hits = caster.cast(np.array([-5.0, 0.0, 0.0]), np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]))
    assert hits.ranges[0] == pytest.approx(4.0, abs=1e-5)
    assert hits.intensity[0] == pytest.approx(0.4)
    assert np.isinf(hits.ranges[1])
    assert hits.source.tolist() == [0, -1]


def test_a_surface_is_cast_at_its_pose_without_moving_its_triangles() -> None:
    caster = SurfaceCaster(cuboid_surface([-1.0, -0.5, -0.5], [1.0, 0.5, 0.5], 0.2))
    pose = yaw_pose([10.0, 0.0, 0.0], np.pi / 2)  # turned: its 1 m half length now lies along y
    hits = caster.cast(np.zeros(3), ALONG_X, pose)
    assert hits.ranges[0] == pytest.approx(9.5, abs=1e-5)
    moved = caster.surface.transformed(pose)
    assert SurfaceCaster(moved).cast(np.zeros(3), ALONG_X).ranges[0] == pytest.approx(9.5, abs=1e-5)


def test_the_first_hits_come_unconverted_and_agree_with_cast() -> None:
    caster = SurfaceCaster(cuboid_surface([-1.0, -1.0, -1.0], [1.0, 1.0, 1.0], 0.4))
    origins, directions = np.array([-5.0, 0.0, 0.0]), np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    rays = np.concatenate([np.broadcast_to(origins, directions.shape), directions], axis=1).astype(np.float32)
    ranges, triangles = caster.cast_first(rays)
    assert ranges.dtype == np.float32
    assert triangles.dtype == np.uint32
    hits = caster.cast(origins, directions)
    assert hits.triangles is not None
    assert ranges.tolist() == hits.ranges.tolist()
    assert triangles[1] == NO_TRIANGLE
    assert int(triangles[0]) == hits.triangles[0]
    empty = SurfaceCaster(Surface(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int32), np.zeros(0)))
    nothing, none = empty.cast_first(rays)
    assert np.all(np.isinf(nothing))
    assert np.all(none == NO_TRIANGLE)


def test_all_crossings_come_sorted_by_ray_and_range() -> None:
    two = Surface.concatenate(
        [
            cuboid_surface([2.0, -1.0, -1.0], [3.0, 1.0, 1.0], 0.1),
            cuboid_surface([5.0, -1.0, -1.0], [6.0, 1.0, 1.0], 0.9),
        ]
    )
    origin = np.array([0.0, 0.13, 0.31])  # off the faces' diagonals, where a ray would cross two triangles
    crossings = SurfaceCaster(two).cast_all(origin, np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]]))
    first = crossings.ranges[crossings.ray_ids == 0]
    assert first == pytest.approx([2.0, 3.0, 5.0, 6.0], abs=1e-5)
    assert np.all(np.diff(crossings.ray_ids) >= 0)
    assert 1 not in crossings.ray_ids  # the ray along y meets nothing


def test_the_nearest_surface_wins_and_is_named() -> None:
    near = PlacedSurface(
        SurfaceCaster(cuboid_surface([-0.5, -0.5, -0.5], [0.5, 0.5, 0.5], 0.3)), yaw_pose([4, 0, 0], 0)
    )
    far = PlacedSurface(SurfaceCaster(cuboid_surface([-0.5, -3.0, -3.0], [0.5, 3.0, 3.0], 0.8)), yaw_pose([9, 0, 0], 0))
    directions = np.array([[1.0, 0.0, 0.0], [np.cos(0.2), np.sin(0.2), 0.0]])
    hits = cast_nearest(np.zeros(3), directions, [far, near])
    assert hits.source.tolist() == [1, 0]
    assert hits.ranges[0] == pytest.approx(3.5, abs=1e-5)
    assert hits.intensity.tolist() == pytest.approx([0.3, 0.8])


def test_surfels_are_squares_facing_their_normal() -> None:
    surface = surfels_to_surface(
        np.array([[5.0, 0.0, 0.0]]), np.array([[-1.0, 0.0, 0.0]]), np.array([0.1]), np.array([0.7])
    )
    caster = SurfaceCaster(surface)
    inside = caster.cast(np.zeros(3), np.array([[1.0, 0.019, 0.0]]) / np.linalg.norm([1.0, 0.019, 0.0]))
    outside = caster.cast(np.zeros(3), np.array([[1.0, 0.03, 0.0]]) / np.linalg.norm([1.0, 0.03, 0.0]))
    assert inside.ranges[0] == pytest.approx(5.0, abs=0.01)
    assert inside.intensity[0] == pytest.approx(0.7)
    assert np.isinf(outside.ranges[0])


def test_malformed_surfaces_are_refused_with_the_reason() -> None:
    with pytest.raises(ScenarioError, match="vertex index out of range"):
        Surface(np.zeros((3, 3)), np.array([[0, 1, 3]]), np.zeros(1))
    with pytest.raises(ScenarioError, match="intensity"):
        Surface(np.zeros((3, 3)), np.array([[0, 1, 2]]), np.zeros(2))
    with pytest.raises(ScenarioError, match="lower < upper"):
        cuboid_surface([0, 0, 0], [1, 0, 1], 0.5)


def _random_surfels(count: int, seed: int = 0) -> tuple[np.ndarray, ...]:
    rng = np.random.default_rng(seed)
    normals = rng.normal(size=(count, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    return (
        (rng.normal(size=(count, 3)) * 10.0).astype(np.float32),
        normals.astype(np.float32),
        rng.uniform(0.05, 0.3, count).astype(np.float32),
        rng.uniform(0.0, 1.0, count).astype(np.float32),
    )


def test_surfels_become_the_same_triangles_whatever_the_chunk_size(monkeypatch: pytest.MonkeyPatch) -> None:
    surfels = _random_surfels(1000)
    whole = surfels_to_surface(*surfels)
    monkeypatch.setattr("advsim_ros.core.lidar.raycast.SURFEL_CHUNK", 7)  # chunks that do not divide the count
    chunked = surfels_to_surface(*surfels)
    # and as the whole float64 computation of before gave them
    as_float64 = surfels_to_surface(*(np.asarray(part, dtype=np.float64) for part in surfels))
    for surface in (chunked, as_float64):
        assert np.array_equal(surface.vertices, whole.vertices)
        assert np.array_equal(surface.triangles, whole.triangles)
        assert np.array_equal(surface.intensity, whole.intensity)
    assert whole.vertices.dtype == np.float32
    assert whole.triangles.dtype == np.int32


def test_a_caster_without_its_surface_casts_exactly_as_one_with_it() -> None:
    surface = surfels_to_surface(*_random_surfels(2000, seed=1))
    kept, lean = SurfaceCaster(surface), SurfaceCaster.lean(lambda: surface)
    rng = np.random.default_rng(2)
    directions = rng.normal(size=(4000, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    rays = np.concatenate([np.zeros_like(directions), directions], axis=1).astype(np.float32)
    for a, b in zip(kept.cast_first(rays), lean.cast_first(rays), strict=True):
        assert np.array_equal(a, b)
    hits_kept, hits_lean = kept.cast(np.zeros(3), directions), lean.cast(np.zeros(3), directions)
    assert np.count_nonzero(np.isfinite(hits_kept.ranges)) > 100
    assert np.array_equal(hits_kept.ranges, hits_lean.ranges)
    assert np.array_equal(hits_kept.intensity, hits_lean.intensity)
    assert lean.intensity is surface.intensity
    with pytest.raises(ScenarioError, match="lean caster"):
        _ = lean.surface


def test_the_ray_caster_loads_open3d_without_its_visualisers(
    imported_after: Callable[[str, tuple[str, ...]], list[str]],
) -> None:
    # Open3D's package __init__ imports plotly, dash and IPython (~45 MB resident): a ray-casting
    # process (lidar_resim) loads only its compiled module
    code = (
        "from advsim_ros.core.lidar.raycast import SurfaceCaster, cuboid_surface\n"
        "SurfaceCaster(cuboid_surface([-1, -1, -1], [1, 1, 1], 0.5))\n"
    )
    assert imported_after(code, ("dash", "plotly", "IPython", "open3d")) == []


def test_open3d_imported_after_the_ray_caster_works_as_usual() -> None:
    # A user's script that imports Open3D itself after advsim_ros' ray caster gets the same compiled module
    # (initialising it twice fails); and the other way round the ray caster takes the package's.
    code = (
        "from advsim_ros.core.lidar import raycast\n"
        "import open3d\n"
        "assert open3d.t.geometry.RaycastingScene is raycast.o3d.t.geometry.RaycastingScene\n"
        "print(open3d.core.Tensor([1, 2]).numpy().sum())\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=False)
    assert result.returncode == 0, result.stderr[-2000:]
    assert result.stdout.strip() == "3"
