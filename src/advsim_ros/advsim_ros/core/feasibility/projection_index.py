"""A principal-component index of one actor's feasible positions: cheap exact lower bounds on L2 distances."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from advsim_ros.core.types import FloatArray, IntArray

Float32Array = npt.NDArray[np.float32]


@dataclass(frozen=True, eq=False)
class ProjectionIndex:
    """Principal components of the feasible positions: cheap exact lower bounds on L2 distances."""

    mean: FloatArray  # (2T,)
    basis: FloatArray  # (2T, k) orthonormal columns
    coords: Float32Array  # (S, k) candidate coordinates in the basis
    coords_sq: Float32Array  # (S,) squared norms of coords
    residual: Float32Array  # (S,) distance of each candidate from the basis span [m]

    @staticmethod
    def build(flat: Float32Array, components: int) -> ProjectionIndex:
        count = flat.shape[0]
        if count == 0:
            empty = np.zeros(0, dtype=np.float32)
            return ProjectionIndex(
                np.zeros(flat.shape[1]), np.zeros((flat.shape[1], 0)), np.zeros((0, 0), np.float32), empty, empty
            )
        sample = flat[:: max(1, count // 10_000)]  # the components only need to be good, not optimal
        mean = sample.astype(np.float64).mean(axis=0)
        centred = sample.astype(np.float64) - mean
        _, vectors = np.linalg.eigh(centred.T @ centred)
        basis = vectors[:, ::-1][:, : min(components, vectors.shape[1])].copy()  # largest variance first
        coords = np.empty((count, basis.shape[1]), dtype=np.float32)
        residual = np.empty(count, dtype=np.float32)
        for start in range(0, count, 50_000):
            block = flat[start : start + 50_000].astype(np.float64) - mean
            projected = block @ basis
            coords[start : start + 50_000] = projected
            residual[start : start + 50_000] = np.linalg.norm(block - projected @ basis.T, axis=1)
        return ProjectionIndex(mean, basis, coords, np.einsum("ij,ij->i", coords, coords), residual)

    def nearest(self, flat: Float32Array, query: FloatArray, count: int) -> tuple[IntArray, FloatArray]:
        """Indices and L2 distances [m] of the `count` candidates nearest to query (2T,), ties to the lower index."""
        # einsum rather than BLAS: a multi-threaded BLAS call on this small shape stalls for
        # milliseconds when the cores are busy.
        centred = query - self.mean
        projected = np.einsum("dk,d->k", self.basis, centred)
        query_residual = np.float32(np.linalg.norm(centred - np.einsum("dk,k->d", self.basis, projected)))
        cross = np.einsum("sk,k->s", self.coords, projected.astype(np.float32))
        in_span = self.coords_sq - np.float32(2.0) * cross + np.float32(projected @ projected)
        in_span = np.maximum(in_span, np.float32(0.0))
        # Out of the span the two residual vectors are at least |r_q - r_x| and at most r_q + r_x apart.
        lower = np.sqrt(in_span + (query_residual - self.residual) ** 2)
        upper = np.sqrt(in_span + (query_residual + self.residual) ** 2)
        count = min(count, flat.shape[0])
        kth_upper = float(np.partition(upper, count - 1)[count - 1]) if count < upper.size else float(upper.max())
        slack = 1e-3 * (1.0 + kth_upper)  # float32 rounding of the bounds [m]
        shortlist = np.nonzero(lower <= kth_upper + slack)[0]
        exact = np.sqrt(np.sum((flat[shortlist].astype(np.float64) - query) ** 2, axis=1))
        order = np.lexsort((shortlist, exact))[:count]
        return shortlist[order].astype(np.int64), exact[order]
