"""Kinematic bicycle model: vectorised rollouts, knot controls, bound checks and track fitting.

State per step t: (x, y, yaw, v, curvature, a) with x, y [m], yaw [rad], v [m/s] >= 0,
curvature [1/m] (positive turning left) and a [m/s^2]. Controls per step: acceleration
a_t [m/s^2] and curvature rate r_t = dcurvature/dt [1/(m s)], applied over [t, t + dt):

    v_{t+1}     = max(v_t + a_t dt, 0)            (a vehicle brakes to a stop, never reverses)
    curv_{t+1}  = curv_t + r_t dt
    yaw_{t+1}   = yaw_t + v_t curv_t dt
    x_{t+1}     = x_t + v_t dt cos(yaw_t + v_t curv_t dt / 2)   (heading at the step's midpoint)
    y_{t+1}     = y_t + v_t dt sin(yaw_t + v_t curv_t dt / 2)

The public arrays are (N, T): N trajectories of T steps. The integrators underneath work
time-major, (T, N), because numpy reduces and accumulates fastest along the first axis of a
C-ordered array; the feasibility pruning calls them directly on hundreds of thousands of columns.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.optimize import least_squares

from advsim_ros.core.geometry import wrap_angle
from advsim_ros.core.types import ScenarioError

AnyFloatArray = npt.NDArray[np.floating[Any]]
FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

STATE_DIM = 5  # initial state [x, y, yaw, v, curvature]


@dataclass(frozen=True)
class KinematicBounds:
    """Physical limits a trajectory must respect at every step (AdvSim's bounds)."""

    max_curvature: float = 0.2  # |curvature| [1/m]
    max_curvature_rate: float = 0.05  # |dcurvature/dt| [1/(m s)]
    max_accel: float = 2.0  # |a| [m/s^2]
    max_lateral_accel: float = 3.0  # |v^2 curvature| [m/s^2]
    max_speed: float = 15.0  # v [m/s]

    def __post_init__(self) -> None:
        for name in ("max_curvature", "max_curvature_rate", "max_accel", "max_lateral_accel", "max_speed"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and np.isfinite(value) and value > 0):
                raise ScenarioError(f"KinematicBounds {name}: must be a positive finite number, got {value!r}")


@dataclass(frozen=True, eq=False)
class Trajectories:
    """N bicycle-model trajectories of T steps; every field is (N, T)."""

    x: AnyFloatArray  # [m]
    y: AnyFloatArray  # [m]
    yaw: AnyFloatArray  # [rad], continuous (not wrapped)
    speed: AnyFloatArray  # v [m/s], >= 0
    curvature: AnyFloatArray  # [1/m]
    accel: AnyFloatArray  # realised acceleration (v_{t+1} - v_t) / dt, held at the last step [m/s^2]
    curvature_rate: AnyFloatArray  # (curv_{t+1} - curv_t) / dt, held at the last step [1/(m s)]

    @property
    def num_steps(self) -> int:
        return int(self.x.shape[-1])

    def lateral_accel(self) -> AnyFloatArray:
        """(N, T) v^2 curvature [m/s^2]."""
        result: AnyFloatArray = self.speed * self.speed * self.curvature
        return result


WIDE_BATCH = 256  # from this many trajectories on, integrate with a loop over steps (see accumulate)


def accumulate(first: AnyFloatArray, increments: AnyFloatArray) -> AnyFloatArray:
    """Time-major (T, N) values: first (N,) then first + cumulative sums of increments (T-1, N).

    For wide batches a loop over the T steps, each adding N values at once: numpy's cumsum along
    axis 0 walks each column with a stride and is an order of magnitude slower there. For narrow
    batches one cumsum call, which costs less than the loop's per-step overhead.
    """
    result = np.empty((increments.shape[0] + 1, increments.shape[1]), dtype=increments.dtype)
    result[0] = first
    if increments.shape[1] < WIDE_BATCH:
        result[1:] = increments
        np.cumsum(result, axis=0, out=result)
        return result
    for step in range(increments.shape[0]):
        np.add(result[step], increments[step], out=result[step + 1])
    return result


def integrate_speed(initial_speed: AnyFloatArray, accel: AnyFloatArray, dt: float) -> AnyFloatArray:
    """Time-major (T, N) speeds [m/s] from initial speeds (N,) and accelerations (T-1, N) [m/s^2].

    v_{t+1} = max(v_t + a_t dt, 0); negative initial speeds are clamped to 0.
    """
    zero = accel.dtype.type(0.0)
    step = accel.dtype.type(dt)
    if accel.shape[1] < WIDE_BATCH:
        # Closed form of the recursion: the running sum reflected at zero.
        running = accumulate(np.maximum(initial_speed, zero), accel * step)
        reflected: AnyFloatArray = running - np.minimum(np.minimum.accumulate(running, axis=0), zero)
        return reflected
    result = np.empty((accel.shape[0] + 1, accel.shape[1]), dtype=accel.dtype)
    np.maximum(initial_speed, zero, out=result[0])
    for t in range(accel.shape[0]):
        np.multiply(accel[t], step, out=result[t + 1])
        result[t + 1] += result[t]
        np.maximum(result[t + 1], zero, out=result[t + 1])
    return result


def integrate_curvature(initial_curvature: AnyFloatArray, rate: AnyFloatArray, dt: float) -> AnyFloatArray:
    """Time-major (T, N) curvatures [1/m] from initial curvatures (N,) and rates (T-1, N) [1/(m s)]."""
    return accumulate(initial_curvature, rate * rate.dtype.type(dt))


def integrate_poses(
    initial: AnyFloatArray, speed: AnyFloatArray, curvature: AnyFloatArray, dt: float
) -> tuple[AnyFloatArray, AnyFloatArray, AnyFloatArray]:
    """Time-major (T, N) x [m], y [m], yaw [rad] from initial (N, 5) and time-major speed and curvature."""
    step = speed.dtype.type(dt)
    turn = speed[:-1] * curvature[:-1] * step  # heading change over each step [rad]
    yaw = accumulate(initial[:, 2], turn)
    mid_yaw = yaw[:-1] + turn * speed.dtype.type(0.5)
    distance = speed[:-1] * step
    x = accumulate(initial[:, 0], distance * np.cos(mid_yaw))
    y = accumulate(initial[:, 1], distance * np.sin(mid_yaw))
    return x, y, yaw


def rollout(initial: AnyFloatArray, accel: AnyFloatArray, curvature_rate: AnyFloatArray, dt: float) -> Trajectories:
    """Integrate the bicycle model from initial (N, 5) = [x, y, yaw, v, curvature] under controls (N, T).

    Column t of the controls acts over [t, t + dt); the last column is not integrated.
    The result keeps the dtype of the inputs.
    """
    if initial.ndim != 2 or initial.shape[1] != STATE_DIM:
        raise ScenarioError(f"rollout: initial state must be (N, 5), got {initial.shape}")
    if accel.shape != curvature_rate.shape or accel.ndim != 2 or accel.shape[0] != initial.shape[0]:
        raise ScenarioError(f"rollout: controls must both be (N, T), got {accel.shape} and {curvature_rate.shape}")
    if accel.shape[1] < 2:
        raise ScenarioError(f"rollout: needs at least 2 steps, got {accel.shape[1]}")
    speed = integrate_speed(initial[:, 3], np.ascontiguousarray(accel[:, :-1].T), dt)
    curvature = integrate_curvature(initial[:, 4], np.ascontiguousarray(curvature_rate[:, :-1].T), dt)
    x, y, yaw = integrate_poses(initial, speed, curvature, dt)
    step = initial.dtype.type(dt)
    return Trajectories(
        x=x.T,
        y=y.T,
        yaw=yaw.T,
        speed=speed.T,
        curvature=curvature.T,
        accel=_held_difference(speed, step).T,
        curvature_rate=_held_difference(curvature, step).T,
    )


def _held_difference(values: AnyFloatArray, step: np.floating[Any]) -> AnyFloatArray:
    """Time-major differences per step, the last one repeated so that every step has one."""
    rate = np.diff(values, axis=0) / step
    return np.concatenate([rate, rate[-1:]], axis=0)


def knot_weights(num_steps: int, num_knots: int) -> FloatArray:
    """(K, T) weights that interpolate K control knots linearly to T steps.

    Knots sit evenly on the horizon, the first at step 0 and the last at step T - 1.
    """
    if num_knots < 2 or num_steps < num_knots:
        raise ScenarioError(f"knot_weights: need 2 <= num_knots <= num_steps, got {num_knots} and {num_steps}")
    knot_steps = np.linspace(0.0, num_steps - 1.0, num_knots)
    steps = np.arange(num_steps, dtype=np.float64)
    weights = np.empty((num_knots, num_steps))
    for k in range(num_knots):
        unit = np.zeros(num_knots)
        unit[k] = 1.0
        weights[k] = np.interp(steps, knot_steps, unit)
    return weights


def interpolate_knots(knots: AnyFloatArray, weights: AnyFloatArray) -> AnyFloatArray:
    """(N, T) controls from (N, K) knot values and (K, T) weights, in the dtype of knots."""
    result: AnyFloatArray = knots @ weights.astype(knots.dtype)
    return result


@dataclass(frozen=True, eq=False)
class TrackFit:
    """A logged track explained by the bicycle model: initial state and per-step controls."""

    initial: FloatArray  # (5,) [x, y, yaw, v, curvature] at step 0
    accel: FloatArray  # (T,) [m/s^2]
    curvature_rate: FloatArray  # (T,) [1/(m s)]
    position_rmse: float  # over the observed steps [m]
    max_position_error: float  # over the observed steps [m]


@dataclass(frozen=True)
class FitWeights:
    """Noise scales of the least-squares track fit (residual = error / scale)."""

    position: float = 0.1  # [m]
    heading: float = 0.15  # [rad]; label headings are noisier than positions
    accel: float = 1.0  # prior on accelerations [m/s^2]
    curvature_rate: float = 0.02  # prior on curvature rates [1/(m s)]
    jerk: float = 2.0  # prior on acceleration changes [m/s^3]
    curvature: float = 0.1  # prior on the initial curvature [1/m]; only matters when the actor barely moves
    knots: int = 13  # control knots of the fit over the horizon (13 contains the default 4 perturbation knots)
    stationary_span: float = 1.0  # observations all within this distance of each other: the actor stands [m]
    bound: float = 1e-3  # penalty scale for state bounds (curvature, lateral acceleration, speed)


def fit_track(
    steps: npt.NDArray[np.int64],
    xy: FloatArray,
    yaws: FloatArray,
    num_steps: int,
    dt: float,
    bounds: KinematicBounds,
    weights: FitWeights | None = None,
) -> TrackFit:
    """Least-squares fit of the bicycle model to a track observed at the given steps.

    steps (M,) are observation step indices in [0, num_steps) and must include 0; xy (M, 2)
    are box centres [m] and yaws (M,) headings [rad]. Controls are bounded to the kinematic
    limits, and state bounds (curvature, lateral acceleration, speed) are soft penalties, so
    the fit is a feasible stand-in for a noisy logged track. Steps after the last observation
    continue with the prior (constant speed and curvature).
    """
    weights = weights or FitWeights()
    steps = np.asarray(steps, dtype=np.int64)
    if steps.ndim != 1 or steps.size == 0 or steps[0] != 0 or np.any(np.diff(steps) <= 0):
        raise ScenarioError("fit_track: observation steps must be strictly increasing and start at 0")
    if steps[-1] >= num_steps or xy.shape != (steps.size, 2) or yaws.shape != (steps.size,):
        raise ScenarioError(
            f"fit_track: observations must be (M, 2) / (M,) at steps < {num_steps}, got {xy.shape}, {yaws.shape}"
        )
    if stands_still(xy, weights.stationary_span):
        return standing_fit(xy, yaws, num_steps)
    origin = xy[0]
    local = xy - origin  # fit around the first position: well-scaled parameters
    unwrapped_yaws = yaws[0] + np.concatenate([[0.0], np.cumsum(wrap_angle(np.diff(yaws)))])
    num_knots = min(weights.knots, num_steps)
    interpolation = knot_weights(num_steps, num_knots)
    jerk_scale = weights.jerk * (num_steps - 1) / (num_knots - 1) * dt  # accel change between knots [m/s^2]

    def unpack(params: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        batch = params.reshape(-1, params.shape[-1])
        accel = np.asarray(interpolate_knots(batch[:, STATE_DIM : STATE_DIM + num_knots], interpolation), np.float64)
        rate = np.asarray(interpolate_knots(batch[:, STATE_DIM + num_knots :], interpolation), np.float64)
        return batch[:, :STATE_DIM], accel, rate

    def residuals(params: FloatArray) -> FloatArray:
        batch = params.reshape(-1, params.shape[-1])
        initial, accel, rate = unpack(batch)
        traj = rollout(initial, accel, rate, dt)
        position = np.concatenate([traj.x[:, steps] - local[:, 0], traj.y[:, steps] - local[:, 1]], axis=1)
        heading = wrap_angle(traj.yaw[:, steps] - unwrapped_yaws)
        # Headings only where the actor moves: a standing actor's yaw says nothing about its controls.
        heading = heading * np.minimum(traj.speed[:, steps] / 0.5, 1.0)
        over_curvature = np.maximum(np.abs(traj.curvature) - bounds.max_curvature, 0.0)
        over_lateral = np.maximum(np.abs(traj.lateral_accel()) - bounds.max_lateral_accel, 0.0)
        over_speed = np.maximum(traj.speed - bounds.max_speed, 0.0)
        accel_knots = batch[:, STATE_DIM : STATE_DIM + num_knots]
        parts = [
            position / weights.position,
            heading / weights.heading,
            accel_knots / weights.accel,
            np.diff(accel_knots, axis=1) / jerk_scale,
            batch[:, STATE_DIM + num_knots :] / weights.curvature_rate,
            batch[:, 4:5] / weights.curvature,
            (over_curvature + over_lateral / 10.0 + over_speed / 10.0) / weights.bound,
        ]
        result: FloatArray = np.concatenate(parts, axis=1)
        return result

    def residual_vector(params: FloatArray) -> FloatArray:
        row: FloatArray = residuals(params)[0]
        return row

    def jacobian(params: FloatArray) -> FloatArray:
        # Forward differences, all parameters in one batched rollout.
        epsilon = 1e-7
        batch = np.repeat(params[None, :], params.size + 1, axis=0)
        batch[1:] += np.eye(params.size) * epsilon
        values = residuals(batch)
        result: FloatArray = ((values[1:] - values[0]) / epsilon).T
        return result

    speed_guess = 0.0
    if steps.size >= 2:
        span = min(steps.size - 1, 5)
        speed_guess = float(np.linalg.norm(local[span] - local[0]) / ((steps[span] - steps[0]) * dt))
    speed_guess = min(speed_guess, bounds.max_speed)
    start = np.zeros(STATE_DIM + 2 * num_knots)
    start[2] = unwrapped_yaws[0]
    start[3] = speed_guess
    lower = np.full_like(start, -np.inf)
    upper = np.full_like(start, np.inf)
    lower[3], upper[3] = 0.0, bounds.max_speed
    lower[4], upper[4] = -bounds.max_curvature, bounds.max_curvature
    lower[STATE_DIM : STATE_DIM + num_knots] = -bounds.max_accel
    upper[STATE_DIM : STATE_DIM + num_knots] = bounds.max_accel
    lower[STATE_DIM + num_knots :] = -bounds.max_curvature_rate
    upper[STATE_DIM + num_knots :] = bounds.max_curvature_rate
    solution = least_squares(
        residual_vector, start, jac=jacobian, bounds=(lower, upper), method="trf", x_scale="jac", max_nfev=100
    )
    initial, accel, rate = unpack(np.asarray(solution.x, dtype=np.float64))
    initial = initial[0].copy()
    initial[:2] += origin
    accel_row, rate_row = accel[0].copy(), rate[0].copy()
    fitted = rollout(initial[None, :], accel_row[None, :], rate_row[None, :], dt)
    errors = np.hypot(fitted.x[0, steps] - xy[:, 0], fitted.y[0, steps] - xy[:, 1])
    return TrackFit(
        initial=initial,
        accel=accel_row,
        curvature_rate=rate_row,
        position_rmse=float(np.sqrt(np.mean(errors**2))),
        max_position_error=float(np.max(errors)),
    )


def stands_still(xy: FloatArray, span: float) -> bool:
    """Whether positions (M, 2) [m] all lie in a square of diagonal span [m]: label jitter, not motion."""
    return bool(np.max(np.ptp(xy, axis=0)) < span / np.sqrt(2.0))


def standing_fit(xy: FloatArray, yaws: FloatArray, num_steps: int) -> TrackFit:
    """A standing actor: median position, mean heading, no motion (label jitter is not motion)."""
    center = np.median(xy, axis=0)
    heading = float(np.arctan2(np.mean(np.sin(yaws)), np.mean(np.cos(yaws))))
    errors = np.linalg.norm(xy - center, axis=1)
    return TrackFit(
        initial=np.array([center[0], center[1], heading, 0.0, 0.0]),
        accel=np.zeros(num_steps),
        curvature_rate=np.zeros(num_steps),
        position_rmse=float(np.sqrt(np.mean(errors**2))),
        max_position_error=float(np.max(errors)),
    )
