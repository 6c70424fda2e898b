"""Surfels: the surface representation of the background and of the actor assets.

Aggregated LiDAR points are merged on a voxel grid (position and intensity averaged per
voxel, normals summed), each voxel becomes a square surfel whose normal is the mean of
the per-sweep range-image normals of its points (facing the sensor that saw them; the
mean viewing direction where those disagree, as on thin poles seen from both sides) and
whose size follows the local spacing of the voxels around it, so that neighbouring
surfels overlap a little where the data is dense and grow (up to a cap) where it is
sparse. Surfels become square pairs of triangles for the ray caster, following LiDARsim
(Manivasagam et al., CVPR 2020), which builds its background and vehicle assets from
surfels.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.spatial import cKDTree

from advsim_ros.core.lidar.raycast import AnyFloatArray, Surface, surfels_to_surface
from advsim_ros.core.types import FloatArray, ScenarioError

SPACING_NEIGHBOURS = 4  # neighbours whose mean distance is the local spacing of surfels
SMOOTHING_NEIGHBOURS = 10  # neighbours whose agreeing normals are averaged into a surfel's normal
SMOOTHING_ANGLE = np.deg2rad(30.0)  # neighbours whose normal differs more than this are an edge, not noise
ISOLATION = 2.0  # surfels whose neighbour spacing exceeds this many maximal half sides are dropped
PLANARITY = 0.05  # a neighbourhood is flat when its least spread is at most this share of the middle one
SMOOTHING_RADIUS_VOXELS = 3.0  # ... and neighbours farther than this many voxels are left out
_CONSISTENT_NORMALS = 0.5  # |sum of unit normals| / count below this: the voxel's normals disagree
BoolArray = npt.NDArray[np.bool_]
Neighbours = npt.NDArray[np.int32]  # (S, K) indices of each surfel's nearest surfels, itself first
_KEY_BITS = 21  # bits per axis of a packed voxel key (about +-1e6 voxels per axis)
_BLOCK = 65536  # surfels whose neighbourhoods are processed at once (bounds the build's memory)


@dataclass(frozen=True, eq=False)
class PointSamples:
    """Points to merge into surfels, with the running sums that make merging associative."""

    xyz: FloatArray  # (N, 3) mean position [m]
    intensity: FloatArray  # (N,) mean intensity
    normal_sum: FloatArray  # (N, 3) sum of unit normals facing the sensor (zero rows: unknown)
    view_sum: FloatArray  # (N, 3) sum of unit directions from the point towards the sensor
    weight: FloatArray  # (N,) number of raw points merged

    @staticmethod
    def of_points(
        xyz: FloatArray, intensity: FloatArray, normals: FloatArray, sensor_origin: FloatArray
    ) -> PointSamples:
        """Raw points (N, 3) [m] with unit normals (zero: unknown), seen from sensor_origin (3,) [m]."""
        view = sensor_origin - xyz
        view /= np.maximum(np.linalg.norm(view, axis=1, keepdims=True), 1e-9)
        return PointSamples(xyz, intensity, normals, view, np.ones(xyz.shape[0]))

    @staticmethod
    def concatenate(parts: list[PointSamples]) -> PointSamples:
        if not parts:
            return PointSamples(np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0))
        return PointSamples(
            xyz=np.concatenate([part.xyz for part in parts]).reshape(-1, 3),
            intensity=np.concatenate([part.intensity for part in parts]),
            normal_sum=np.concatenate([part.normal_sum for part in parts]).reshape(-1, 3),
            view_sum=np.concatenate([part.view_sum for part in parts]).reshape(-1, 3),
            weight=np.concatenate([part.weight for part in parts]),
        )

    @staticmethod
    def gather(parts: list[PointSamples]) -> PointSamples:
        """``concatenate`` that empties ``parts`` as it copies them: the peak is the result plus one part."""
        total = sum(part.count for part in parts)
        gathered = PointSamples(np.empty((total, 3)), np.empty(total), np.empty((total, 3)), np.empty((total, 3)),
                                np.empty(total))  # fmt: skip
        start = 0
        while parts:
            part = parts.pop(0)
            rows = slice(start, start + part.count)
            gathered.xyz[rows], gathered.intensity[rows], gathered.weight[rows] = part.xyz, part.intensity, part.weight
            gathered.normal_sum[rows], gathered.view_sum[rows] = part.normal_sum, part.view_sum
            start += part.count
        return gathered

    @property
    def count(self) -> int:
        return int(self.xyz.shape[0])

    def transformed(self, transform: FloatArray) -> PointSamples:
        """The samples moved by a rigid transform (4, 4)."""
        rotation = transform[:3, :3]
        return PointSamples(
            self.xyz @ rotation.T + transform[:3, 3],
            self.intensity,
            self.normal_sum @ rotation.T,
            self.view_sum @ rotation.T,
            self.weight,
        )

    def mirrored_y(self) -> PointSamples:
        """The samples reflected in the x-z plane (y -> -y), e.g. the unseen side of a car."""
        flip = np.array([1.0, -1.0, 1.0])
        return PointSamples(self.xyz * flip, self.intensity, self.normal_sum * flip, self.view_sum * flip, self.weight)


def voxel_merge(samples: PointSamples, voxel_size: float) -> PointSamples:
    """One sample per occupied voxel of size `voxel_size` [m]: weighted means and summed normals."""
    if samples.count == 0:
        return samples
    keys = np.zeros(samples.count, dtype=np.int64)
    for axis in range(3):  # one axis at a time: (N, 3) temporaries of a whole log's points are GBs
        cells = np.floor(samples.xyz[:, axis] / voxel_size).astype(np.int64) + (1 << (_KEY_BITS - 1))
        if cells.min() < 0 or cells.max() >= (1 << _KEY_BITS):
            raise ScenarioError(f"voxel_merge: points span more than {(1 << _KEY_BITS) * voxel_size:.0f} m")
        keys |= cells << ((2 - axis) * _KEY_BITS)
    del cells
    _, inverse = np.unique(keys, return_inverse=True)
    weight: FloatArray = np.bincount(inverse, weights=samples.weight).astype(np.float64)

    def mean(values: FloatArray) -> FloatArray:
        result: FloatArray = np.bincount(inverse, weights=values * samples.weight).astype(np.float64) / weight
        return result

    def total(values: FloatArray) -> FloatArray:
        result: FloatArray = np.bincount(inverse, weights=values).astype(np.float64)
        return result

    return PointSamples(
        xyz=np.stack([mean(samples.xyz[:, axis]) for axis in range(3)], axis=1),
        intensity=mean(samples.intensity),
        normal_sum=np.stack([total(samples.normal_sum[:, axis]) for axis in range(3)], axis=1),
        view_sum=np.stack([total(samples.view_sum[:, axis]) for axis in range(3)], axis=1),
        weight=weight,
    )


@dataclass(frozen=True, eq=False)
class SurfelCloud:
    """Oriented square surfels in one frame."""

    centers: AnyFloatArray  # (S, 3) [m], stored as float32 (as are the other fields)
    normals: AnyFloatArray  # (S, 3) unit
    half_sizes: AnyFloatArray  # (S,) half the square's side [m]
    intensity: AnyFloatArray  # (S,) mean intensity of the points merged into the surfel

    def __post_init__(self) -> None:
        count = np.asarray(self.centers).shape[0]
        for name in ("centers", "normals", "half_sizes", "intensity"):
            value = np.ascontiguousarray(getattr(self, name), dtype=np.float32)
            if value.shape[0] != count:
                raise ScenarioError(f"SurfelCloud {name}: expected {count} rows, got shape {value.shape}")
            object.__setattr__(self, name, value)

    @property
    def count(self) -> int:
        return int(self.centers.shape[0])

    def surface(self) -> Surface:
        # converted to float64 a chunk at a time inside, not as whole copies here
        return surfels_to_surface(self.centers, self.normals, self.half_sizes, self.intensity)

    def to_arrays(self, prefix: str) -> dict[str, np.ndarray]:
        return {f"{prefix}{name}": getattr(self, name) for name in ("centers", "normals", "half_sizes", "intensity")}

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray], prefix: str) -> SurfelCloud:
        return cls(
            centers=arrays[f"{prefix}centers"],
            normals=arrays[f"{prefix}normals"],
            half_sizes=arrays[f"{prefix}half_sizes"],
            intensity=arrays[f"{prefix}intensity"],
        )

    @staticmethod
    def concatenate(clouds: list[SurfelCloud]) -> SurfelCloud:
        return SurfelCloud(
            centers=np.concatenate([cloud.centers for cloud in clouds]).reshape(-1, 3),
            normals=np.concatenate([cloud.normals for cloud in clouds]).reshape(-1, 3),
            half_sizes=np.concatenate([cloud.half_sizes for cloud in clouds]),
            intensity=np.concatenate([cloud.intensity for cloud in clouds]),
        )

    @staticmethod
    def empty() -> SurfelCloud:
        return SurfelCloud(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), np.zeros(0))


def _plane_normals(centers: FloatArray, neighbours: Neighbours) -> tuple[FloatArray, BoolArray]:
    """Normals of planes fitted to each surfel's neighbourhood, and whether the neighbourhood is flat.

    Where it is flat this beats the range-image normal, which is noisy or missing for far,
    sparse returns (a far sidewalk point with a wrong normal would stand up as a wall).
    """
    offsets = centers[neighbours] - centers[neighbours].mean(axis=1, keepdims=True)
    covariance = np.einsum("ski,skj->sij", offsets, offsets)
    eigenvalues, eigenvectors = np.linalg.eigh(covariance)  # ascending
    planar: BoolArray = eigenvalues[:, 0] <= PLANARITY * eigenvalues[:, 1]
    normals: FloatArray = eigenvectors[:, :, 0]
    return normals, planar


def _smoothed_normals(normals: FloatArray, block: slice, neighbours: Neighbours, close: BoolArray) -> FloatArray:
    """The normals of the surfels in ``block``, each averaged with its close neighbours' normals that agree with
    it (within SMOOTHING_ANGLE); ``neighbours`` and ``close`` are the block's rows.

    Range-image normals are noisy where rays graze a surface (far road); averaging only
    agreeing neighbours smooths planes without rounding off edges such as curbs.
    """
    own = normals[block][:, None, :]
    others = normals[neighbours]  # (S, K + 1, 3), the surfel itself first
    alignment = np.einsum("skc,skc->sk", others, np.broadcast_to(own, others.shape))
    weight = np.where((np.abs(alignment) >= np.cos(SMOOTHING_ANGLE)) & close, np.sign(alignment), 0.0)
    summed = np.einsum("sk,skc->sc", weight, others)
    length = np.linalg.norm(summed, axis=1, keepdims=True)
    result: FloatArray = np.where(length > 1e-9, summed / np.maximum(length, 1e-12), normals[block])
    return result


def surfels_from_samples(
    samples: PointSamples, voxel_size: float, size_scale: float, max_half_size: float
) -> SurfelCloud:
    """Surfels from point samples merged on a `voxel_size` [m] grid.

    A surfel's half side is `size_scale` times the mean distance to its SPACING_NEIGHBOURS
    nearest surfels, clipped to [voxel_size / 2, max_half_size] [m].
    """
    merged = voxel_merge(samples, voxel_size)
    count = merged.count
    if count == 0:
        return SurfelCloud.empty()
    normal_length = np.linalg.norm(merged.normal_sum, axis=1)
    view_length = np.maximum(np.linalg.norm(merged.view_sum, axis=1), 1e-9)
    consistent = normal_length >= _CONSISTENT_NORMALS * merged.weight
    normals = np.where(
        consistent[:, None],
        merged.normal_sum / np.maximum(normal_length, 1e-9)[:, None],
        merged.view_sum / view_length[:, None],
    )
    if count > SMOOTHING_NEIGHBOURS:
        # In blocks of surfels: a whole log's background has millions, and its per-neighbour temporaries
        # would take GBs at once. Each block's figures are exactly those of one pass over all.
        tree = cKDTree(merged.xyz)
        blocks = [slice(start, start + _BLOCK) for start in range(0, count, _BLOCK)]
        neighbours = np.empty((count, SMOOTHING_NEIGHBOURS + 1), dtype=np.int32)
        close = np.empty((count, SMOOTHING_NEIGHBOURS + 1), dtype=bool)
        spacing = np.empty(count)
        for block in blocks:
            distances, neighbours[block] = tree.query(merged.xyz[block], k=SMOOTHING_NEIGHBOURS + 1, workers=-1)
            spacing[block] = distances[:, 1 : SPACING_NEIGHBOURS + 1].mean(axis=1)
            close[block] = distances <= SMOOTHING_RADIUS_VOXELS * voxel_size
            fitted, planar = _plane_normals(merged.xyz, neighbours[block])
            normals[block] = np.where(planar[:, None], fitted, normals[block])
        smoothed = np.empty_like(normals)
        for block in blocks:  # after every plane fit: a block's neighbours may lie in any block
            smoothed[block] = _smoothed_normals(normals, block, neighbours[block], close[block])
        normals = smoothed
    else:
        spacing = np.full(count, voxel_size)
    # A surfel whose neighbours are farther apart than a full surfel would span is a stray
    # return (noise, a fragment of something that moved), not a surface: leave it out.
    keep = spacing <= ISOLATION * max_half_size
    half_sizes = np.clip(size_scale * spacing[keep], 0.5 * voxel_size, max_half_size)
    return SurfelCloud(
        centers=merged.xyz[keep], normals=normals[keep], half_sizes=half_sizes, intensity=merged.intensity[keep]
    )
