"""The one ray caster: triangle surfaces with intensity, poses, all crossings, nearest of several."""

from __future__ import annotations

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
