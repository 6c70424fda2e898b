"""Perturbed trajectories: a normalised delta rolled out through the kinematic bicycle model (AdvSim, Sec. 3).

Per actor the perturbation is a vector delta in [-1, 1]^D, D = 4 + 2 K (K control knots,
default 4, so D = 12), laid out as

    [dx0, dy0, dheading0, dv0, da_1 .. da_K, dr_1 .. dr_K]

dx0 / dy0 shift the actor's initial position along / across its initial heading by up to
``max_position_offset`` metres, dheading0 turns it by up to ``max_heading_offset``, dv0 changes
its initial speed by up to ``max_speed_offset``; da_k and dr_k are offsets of the acceleration
and curvature rate at K knots spread evenly over the horizon, linearly interpolated to every
step and added to the controls of the bicycle-model fit of the logged track (the reference).
delta = 0 therefore replays the reference, which follows the logged track.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from advsim_ros.core.dynamics import STATE_DIM, integrate_curvature, integrate_poses, integrate_speed, knot_weights
from advsim_ros.core.feasibility.config import STATE_OFFSETS, PerturberConfig
from advsim_ros.core.feasibility.reference import ActorReference
from advsim_ros.core.geometry import wrap_angle
from advsim_ros.core.types import ActorClass, ActorTrack, FloatArray, IntArray, ScenarioError

AnyFloatArray = npt.NDArray[np.floating[Any]]


@dataclass(frozen=True, eq=False)
class PerturbedTrajectory:
    """One actor's trajectory over the window, every field per 10 Hz step (T,), world frame."""

    actor_id: str
    actor_class: ActorClass
    size: FloatArray  # (3,) length, width, height [m]
    stamps_ns: IntArray  # (T,) [ns]
    x: FloatArray  # box centre [m]
    y: FloatArray  # [m]
    z: FloatArray  # logged box-centre height [m]
    yaw: FloatArray  # heading, continuous [rad]
    speed: FloatArray  # [m/s]
    curvature: FloatArray  # [1/m]
    accel: FloatArray  # realised acceleration, held at the last step [m/s^2]
    curvature_rate: FloatArray  # realised curvature rate, held at the last step [1/(m s)]
    delta: FloatArray  # (D,) the normalised perturbation that produced it

    def boxes(self) -> FloatArray:
        """(T, 5) [x, y, yaw, length, width] per step."""
        count = self.x.shape[0]
        return np.column_stack([self.x, self.y, self.yaw, np.full(count, self.size[0]), np.full(count, self.size[1])])

    def to_actor_track(self) -> ActorTrack:
        """The trajectory as an ActorTrack (headings wrapped), e.g. to re-simulate LiDAR."""
        return ActorTrack(
            actor_id=self.actor_id,
            actor_class=self.actor_class,
            size=self.size.copy(),
            stamps_ns=self.stamps_ns.copy(),
            centers=np.column_stack([self.x, self.y, self.z]),
            yaws=np.asarray(wrap_angle(self.yaw), dtype=np.float64),
        )


def delta_controls(
    reference: ActorReference, deltas: AnyFloatArray, config: PerturberConfig, weights: AnyFloatArray
) -> tuple[AnyFloatArray, AnyFloatArray, AnyFloatArray]:
    """Initial states (N, 5) in the local frame (origin at the reference start) and time-major controls (T-1, N).

    Computed in the dtype of deltas; weights are the (K, T) knot weights in that dtype.
    """
    dtype = deltas.dtype.type
    knots = config.num_knots
    fit = reference.fit
    heading = fit.initial[2]
    along = deltas[:, 0] * dtype(config.max_position_offset)
    across = deltas[:, 1] * dtype(config.max_position_offset)
    initial = np.empty((deltas.shape[0], STATE_DIM), dtype=deltas.dtype)
    initial[:, 0] = along * dtype(math.cos(heading)) - across * dtype(math.sin(heading))
    initial[:, 1] = along * dtype(math.sin(heading)) + across * dtype(math.cos(heading))
    initial[:, 2] = dtype(heading) + deltas[:, 2] * dtype(config.max_heading_offset)
    initial[:, 3] = dtype(fit.initial[3]) + deltas[:, 3] * dtype(config.max_speed_offset)
    initial[:, 4] = dtype(fit.initial[4])
    accel = _knot_controls(
        deltas[:, STATE_OFFSETS : STATE_OFFSETS + knots], config.max_accel_offset, weights, fit.accel
    )
    rate = _knot_controls(
        deltas[:, STATE_OFFSETS + knots :], config.max_curvature_rate_offset, weights, fit.curvature_rate
    )
    return initial, accel, rate


def _knot_controls(knots: AnyFloatArray, scale: float, weights: AnyFloatArray, reference: FloatArray) -> AnyFloatArray:
    """Time-major (T-1, N) reference controls plus knot offsets (N, K) in [-1, 1], scaled and interpolated.

    The last step's control is never integrated, so it is left out. Linear interpolation puts
    two knots on each segment of steps, so each segment is two broadcast multiply-adds rather
    than a matrix product (BLAS is slow on this thin shape and rounds batch-dependently).
    """
    dtype = knots.dtype
    columns = np.ascontiguousarray(knots.T) * dtype.type(scale)  # (K, N)
    steps = weights.shape[1] - 1
    result = np.empty((steps, knots.shape[0]), dtype=dtype)
    result[:] = reference[:steps, None].astype(dtype)
    segment = np.minimum(np.arange(steps) * (weights.shape[0] - 1) // (weights.shape[1] - 1), weights.shape[0] - 2)
    for k in range(weights.shape[0] - 1):
        rows = np.nonzero(segment == k)[0]
        if rows.size == 0:
            continue
        block = slice(int(rows[0]), int(rows[-1]) + 1)
        result[block] += weights[k, block, None].astype(dtype) * columns[k]
        result[block] += weights[k + 1, block, None].astype(dtype) * columns[k + 1]
    return result


def _check_block(delta: npt.ArrayLike, config: PerturberConfig) -> FloatArray:
    block = np.asarray(delta, dtype=np.float64)
    if block.shape != (config.perturbation_dim,):
        raise ScenarioError(f"perturbation: expected {config.perturbation_dim} entries per actor, got {block.shape}")
    if not np.all(np.isfinite(block)) or np.any(np.abs(block) > 1.0 + 1e-9):
        raise ScenarioError("perturbation: entries must be finite and lie in [-1, 1]")
    return block


def perturbation_to_trajectory(
    reference: ActorReference, delta: npt.ArrayLike, config: PerturberConfig
) -> PerturbedTrajectory:
    """Roll the bicycle model out from one actor's normalised delta (D,), without projection (float64)."""
    block = _check_block(delta, config)
    return RolloutBatch(reference, block[None, :], config).trajectory(0)


class RolloutBatch:
    """float64 rollouts of a batch of deltas (N, D) of one actor, time-major (T, N), in the world frame."""

    def __init__(self, reference: ActorReference, deltas: FloatArray, config: PerturberConfig) -> None:
        self.reference = reference
        self.deltas = deltas
        weights = knot_weights(reference.num_steps, config.num_knots)
        initial, accel, rate = delta_controls(reference, deltas, config, weights)
        dt = reference.dt
        self.speed: FloatArray = np.asarray(integrate_speed(initial[:, 3], accel, dt), dtype=np.float64)
        self.curvature: FloatArray = np.asarray(integrate_curvature(initial[:, 4], rate, dt), dtype=np.float64)
        x, y, yaw = integrate_poses(initial, self.speed, self.curvature, dt)
        self.yaw: FloatArray = np.asarray(yaw, dtype=np.float64)
        self.x: FloatArray = np.asarray(x, dtype=np.float64) + reference.origin[0]
        self.y: FloatArray = np.asarray(y, dtype=np.float64) + reference.origin[1]

    def boxes(self) -> FloatArray:
        """(T, N, 5) [x, y, yaw, length, width]."""
        size = self.reference.size
        return np.stack(
            [self.x, self.y, self.yaw, np.full_like(self.x, size[0]), np.full_like(self.x, size[1])], axis=-1
        )

    def trajectory(self, column: int) -> PerturbedTrajectory:
        reference, dt = self.reference, self.reference.dt
        speed, curvature = self.speed[:, column], self.curvature[:, column]
        accel = np.diff(speed) / dt
        rate = np.diff(curvature) / dt
        return PerturbedTrajectory(
            actor_id=reference.actor_id,
            actor_class=reference.actor_class,
            size=reference.size.copy(),
            stamps_ns=reference.stamps_ns.copy(),
            x=self.x[:, column].copy(),
            y=self.y[:, column].copy(),
            z=reference.z.copy(),
            yaw=self.yaw[:, column].copy(),
            speed=speed.copy(),
            curvature=curvature.copy(),
            accel=np.append(accel, accel[-1]),
            curvature_rate=np.append(rate, rate[-1]),
            delta=self.deltas[column].copy(),
        )
