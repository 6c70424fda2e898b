"""The one ray caster of advsim_ros: triangle surfaces with an intensity per triangle.

Everything that renders LiDAR goes through ``SurfaceCaster``: the synthetic logs (meshes of
a street scene), the background model and the actor assets of the re-simulation (surfels
turned into triangles). Each surface lives in its own frame; a cast takes the surface's
pose in the frame of the rays, so an actor asset is built once in its box frame and cast
at any pose without moving its triangles. Open3D's RaycastingScene (Embree) does the work.
"""

from __future__ import annotations

import importlib.machinery
import importlib.util
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from advsim_ros.core.lidar.sensor import rotate
from advsim_ros.core.types import FloatArray, IntArray, ScenarioError


def _open3d() -> Any:
    """Open3D's compiled module (``open3d.pybind``: core, t.geometry, ...) without the package's __init__.

    That __init__ also imports Open3D's visualisers and with them plotly, dash and IPython: about
    45 MB resident in every process that casts a ray, for nothing. The package as usual when its
    compiled module is not where Open3D 0.19/0.20 wheels put it, or when Open3D is already imported.
    """
    imported = sys.modules.get("open3d")
    spec = importlib.util.find_spec("open3d") if imported is None else None
    if spec is not None and spec.submodule_search_locations:
        for suffix in importlib.machinery.EXTENSION_SUFFIXES:
            for folder in spec.submodule_search_locations:
                path = Path(folder) / f"pybind{suffix}"
                library = importlib.util.spec_from_file_location("open3d.pybind", path)
                if path.is_file() and library is not None and library.loader is not None:
                    module = importlib.util.module_from_spec(library)
                    library.loader.exec_module(module)
                    # Registered under its own name, so that a later `import open3d` (a user's script) takes
                    # this one: a second initialisation of the compiled module fails ("already defined").
                    sys.modules["open3d.pybind"] = module
                    return module
    import open3d

    return open3d


o3d = _open3d()

AnyFloatArray = npt.NDArray[np.floating[Any]]  # any float dtype on input; stored as float32
AnyIntArray = npt.NDArray[np.integer[Any]]


NO_TRIANGLE = int(o3d.t.geometry.RaycastingScene.INVALID_ID)  # the triangle of a ray that hits nothing (cast_first)


def as_tensor(array: np.ndarray) -> Any:
    """An Open3D tensor sharing the memory of a C-contiguous numpy array."""
    return o3d.core.Tensor.from_numpy(np.ascontiguousarray(array))


@dataclass(frozen=True, eq=False)
class Surface:
    """A triangle surface in its own frame; a ray that hits a triangle returns its intensity."""

    vertices: AnyFloatArray  # (V, 3) [m], stored as float32
    triangles: AnyIntArray  # (T, 3) vertex indices, stored as int32
    intensity: AnyFloatArray  # (T,) what a hit on each triangle returns (the log's intensity unit), stored as float32

    def __post_init__(self) -> None:
        vertices = np.ascontiguousarray(self.vertices, dtype=np.float32)
        triangles = np.ascontiguousarray(self.triangles, dtype=np.int32)
        intensity = np.ascontiguousarray(self.intensity, dtype=np.float32)
        if vertices.ndim != 2 or vertices.shape[1] != 3:
            raise ScenarioError(f"Surface vertices: expected shape (V, 3), got {vertices.shape}")
        if triangles.ndim != 2 or triangles.shape[1] != 3:
            raise ScenarioError(f"Surface triangles: expected shape (T, 3), got {triangles.shape}")
        if intensity.shape != (triangles.shape[0],):
            raise ScenarioError(f"Surface intensity: expected shape ({triangles.shape[0]},), got {intensity.shape}")
        if triangles.size and (triangles.min() < 0 or triangles.max() >= vertices.shape[0]):
            raise ScenarioError("Surface triangles: vertex index out of range")
        if not np.all(np.isfinite(vertices)):
            raise ScenarioError("Surface vertices: contain NaN or infinite values")
        object.__setattr__(self, "vertices", vertices)
        object.__setattr__(self, "triangles", triangles)
        object.__setattr__(self, "intensity", intensity)

    @property
    def num_triangles(self) -> int:
        return int(self.triangles.shape[0])

    def transformed(self, pose: FloatArray) -> Surface:
        """The surface moved by the rigid transform `pose` (4, 4)."""
        vertices = rotate(self.vertices, pose[:3, :3]) + pose[:3, 3]
        return Surface(vertices=vertices, triangles=self.triangles, intensity=self.intensity)

    @staticmethod
    def concatenate(surfaces: Sequence[Surface]) -> Surface:
        """One surface holding all of `surfaces` (same frame)."""
        offsets = np.cumsum([0] + [surface.vertices.shape[0] for surface in surfaces])
        return Surface(
            vertices=np.concatenate([surface.vertices for surface in surfaces]).reshape(-1, 3),
            triangles=np.concatenate(
                [surface.triangles + offset for surface, offset in zip(surfaces, offsets, strict=False)]
            ).reshape(-1, 3),
            intensity=np.concatenate([surface.intensity for surface in surfaces]),
        )


def cuboid_surface(lower: npt.ArrayLike, upper: npt.ArrayLike, intensity: float) -> Surface:
    """The six faces of the axis-aligned box lower..upper (3,) [m] as 12 triangles."""
    low = np.asarray(lower, dtype=np.float64)
    high = np.asarray(upper, dtype=np.float64)
    if low.shape != (3,) or high.shape != (3,) or np.any(high <= low):
        raise ScenarioError(f"cuboid_surface: need lower < upper, got {low} and {high}")
    corners = np.array([[(high if (index >> axis) & 1 else low)[axis] for axis in range(3)] for index in range(8)])
    faces = np.array(
        [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]], dtype=np.int32
    )
    triangles = np.concatenate([faces[:, [0, 1, 2]], faces[:, [0, 2, 3]]])
    return Surface(vertices=corners, triangles=triangles, intensity=np.full(12, intensity))


SURFEL_CHUNK = 65_536  # surfels turned into triangles at a time (bounds the float64 temporaries)


def surfels_to_surface(
    centers: AnyFloatArray, normals: AnyFloatArray, half_sizes: AnyFloatArray, intensity: AnyFloatArray
) -> Surface:
    """Square surfels (disc stand-ins) as two triangles each.

    centers (S, 3) [m], normals (S, 3) unit, half_sizes (S,) half the square's side [m],
    intensity (S,). A ray hits either side of a triangle. The corners are computed in float64
    (whatever the inputs' float type), a chunk of surfels at a time: each surfel's corners
    depend on that surfel alone, so chunking changes no value, and a log's million background
    surfels never hold a dozen float64 copies at once.
    """
    count = centers.shape[0]
    if normals.shape != (count, 3) or half_sizes.shape != (count,) or intensity.shape != (count,):
        raise ScenarioError("surfels_to_surface: centers, normals, half_sizes and intensity disagree in length")
    vertices = np.empty((count, 4, 3), dtype=np.float32)
    for start in range(0, count, SURFEL_CHUNK):
        part = slice(start, start + SURFEL_CHUNK)
        vertices[part] = _surfel_corners(
            np.asarray(centers[part], dtype=np.float64),
            np.asarray(normals[part], dtype=np.float64),
            np.asarray(half_sizes[part], dtype=np.float64),
        )
    base = 4 * np.arange(count, dtype=np.int32)[:, None]
    corners = np.array([[0, 1, 2, 0, 2, 3]], dtype=np.int32)
    triangles = (base + corners).reshape(-1, 3)
    # intensity through float64 as before, so the float32 per-triangle values are unchanged
    return Surface(
        vertices=vertices.reshape(-1, 3),
        triangles=triangles,
        intensity=np.repeat(np.asarray(intensity, dtype=np.float64), 2),
    )


def _surfel_corners(centers: FloatArray, normals: FloatArray, half_sizes: FloatArray) -> FloatArray:
    """(S, 4, 3) the corners of square surfels, in float64."""
    # Any vector not parallel to the normal gives the first tangent.
    helper = np.where(np.abs(normals[:, 2:3]) < 0.9, np.array([[0.0, 0.0, 1.0]]), np.array([[1.0, 0.0, 0.0]]))
    tangent_u = np.cross(normals, helper)
    tangent_u /= np.maximum(np.linalg.norm(tangent_u, axis=1, keepdims=True), 1e-12)
    tangent_v = np.cross(normals, tangent_u)
    u = tangent_u * half_sizes[:, None]
    v = tangent_v * half_sizes[:, None]
    return np.stack([centers - u - v, centers + u - v, centers + u + v, centers - u + v], axis=1)


@dataclass(frozen=True, eq=False)
class RayHits:
    """Where rays hit: range along the unit direction, the hit triangle's intensity, which surface."""

    ranges: FloatArray  # (N,) [m]; inf where the ray hits nothing
    intensity: FloatArray  # (N,) intensity of the hit surface; 0 where the ray hits nothing
    source: IntArray  # (N,) index of the surface hit (see cast_nearest); -1 where the ray hits nothing
    triangles: IntArray | None = None  # (N,) triangle hit within its surface; -1 where nothing (None: not kept)

    @staticmethod
    def misses(count: int) -> RayHits:
        return RayHits(
            ranges=np.full(count, np.inf),
            intensity=np.zeros(count),
            source=np.full(count, -1),
            triangles=np.full(count, -1, dtype=np.int64),
        )

    def nearest(self, other: RayHits) -> RayHits:
        """Per ray, the nearer of the two hits (the occlusion-correct merge)."""
        closer = other.ranges < self.ranges
        return RayHits(
            ranges=np.where(closer, other.ranges, self.ranges),
            intensity=np.where(closer, other.intensity, self.intensity),
            source=np.where(closer, other.source, self.source),
        )


class SurfaceCaster:
    """A surface ready for ray casting (the acceleration structure is built on construction).

    ``SurfaceCaster.lean(make_surface)`` keeps only what a cast needs (the triangles'
    intensities): Embree holds its own copy of the vertices and triangles, so the surface's
    arrays would be a second one (a log's background: 2 M triangles, about 80 MB).
    """

    def __init__(self, surface: Surface) -> None:
        self._surface: Surface | None = surface
        self._scene = o3d.t.geometry.RaycastingScene()
        self._add(surface)
        self._commit()

    @classmethod
    def lean(cls, make_surface: Callable[[], Surface]) -> SurfaceCaster:
        """A caster of the surface ``make_surface()`` returns, which it does not keep.

        The surface's vertices and triangles are freed as soon as Embree has copied them, before
        Embree builds its hierarchy (whose own temporaries then do not come on top of them).
        """
        caster = cls.__new__(cls)
        caster._surface = None
        caster._scene = o3d.t.geometry.RaycastingScene()
        caster._add(make_surface())  # the only reference to the surface: gone when _add returns
        caster._commit()
        return caster

    def _add(self, surface: Surface) -> None:
        self.intensity = surface.intensity  # (T,) what a hit on each triangle returns
        self.num_triangles = surface.num_triangles
        if surface.num_triangles:
            # add_triangles copies both arrays into Embree's buffers; the int32 indices are passed as
            # uint32 without a copy (they are never negative: Surface checks them).
            self._scene.add_triangles(as_tensor(surface.vertices), as_tensor(surface.triangles.view(np.uint32)))

    def _commit(self) -> None:
        if self.num_triangles:
            self._scene.cast_rays(as_tensor(np.array([[0, 0, 0, 0, 0, 1]], dtype=np.float32)))  # builds it now

    @property
    def surface(self) -> Surface:
        """The surface cast against (not kept by a lean caster)."""
        if self._surface is None:
            raise ScenarioError("SurfaceCaster: a lean caster does not keep its surface")
        return self._surface

    def cast(self, origins: npt.ArrayLike, directions: FloatArray, pose: FloatArray | None = None) -> RayHits:
        """Hits of rays from origins ((3,) or (N, 3)) along unit directions (N, 3) in the frame F.

        `pose` (4, 4) is T_F_surface, the surface's pose in F (identity when None).
        """
        count = directions.shape[0]
        if count == 0 or self.num_triangles == 0:
            return RayHits.misses(count)
        return self.cast_prepared(self._rays(origins, directions, pose))

    def cast_prepared(self, rays: npt.NDArray[np.float32]) -> RayHits:
        """``cast`` for rays already in the surface's frame: (N, 6) float32 origins and unit directions."""
        count = rays.shape[0]
        if count == 0 or self.num_triangles == 0:
            return RayHits.misses(count)
        answer = self._scene.cast_rays(as_tensor(rays))
        ranges = answer["t_hit"].numpy().astype(np.float64)
        hit = np.isfinite(ranges)
        primitive = answer["primitive_ids"].numpy().astype(np.int64)
        intensity = np.zeros(count)
        intensity[hit] = self.intensity[primitive[hit]]
        return RayHits(
            ranges=ranges, intensity=intensity, source=np.where(hit, 0, -1), triangles=np.where(hit, primitive, -1)
        )

    def cast_first(self, rays: npt.NDArray[np.float32]) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.uint32]]:
        """Each ray's first hit as Embree gives it, with none of ``cast_prepared``'s conversions.

        `rays` as in ``cast_prepared``; returns the ranges (N,) float32 (inf: no hit) and the
        triangles (N,) uint32 (``NO_TRIANGLE``: no hit).
        """
        count = rays.shape[0]
        if count == 0 or self.num_triangles == 0:
            return np.full(count, np.inf, dtype=np.float32), np.full(count, NO_TRIANGLE, dtype=np.uint32)
        answer = self._scene.cast_rays(as_tensor(rays))
        ranges: npt.NDArray[np.float32] = answer["t_hit"].numpy()
        triangles: npt.NDArray[np.uint32] = answer["primitive_ids"].numpy()
        return ranges, triangles

    def cast_all(self, origins: npt.ArrayLike, directions: FloatArray, pose: FloatArray | None = None) -> Intersections:
        """Every crossing of the rays (as in ``cast``) with the surface, not only the first."""
        count = directions.shape[0]
        if count == 0 or self.num_triangles == 0:
            empty = np.zeros(0, dtype=np.int64)
            return Intersections(ray_ids=empty, ranges=np.zeros(0), triangles=empty)
        rays = self._rays(origins, directions, pose)
        answer = self._scene.list_intersections(as_tensor(rays))
        ray_ids = answer["ray_ids"].numpy().astype(np.int64)
        ranges = answer["t_hit"].numpy().astype(np.float64)
        triangles = answer["primitive_ids"].numpy().astype(np.int64)
        order = np.lexsort((ranges, ray_ids))
        return Intersections(ray_ids=ray_ids[order], ranges=ranges[order], triangles=triangles[order])

    def _rays(self, origins: npt.ArrayLike, directions: FloatArray, pose: FloatArray | None) -> np.ndarray:
        """(N, 6) float32 rays in the surface's frame."""
        count = directions.shape[0]
        origin = np.broadcast_to(np.asarray(origins, dtype=np.float64), (count, 3))
        if pose is not None:
            rotation_t = pose[:3, :3].T
            origin = rotate(origin - pose[:3, 3], rotation_t)
            directions = rotate(directions, rotation_t)
        return np.concatenate([origin, directions], axis=1).astype(np.float32)


@dataclass(frozen=True, eq=False)
class Intersections:
    """Every crossing of rays with a surface, sorted by ray and then by range."""

    ray_ids: IntArray  # (K,) index of the ray
    ranges: FloatArray  # (K,) [m] along the ray
    triangles: IntArray  # (K,) index of the triangle crossed


@dataclass(frozen=True, eq=False)
class PlacedSurface:
    """A caster and its pose (4, 4) T_F_surface in the frame F of the rays (None: identity)."""

    caster: SurfaceCaster
    pose: FloatArray | None = None


def cast_nearest(origins: npt.ArrayLike, directions: FloatArray, placed: Sequence[PlacedSurface]) -> RayHits:
    """The nearest hit over several placed surfaces, per ray (occlusion between them is exact).

    ``source`` of the answer is the index in `placed` of the surface each ray hit.
    """
    hits = RayHits.misses(directions.shape[0])
    for index, item in enumerate(placed):
        found = item.caster.cast(origins, directions, item.pose)
        hits = hits.nearest(RayHits(found.ranges, found.intensity, np.where(found.source >= 0, index, -1)))
    return hits
