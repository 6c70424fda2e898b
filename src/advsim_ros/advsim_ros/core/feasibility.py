"""Physically plausible actor perturbations: feasible sets, actor selection and projection (AdvSim, Sec. 3).

Per actor the perturbation is a vector delta in [-1, 1]^D, D = 4 + 2 K (K control knots,
default 4, so D = 12), laid out as

    [dx0, dy0, dheading0, dv0, da_1 .. da_K, dr_1 .. dr_K]

dx0 / dy0 shift the actor's initial position along / across its initial heading by up to
``max_position_offset`` metres, dheading0 turns it by up to ``max_heading_offset``, dv0 changes
its initial speed by up to ``max_speed_offset``; da_k and dr_k are offsets of the acceleration
and curvature rate at K knots spread evenly over the horizon, linearly interpolated to every
step and added to the controls of the bicycle-model fit of the logged track (the reference).
delta = 0 therefore replays the reference, which follows the logged track.

The feasible set of an actor is a cloud of sampled deltas (the zero delta first) whose 6-s
rollouts respect the kinematic bounds, keep their centre on the drivable area and overlap
neither the SDV's logged trajectory nor any other actor's logged box at any step. Pruning runs
cheapest first: kinematic bounds (speed and curvature only), poses and drivable area, then a
coarse raster of where other boxes could be touched, then exact oriented-box tests on what the
raster flags. Projection replaces a proposed delta by the feasible candidate whose positions
are L2-nearest to its rollout over the whole horizon; with several actors it returns the
jointly nearest candidates that do not collide with each other.
"""

from __future__ import annotations

import contextlib
import functools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from advsim_ros.core.drivable import DrivableConfig, drivable_area_for
from advsim_ros.core.dynamics import (
    STATE_DIM,
    KinematicBounds,
    TrackFit,
    fit_track,
    integrate_curvature,
    integrate_poses,
    integrate_speed,
    knot_weights,
    standing_fit,
    stands_still,
)
from advsim_ros.core.geometry import box_distance, boxes_overlap, overlap_from_components, wrap_angle
from advsim_ros.core.params import config_from_mapping, load_node_params
from advsim_ros.core.types import (
    ActorClass,
    ActorTrack,
    DrivableArea,
    IntArray,
    Perturbation,
    Scenario,
    ScenarioError,
)

AnyFloatArray = npt.NDArray[np.floating[Any]]
FloatArray = npt.NDArray[np.float64]
Float32Array = npt.NDArray[np.float32]
BoolArray = npt.NDArray[np.bool_]

NODE_NAME = "perturber"
EGO_ID = "ego"  # obstacle id of the SDV's logged trajectory
STATE_OFFSETS = 4  # dx0, dy0, dheading0, dv0
STATIC_SPAN = 1.0  # an actor whose logged centres all lie within this distance stands still [m]
COLLISION_BATCH = 16_384  # candidates whose collisions are tested at once
COARSE_STRIDE = 4  # actors are first tested at every COARSE_STRIDE-th step
MAX_JOINT_CHECKED = 20_000  # candidates a joint projection checks before it returns its best so far


class InfeasibleError(ScenarioError):
    """No physically plausible perturbation exists for what was asked; the message says why."""

    def __init__(self, message: str, reports: tuple[ActorReport, ...] = ()) -> None:
        super().__init__(message)
        self.reports = reports  # per-actor outcome when raised by select_actors


@dataclass(frozen=True)
class PerturberConfig:
    """Perturbation, feasibility and projection settings (params/perturber.yaml, node /perturber)."""

    seed: int = 0  # random seed of the candidate sampling (the perturber node's generator)
    horizon_steps: int = 60  # states per trajectory: 6 s at 10 Hz
    frame_period: float = 0.1  # expected spacing of the log's frames [s]
    num_knots: int = 4  # control knots per control over the horizon
    num_candidates: int = 200_000  # sampled deltas per actor (the zero delta included)
    min_feasible: int = 100  # an actor is perturbed only if at least this many candidates survive
    num_actors: int = 1  # m: actors perturbed at once
    perturbable_classes: tuple[str, ...] = ("vehicle",)  # ActorClass values the search may move
    min_observed_steps: int = 10  # a perturbed actor is labelled in at least this many window frames
    max_position_offset: float = 5.0  # |dx0|, |dy0| along / across the initial heading [m]
    max_heading_offset: float = math.pi / 4  # |dheading0| [rad]
    max_speed_offset: float = 5.0  # |dv0| [m/s]
    max_accel_offset: float = 2.0  # |acceleration offset| at a knot [m/s^2]
    max_curvature_rate_offset: float = 0.05  # |curvature-rate offset| at a knot [1/(m s)]
    max_curvature: float = 0.2  # [1/m]
    max_curvature_rate: float = 0.05  # [1/(m s)]
    max_accel: float = 2.0  # [m/s^2]
    max_lateral_accel: float = 3.0  # [m/s^2]
    max_speed: float = 15.0  # [m/s]
    ego_forward_offset: float = 1.0  # SDV box centre ahead of the ego frame origin [m]
    collision_margin: float = 0.05  # perturbed boxes are grown by this on every side when pruning [m]
    drivable_margin: float = 0.0  # the actor's centre stays this far inside the drivable area [m]
    drivable_resolution: float = 0.25  # drivable raster cell [m]
    drivable_reach: float = 110.0  # drivable raster extent beyond the logged positions [m]
    drivable_ground_cell: float = 0.5  # LiDAR ground-height grid cell (logs without a map) [m]
    drivable_max_step: float = 0.06  # largest height step inside the road surface [m]
    drivable_max_growth: float = 6.0  # road surface grows at most this far from driven areas [m]
    drivable_max_sweeps: int = 20  # LiDAR sweeps used for the ground-height grid
    drivable_max_point_range: float = 40.0  # LiDAR returns used up to this range [m]
    drivable_closing: float = 1.0  # gaps narrower than this are filled [m]
    chunk_size: int = 4096  # candidates pruned at once: small enough for the CPU caches
    cull_cell: float = 1.0  # cell of the coarse collision raster [m]
    bound_slack: float = 1e-4  # relative tightening of the bounds while pruning in float32
    projection_components: int = 24  # principal components of the projection's lower bounds
    projection_candidates: int = 16  # nearest candidates per actor considered first in joint projection

    def __post_init__(self) -> None:
        positive_ints = ("horizon_steps", "num_candidates", "min_feasible", "num_actors", "chunk_size")
        for name in (*positive_ints, "projection_components", "projection_candidates"):
            if getattr(self, name) < 1:
                raise ScenarioError(f"PerturberConfig {name}: must be >= 1, got {getattr(self, name)}")
        if not 2 <= self.num_knots <= self.horizon_steps:
            raise ScenarioError(f"PerturberConfig num_knots: must be in [2, horizon_steps], got {self.num_knots}")
        if self.horizon_steps < 2:
            raise ScenarioError(f"PerturberConfig horizon_steps: must be >= 2, got {self.horizon_steps}")
        if not 1 <= self.min_observed_steps <= self.horizon_steps:
            raise ScenarioError(
                f"PerturberConfig min_observed_steps: must be in [1, horizon_steps], got {self.min_observed_steps}"
            )
        positive = (
            "frame_period",
            "max_position_offset",
            "max_heading_offset",
            "max_speed_offset",
            "max_accel_offset",
            "max_curvature_rate_offset",
            "cull_cell",
        )
        for name in positive:
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ScenarioError(f"PerturberConfig {name}: must be positive, got {value!r}")
        for name in ("collision_margin", "drivable_margin", "bound_slack"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ScenarioError(f"PerturberConfig {name}: must be >= 0, got {value!r}")
        if not math.isfinite(self.ego_forward_offset):
            raise ScenarioError(f"PerturberConfig ego_forward_offset: must be finite, got {self.ego_forward_offset}")
        if self.bound_slack >= 0.01:
            raise ScenarioError(f"PerturberConfig bound_slack: must be below 0.01, got {self.bound_slack}")
        valid = {member.value for member in ActorClass}
        unknown = [name for name in self.perturbable_classes if name not in valid]
        if unknown or not self.perturbable_classes:
            raise ScenarioError(
                f"PerturberConfig perturbable_classes: {list(self.perturbable_classes)} must be a non-empty subset "
                f"of {sorted(valid)}"
            )
        object.__setattr__(self, "perturbable_classes", tuple(self.perturbable_classes))
        self.bounds  # noqa: B018 - validates the kinematic bounds with their own messages
        self.drivable  # noqa: B018

    @property
    def bounds(self) -> KinematicBounds:
        return KinematicBounds(
            max_curvature=self.max_curvature,
            max_curvature_rate=self.max_curvature_rate,
            max_accel=self.max_accel,
            max_lateral_accel=self.max_lateral_accel,
            max_speed=self.max_speed,
        )

    @property
    def drivable(self) -> DrivableConfig:
        return DrivableConfig(
            resolution=self.drivable_resolution,
            reach=self.drivable_reach,
            ground_cell=self.drivable_ground_cell,
            max_step=self.drivable_max_step,
            max_growth=self.drivable_max_growth,
            max_sweeps=self.drivable_max_sweeps,
            max_point_range=self.drivable_max_point_range,
            closing=self.drivable_closing,
        )

    @property
    def perturbation_dim(self) -> int:
        """Entries of delta per perturbed actor: dx0, dy0, dheading0, dv0, then K accel and K curvature-rate knots."""
        return STATE_OFFSETS + 2 * self.num_knots

    @classmethod
    def from_mapping(cls, parameters: Mapping[str, Any], context: str = f"/{NODE_NAME}") -> PerturberConfig:
        return config_from_mapping(cls, parameters, context)


def load_perturber_config(path: Path) -> PerturberConfig:
    """The /perturber parameters of a YAML file in the ROS shape; errors name the file and key."""
    return PerturberConfig.from_mapping(load_node_params(path, NODE_NAME), f"{path} /{NODE_NAME}")


def perturbation_names(num_knots: int) -> tuple[str, ...]:
    """Names of the entries of one actor's delta block, in order."""
    accel = tuple(f"da_{k}" for k in range(num_knots))
    rate = tuple(f"dr_{k}" for k in range(num_knots))
    return ("dx0", "dy0", "dheading0", "dv0", *accel, *rate)


@dataclass(frozen=True)
class Window:
    """Frames start_frame .. start_frame + num_steps - 1 of a scenario: the perturbed horizon."""

    start_frame: int  # index into scenario.frame_stamps_ns
    num_steps: int = 60  # states per trajectory

    def __post_init__(self) -> None:
        if self.start_frame < 0 or self.num_steps < 2:
            raise ScenarioError(f"Window: need start_frame >= 0 and num_steps >= 2, got {self}")

    def stamps(self, scenario: Scenario, frame_period: float) -> IntArray:
        """(T,) frame stamps [ns]; raises ScenarioError if the window leaves the log or frames are not evenly spaced."""
        end = self.start_frame + self.num_steps
        if end > scenario.num_frames:
            raise ScenarioError(
                f"Window frames {self.start_frame}..{end - 1} leave scenario {scenario.scenario_id}, "
                f"which has {scenario.num_frames} frames"
            )
        stamps = scenario.frame_stamps_ns[self.start_frame : end]
        spacing = np.diff(stamps) * 1e-9
        if np.max(np.abs(spacing - frame_period)) > 0.1 * frame_period:
            raise ScenarioError(
                f"scenario {scenario.scenario_id}: frames {self.start_frame}..{end - 1} are not spaced "
                f"{frame_period} s apart (found {spacing.min():.3f}..{spacing.max():.3f} s)"
            )
        return stamps


@dataclass(frozen=True, eq=False)
class ActorReference:
    """An actor's logged track over a window, explained by the bicycle model (delta = 0 replays it)."""

    actor_id: str
    actor_class: ActorClass
    size: FloatArray  # (3,) length, width, height [m]
    stamps_ns: IntArray  # (T,) window frame stamps [ns]
    dt: float  # step [s]
    fit: TrackFit  # initial state in the world frame and per-step controls
    z: FloatArray  # (T,) logged box-centre height, held beyond the labelled frames [m]
    observed: BoolArray  # (T,) whether the actor is labelled at each window frame

    @property
    def num_steps(self) -> int:
        return int(self.stamps_ns.shape[0])

    @property
    def origin(self) -> FloatArray:
        """(2,) world position of the reference at step 0: the origin of the local pruning frame [m]."""
        return self.fit.initial[:2]


def _window_observations(track: ActorTrack, stamps: IntArray) -> tuple[IntArray, IntArray]:
    """Window steps where the track is labelled, and the matching indices into the track."""
    steps = np.nonzero(np.isin(stamps, track.stamps_ns))[0]
    indices = np.searchsorted(track.stamps_ns, stamps[steps])
    return steps.astype(np.int64), indices.astype(np.int64)


def fit_reference(scenario: Scenario, window: Window, actor_id: str, config: PerturberConfig) -> ActorReference:
    """Fit the bicycle model to an actor's logged track over the window.

    The actor must be labelled at the window's first frame, unless it stands still over the
    whole log (then it stands at its median position throughout).
    """
    track = scenario.actor(actor_id)
    stamps = window.stamps(scenario, config.frame_period)
    count = stamps.shape[0]
    dt = float(np.mean(np.diff(stamps))) * 1e-9
    steps, indices = _window_observations(track, stamps)
    observed = np.zeros(count, dtype=bool)
    observed[steps] = True
    if is_standing(track):
        fit = standing_fit(track.centers[:, :2], track.yaws, count)
        z = np.full(count, float(np.median(track.centers[:, 2])))
    elif steps.size == 0 or steps[0] != 0:
        raise InfeasibleError(
            f"actor {actor_id} is not labelled at the first frame ({window.start_frame}) of the window: "
            "its initial state is unknown"
        )
    else:
        fit = fit_track(steps, track.centers[indices, :2], track.yaws[indices], count, dt, config.bounds)
        z = np.interp(np.arange(count), steps, track.centers[indices, 2])
    return ActorReference(
        actor_id=actor_id,
        actor_class=track.actor_class,
        size=track.size.copy(),
        stamps_ns=stamps.copy(),
        dt=dt,
        fit=fit,
        z=z,
        observed=observed,
    )


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


def _controls(
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
    return _RolloutBatch(reference, block[None, :], config).trajectory(0)


class _RolloutBatch:
    """float64 rollouts of a batch of deltas (N, D) of one actor, time-major (T, N), in the world frame."""

    def __init__(self, reference: ActorReference, deltas: FloatArray, config: PerturberConfig) -> None:
        self.reference = reference
        self.deltas = deltas
        weights = knot_weights(reference.num_steps, config.num_knots)
        initial, accel, rate = _controls(reference, deltas, config, weights)
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


@dataclass(frozen=True, eq=False)
class WindowObstacles:
    """Everything a perturbed actor must not touch, per window step: the SDV first, then every actor."""

    ids: tuple[str, ...]  # (J,) EGO_ID, then actor ids
    boxes: FloatArray  # (T, J, 5) [x, y, yaw, length, width] in the world frame
    present: BoolArray  # (T, J) whether obstacle j exists at step t

    def without(self, actor_id: str) -> WindowObstacles:
        keep = [index for index, name in enumerate(self.ids) if name != actor_id]
        return WindowObstacles(
            ids=tuple(self.ids[index] for index in keep),
            boxes=self.boxes[:, keep],
            present=self.present[:, keep],
        )


def is_standing(actor: ActorTrack) -> bool:
    """Whether the actor is a parked vehicle: labelled for >= 1 s, all its centres within STATIC_SPAN.

    A parked vehicle was there before it came into view and stays after; a pedestrian or cyclist
    standing for a moment may not, so only vehicles are extended beyond their labels.
    """
    span_s = (actor.stamps_ns[-1] - actor.stamps_ns[0]) * 1e-9
    return actor.actor_class == ActorClass.VEHICLE and span_s >= 1.0 and stands_still(actor.centers[:, :2], STATIC_SPAN)


def actor_window_boxes(actor: ActorTrack, stamps: IntArray) -> tuple[FloatArray, BoolArray]:
    """(T, 5) boxes [x, y, yaw, length, width] of a logged actor at the window stamps, and (T,) presence.

    An actor is present from its first to its last label in the window, positions and headings
    interpolated across unlabelled frames in between; an actor that stands still over the whole
    log is present at every step at its median position, also before it was first seen.
    """
    steps = stamps.shape[0]
    if is_standing(actor):
        fit = standing_fit(actor.centers[:, :2], actor.yaws, steps)
        box = np.tile([*fit.initial[:3], actor.length, actor.width], (steps, 1))
        return box, np.ones(steps, dtype=bool)
    window_steps, indices = _window_observations(actor, stamps)
    if window_steps.size == 0:
        return np.zeros((steps, 5)), np.zeros(steps, dtype=bool)
    grid = np.arange(steps)
    box = np.column_stack(
        [
            np.interp(grid, window_steps, actor.centers[indices, 0]),
            np.interp(grid, window_steps, actor.centers[indices, 1]),
            np.interp(grid, window_steps, np.unwrap(actor.yaws[indices])),
            np.full(steps, actor.length),
            np.full(steps, actor.width),
        ]
    )
    return box, (grid >= window_steps[0]) & (grid <= window_steps[-1])


def ego_window_boxes(scenario: Scenario, window: Window, config: PerturberConfig) -> FloatArray:
    """(T, 5) boxes of the SDV's logged trajectory over the window, centred ego_forward_offset ahead of its frame."""
    frames = np.arange(window.start_frame, window.start_frame + window.num_steps)
    yaw = scenario.ego.yaws[frames]
    xy = scenario.ego.xy[frames] + config.ego_forward_offset * np.column_stack([np.cos(yaw), np.sin(yaw)])
    count = frames.shape[0]
    return np.column_stack([xy, yaw, np.full(count, scenario.ego_size[0]), np.full(count, scenario.ego_size[1])])


def window_obstacles(scenario: Scenario, window: Window, config: PerturberConfig) -> WindowObstacles:
    """The SDV's logged boxes and every actor's boxes over the window (see actor_window_boxes)."""
    stamps = window.stamps(scenario, config.frame_period)
    ids = [EGO_ID]
    boxes = [ego_window_boxes(scenario, window, config)]
    present = [np.ones(stamps.shape[0], dtype=bool)]
    for actor in scenario.actors:
        box, mask = actor_window_boxes(actor, stamps)
        if not np.any(mask):
            continue
        ids.append(actor.actor_id)
        boxes.append(box)
        present.append(mask)
    return WindowObstacles(ids=tuple(ids), boxes=np.stack(boxes, axis=1), present=np.stack(present, axis=1))


@dataclass(frozen=True)
class PruningCounts:
    """Candidates left after each pruning step, in the order they run."""

    sampled: int
    kinematic: int  # after curvature, curvature-rate, acceleration, lateral-acceleration and speed bounds
    drivable: int  # after leaving the drivable area
    ego: int  # after collision with the SDV's logged trajectory
    actors: int  # after collision with every other actor: the feasible set
    # removed by each kinematic check, in KINEMATIC_CHECKS order
    violations: dict[str, int] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        return {
            "sampled": self.sampled,
            "kinematic": self.kinematic,
            "drivable": self.drivable,
            "ego": self.ego,
            "actors": self.actors,
            "violations": dict(self.violations),
        }


_GROUP_BITS = 31  # actors share bits 1..31 of the cull raster; bit 0 is the SDV


class _CullRaster:
    """Per step, a bitmask raster of cells from which a candidate centre could touch an obstacle.

    A cell is flagged for an obstacle when its centre lies within reach (the candidate's
    circumradius) plus half a cell diagonal of the obstacle's box: a rounded rectangle, much
    tighter than a circle for cars side by side in adjacent lanes. A candidate centre in a
    flagged cell is within reach of the obstacles of the flagged bits (bit 0: the SDV; bit
    b > 0: actors j with (j - 1) % 31 == b - 1) and needs an exact test; a centre in an empty
    cell touches nothing at that step.
    """

    def __init__(
        self, obstacles: WindowObstacles, origin: FloatArray, half_size: float, cell: float, reach: float
    ) -> None:
        self.cell = cell
        self.width = math.ceil(2.0 * half_size / cell)
        self.low = origin - half_size  # world position of cell (0, 0) corner [m]
        steps, count = obstacles.present.shape
        self.steps = steps
        self.grid = np.zeros((steps, self.width, self.width), dtype=np.uint32)
        margin = reach + cell * math.sqrt(0.5)
        for j in range(count):
            times = np.nonzero(obstacles.present[:, j])[0]
            if times.size == 0:
                continue
            half_length, half_width = 0.5 * obstacles.boxes[0, j, 3], 0.5 * obstacles.boxes[0, j, 4]
            span = math.ceil((math.hypot(half_length, half_width) + margin) / cell) + 1
            offsets = np.arange(-span, span + 1)
            boxes = obstacles.boxes[times, j]
            base = np.floor((boxes[:, :2] - self.low) / cell).astype(np.int64)
            cols = base[:, 0, None, None] + offsets[None, None, :]
            rows = base[:, 1, None, None] + offsets[None, :, None]
            dx = self.low[0] + (cols + 0.5) * cell - boxes[:, 0, None, None]  # cell centre from the box centre [m]
            dy = self.low[1] + (rows + 0.5) * cell - boxes[:, 1, None, None]
            cos, sin = np.cos(boxes[:, 2])[:, None, None], np.sin(boxes[:, 2])[:, None, None]
            outside_along = np.maximum(np.abs(dx * cos + dy * sin) - half_length, 0.0)
            outside_across = np.maximum(np.abs(-dx * sin + dy * cos) - half_width, 0.0)
            near = outside_along**2 + outside_across**2 <= margin**2
            near &= (cols >= 0) & (cols < self.width) & (rows >= 0) & (rows < self.width)
            t_index = np.broadcast_to(times[:, None, None], near.shape)[near]
            row_index = np.broadcast_to(rows, near.shape)[near]
            col_index = np.broadcast_to(cols, near.shape)[near]
            bit = np.uint32(1) if j == 0 else np.uint32(1 << (1 + (j - 1) % _GROUP_BITS))
            self.grid[t_index, row_index, col_index] |= bit
        self.flat = self.grid.reshape(-1)

    def lookup(self, x: Float32Array, y: Float32Array, local_low: FloatArray) -> npt.NDArray[np.uint32]:
        """Time-major (T, N) obstacle bits at candidate centres (T, N) in the local frame.

        local_low is the raster's lower corner in that frame.
        """
        scale = np.float32(1.0 / self.cell)
        cols = np.clip(((x - np.float32(local_low[0])) * scale).astype(np.int32), 0, self.width - 1)
        rows = np.clip(((y - np.float32(local_low[1])) * scale).astype(np.int32), 0, self.width - 1)
        step_offset = (np.arange(self.steps, dtype=np.int32) * np.int32(self.width * self.width))[:, None]
        index = step_offset + rows * np.int32(self.width) + cols
        result: npt.NDArray[np.uint32] = self.flat[index]
        return result


@dataclass(frozen=True, eq=False)
class _ProjectionIndex:
    """Principal components of the feasible positions: cheap exact lower bounds on L2 distances."""

    mean: FloatArray  # (2T,)
    basis: FloatArray  # (2T, k) orthonormal columns
    coords: Float32Array  # (S, k) candidate coordinates in the basis
    coords_sq: Float32Array  # (S,) squared norms of coords
    residual: Float32Array  # (S,) distance of each candidate from the basis span [m]

    @staticmethod
    def build(flat: Float32Array, components: int) -> _ProjectionIndex:
        count = flat.shape[0]
        if count == 0:
            empty = np.zeros(0, dtype=np.float32)
            return _ProjectionIndex(
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
        return _ProjectionIndex(mean, basis, coords, np.einsum("ij,ij->i", coords, coords), residual)

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


@dataclass(frozen=True, eq=False)
class FeasibleSet:
    """The surviving candidates of one actor: their deltas and positions, with pruning statistics."""

    reference: ActorReference
    config: PerturberConfig
    deltas: Float32Array  # (S, D) normalised perturbations; row 0 is the zero delta when it survived
    positions: Float32Array  # (S, 2T) x0, y0, x1, y1, ... relative to reference.origin [m]
    counts: PruningCounts

    @functools.cached_property
    def index(self) -> _ProjectionIndex:
        """Built on the first projection, so that sets that are never projected cost nothing more."""
        return _ProjectionIndex.build(self.positions, self.config.projection_components)

    @property
    def actor_id(self) -> str:
        return self.reference.actor_id

    @property
    def size(self) -> int:
        return int(self.deltas.shape[0])

    def trajectory(self, candidate: int) -> PerturbedTrajectory:
        """The candidate's trajectory, recomputed in float64 from its delta."""
        return perturbation_to_trajectory(self.reference, self.deltas[candidate].astype(np.float64), self.config)


def _columns(values: Float32Array, columns: IntArray) -> Float32Array:
    """values[:, columns] in C order (plain indexing returns Fortran order, which slows every later step)."""
    result: Float32Array = np.take(values, columns, axis=1)
    return result


KINEMATIC_CHECKS = ("curvature_rate", "curvature", "speed", "accel", "lateral_accel")  # in the order they run


class _Pruner:
    """Everything fixed while one actor's candidates are pruned, and the pruning of one chunk."""

    def __init__(
        self,
        reference: ActorReference,
        config: PerturberConfig,
        drivable: DrivableArea,
        obstacles: WindowObstacles,
    ) -> None:
        self.reference = reference
        self.config = config
        self.area = drivable.eroded(config.drivable_margin)
        self.others = obstacles.without(reference.actor_id)
        steps, dt = reference.num_steps, reference.dt
        self.weights = knot_weights(steps, config.num_knots).astype(np.float32)
        self.half_length = 0.5 * float(reference.size[0]) + config.collision_margin
        self.half_width = 0.5 * float(reference.size[1]) + config.collision_margin
        reach = math.hypot(self.half_length, self.half_width)
        # Every candidate centre stays within half_size of the reference start (offset plus top speed).
        half_size = (
            config.max_position_offset * math.sqrt(2.0)
            + config.max_speed * (steps - 1) * dt
            + reach
            + 2.0 * config.cull_cell
        )
        origin = reference.origin
        self.raster = _CullRaster(self.others, origin, half_size, config.cull_cell, reach)
        self.local_low = self.raster.low - origin
        local_boxes = self.others.boxes.copy()
        local_boxes[..., :2] -= origin
        # Per obstacle j, contiguous (T,) float32 arrays: one-dimensional gathers are the fastest.
        boxes32 = np.ascontiguousarray(np.moveaxis(local_boxes, 1, 0), dtype=np.float32)  # (J, T, 5)
        self.obstacle_x = np.ascontiguousarray(boxes32[..., 0])
        self.obstacle_y = np.ascontiguousarray(boxes32[..., 1])
        self.obstacle_cos = np.cos(boxes32[..., 2])
        self.obstacle_sin = np.sin(boxes32[..., 2])
        self.obstacle_half_length = boxes32[:, 0, 3] * np.float32(0.5)  # (J,) sizes do not change
        self.obstacle_half_width = boxes32[:, 0, 4] * np.float32(0.5)
        self.obstacle_present = np.ascontiguousarray(self.others.present.T)  # (J, T)
        self.group_members = [[0]] + [
            [j for j in range(1, len(self.others.ids)) if 1 + (j - 1) % _GROUP_BITS == bit]
            for bit in range(1, _GROUP_BITS + 1)
        ]
        keep = 1.0 - config.bound_slack
        bounds = config.bounds
        self.limits = {
            "curvature_rate": np.float32(bounds.max_curvature_rate * keep),
            "curvature": np.float32(bounds.max_curvature * keep),
            "speed": np.float32(bounds.max_speed * keep),
            "accel": np.float32(bounds.max_accel * keep * dt),  # as a speed change per step [m/s]
            "lateral_accel": np.float32(bounds.max_lateral_accel * keep),
        }

    def kinematic(
        self, deltas: Float32Array, removed: dict[str, int]
    ) -> tuple[IntArray, Float32Array, Float32Array, Float32Array]:
        """Candidates within every kinematic bound: indices, initial states, time-major speeds and curvatures."""
        limits, dt = self.limits, self.reference.dt
        initial, accel, rate = _controls(self.reference, deltas, self.config, self.weights)
        bad = (rate.max(axis=0) > limits["curvature_rate"]) | (rate.min(axis=0) < -limits["curvature_rate"])
        removed["curvature_rate"] += int(np.count_nonzero(bad))
        curvature = integrate_curvature(initial[:, 4], rate, dt)
        worse = (curvature.max(axis=0) > limits["curvature"]) | (curvature.min(axis=0) < -limits["curvature"])
        removed["curvature"] += int(np.count_nonzero(worse & ~bad))
        keep = np.nonzero(~(bad | worse))[0]
        initial, accel, curvature = initial[keep], _columns(accel, keep), _columns(curvature, keep)
        speed = integrate_speed(initial[:, 3], accel, dt)
        bad = speed.max(axis=0) > limits["speed"]
        removed["speed"] += int(np.count_nonzero(bad))
        change = speed[1:] - speed[:-1]
        worse = (change.max(axis=0) > limits["accel"]) | (change.min(axis=0) < -limits["accel"])
        removed["accel"] += int(np.count_nonzero(worse & ~bad))
        bad |= worse
        lateral = speed * speed * curvature
        worse = (lateral.max(axis=0) > limits["lateral_accel"]) | (lateral.min(axis=0) < -limits["lateral_accel"])
        removed["lateral_accel"] += int(np.count_nonzero(worse & ~bad))
        survivors = np.nonzero(~(bad | worse))[0]
        return keep[survivors], initial[survivors], _columns(speed, survivors), _columns(curvature, survivors)

    def collisions(self, x: Float32Array, y: Float32Array, yaw: Float32Array) -> tuple[BoolArray, BoolArray]:
        """(N,) whether each candidate touches the SDV, and whether it otherwise touches another actor.

        x, y, yaw are time-major (T, N) in the local frame. The SDV is tested at every step; the
        actors first at every COARSE_STRIDE-th step and then at the others, only for candidates
        not pruned yet (a colliding candidate usually overlaps for several steps in a row).
        """
        steps, count = x.shape
        bits = self.raster.lookup(x, y, self.local_low)
        every = np.arange(steps)
        hit_ego = np.zeros(count, dtype=bool)
        hit_actor = np.zeros(count, dtype=bool)
        self._exact(bits, every, x, y, yaw, np.uint32(1), hit_ego, hit_ego)
        coarse = every[::COARSE_STRIDE]
        fine = np.setdiff1d(every, coarse)
        actor_bits = np.uint32(0xFFFFFFFE)
        self._exact(bits[coarse], coarse, x, y, yaw, actor_bits, hit_ego, hit_actor)
        self._exact(bits[fine], fine, x, y, yaw, actor_bits, hit_ego | hit_actor, hit_actor)
        return hit_ego, hit_actor & ~hit_ego

    def _exact(
        self,
        bits: npt.NDArray[np.uint32],
        times_of_rows: IntArray,
        x: Float32Array,
        y: Float32Array,
        yaw: Float32Array,
        wanted: np.uint32,
        skip: BoolArray,
        hit: BoolArray,
    ) -> None:
        """Exact overlap tests of the candidates flagged in bits (S, N) for the wanted bits; sets hit (N,).

        times_of_rows (S,) are the steps of the rows of bits; candidates marked in skip are not tested.
        """
        count = x.shape[1]
        flat = np.flatnonzero(bits & wanted)
        rows, cands = np.divmod(flat, count)
        keep = ~skip[cands]
        flat, rows, cands = flat[keep], rows[keep], cands[keep]
        if flat.size == 0:
            return
        values = bits.reshape(-1)[flat] & wanted
        times = times_of_rows[rows]
        index = times * count + cands
        pose_x, pose_y = x.reshape(-1)[index], y.reshape(-1)[index]
        pose_yaw = yaw.reshape(-1)[index]
        pose_cos, pose_sin = np.cos(pose_yaw), np.sin(pose_yaw)
        present_bits = int(np.bitwise_or.reduce(values))
        for bit, members in enumerate(self.group_members):
            if not present_bits & (1 << bit):
                continue
            selected = np.nonzero(values & np.uint32(1 << bit))[0]
            for j in members:
                pairs = selected[self.obstacle_present[j][times[selected]]]
                if pairs.size == 0:
                    continue
                time = times[pairs]
                overlaps = overlap_from_components(
                    self.obstacle_x[j][time] - pose_x[pairs],
                    self.obstacle_y[j][time] - pose_y[pairs],
                    pose_cos[pairs],
                    pose_sin[pairs],
                    self.obstacle_cos[j][time],
                    self.obstacle_sin[j][time],
                    self.half_length,
                    self.half_width,
                    float(self.obstacle_half_length[j]),
                    float(self.obstacle_half_width[j]),
                )
                hit[cands[pairs[overlaps]]] = True

    def on_road(
        self, deltas: Float32Array, tally: dict[str, int], removed: dict[str, int]
    ) -> tuple[Float32Array, Float32Array, Float32Array, Float32Array]:
        """Candidates of a chunk within the bounds and on the drivable area: deltas and time-major x, y, yaw."""
        keep, initial, speed, curvature = self.kinematic(deltas, removed)
        tally["kinematic"] += keep.size
        deltas = deltas[keep]
        x, y, yaw = integrate_poses(initial, speed, curvature, self.reference.dt)
        on_road = np.nonzero(np.all(self.area.contains(x, y, offset=self.reference.origin), axis=0))[0]
        tally["drivable"] += on_road.size
        return deltas[on_road], _columns(x, on_road), _columns(y, on_road), _columns(yaw, on_road)

    def collision_free(
        self, deltas: Float32Array, x: Float32Array, y: Float32Array, yaw: Float32Array, tally: dict[str, int]
    ) -> tuple[Float32Array, Float32Array]:
        """The surviving deltas and their positions (S, 2T) = x0, y0, x1, y1, ... in the local frame."""
        hit_ego, hit_actor = self.collisions(x, y, yaw)
        tally["ego"] += int(np.count_nonzero(~hit_ego))
        feasible = np.nonzero(~(hit_ego | hit_actor))[0]
        tally["actors"] += feasible.size
        positions = np.stack([_columns(x, feasible).T, _columns(y, feasible).T], axis=-1).reshape(feasible.size, -1)
        return deltas[feasible], positions


def build_feasible_set(
    scenario: Scenario,
    window: Window,
    actor_id: str,
    config: PerturberConfig,
    rng: np.random.Generator,
    *,
    drivable: DrivableArea | None = None,
    obstacles: WindowObstacles | None = None,
) -> FeasibleSet:
    """Sample config.num_candidates deltas for one actor and keep the physically plausible ones.

    ``drivable`` and ``obstacles`` default to drivable_area_for(scenario) and
    window_obstacles(scenario, window); pass them in to share them between actors.
    Raises InfeasibleError if the actor cannot be fitted (not labelled at the window start).
    """
    reference = fit_reference(scenario, window, actor_id, config)
    if drivable is None:
        drivable = drivable_area_for(scenario, config.drivable, config.ego_forward_offset)
    if obstacles is None:
        obstacles = window_obstacles(scenario, window, config)
    pruner = _Pruner(reference, config, drivable, obstacles)
    dim, steps = config.perturbation_dim, reference.num_steps
    tally = {"kinematic": 0, "drivable": 0, "ego": 0, "actors": 0}
    removed = dict.fromkeys(KINEMATIC_CHECKS, 0)
    kept_deltas: list[Float32Array] = []
    kept_positions: list[Float32Array] = []
    # Bounds and drivable area run on cache-sized chunks; the collision tests, whose cost is
    # mostly per call, on batches of at least COLLISION_BATCH survivors.
    pending: list[tuple[Float32Array, Float32Array, Float32Array, Float32Array]] = []
    pending_count = 0
    for start in range(0, config.num_candidates, config.chunk_size):
        count = min(config.chunk_size, config.num_candidates - start)
        deltas = rng.random((count, dim), dtype=np.float32) * np.float32(2.0) - np.float32(1.0)
        if start == 0:
            deltas[0] = 0.0  # the logged behaviour is always a candidate
        pending.append(pruner.on_road(deltas, tally, removed))
        pending_count += pending[-1][0].shape[0]
        if pending_count >= COLLISION_BATCH or start + count >= config.num_candidates:
            batch_deltas = np.concatenate([part[0] for part in pending])
            x, y, yaw = (np.concatenate([part[i] for part in pending], axis=1) for i in (1, 2, 3))
            survivors, positions = pruner.collision_free(batch_deltas, x, y, yaw, tally)
            kept_deltas.append(survivors)
            kept_positions.append(positions)
            pending, pending_count = [], 0
    counts = PruningCounts(
        sampled=config.num_candidates,
        kinematic=tally["kinematic"],
        drivable=tally["drivable"],
        ego=tally["ego"],
        actors=tally["actors"],
        violations=removed,
    )
    all_deltas = np.concatenate(kept_deltas) if kept_deltas else np.zeros((0, dim), dtype=np.float32)
    positions = np.concatenate(kept_positions) if kept_positions else np.zeros((0, 2 * steps), dtype=np.float32)
    return FeasibleSet(reference, config, all_deltas, positions, counts)


class _Ranking:
    """One actor's feasible candidates in ascending L2 distance to a query, fetched in growing prefixes."""

    def __init__(self, feasible: FeasibleSet, query: PerturbedTrajectory) -> None:
        self.feasible = feasible
        origin = feasible.reference.origin
        self.query = np.column_stack([query.x - origin[0], query.y - origin[1]]).reshape(-1)
        self.indices = np.zeros(0, dtype=np.int64)
        self.distances = np.zeros(0)
        self.fetch(feasible.config.projection_candidates)

    def fetch(self, count: int) -> None:
        """Make sure the `count` nearest candidates are ranked (fewer if the set is smaller)."""
        count = min(count, self.feasible.size)
        if count > self.indices.size:
            self.indices, self.distances = self.feasible.index.nearest(self.feasible.positions, self.query, count)

    def block(self, start: int, length: int) -> tuple[IntArray, FloatArray]:
        """Candidate indices and distances of ranks start .. start + length - 1 (fewer at the end)."""
        if start + length > self.indices.size:
            self.fetch(max(4 * self.indices.size, start + length))
        return self.indices[start : start + length], self.distances[start : start + length]


class _BudgetSpentError(Exception):
    """The joint projection checked its maximum number of candidates."""


def _joint_nearest(rankings: Sequence[_Ranking], max_checked: int) -> tuple[PerturbedTrajectory, ...]:
    """Branch and bound for the candidates minimising the summed squared distances, pairwise collision-free.

    Actor by actor, candidates are visited in ascending distance and checked, in blocks that grow
    fourfold, against the ones already chosen; a branch stops as soon as its cost bound reaches
    the best full solution found so far. The search starts from the logged behaviours (the zero
    deltas) when they are feasible together, and after max_checked candidates it returns the
    best solution found, so a query never takes long.
    """
    count = len(rankings)
    floors = [float(ranking.distances[0] ** 2) for ranking in rankings]
    best_cost, best = _logged_combination(rankings)
    checked = 0
    first_block = max(1, rankings[0].feasible.config.projection_candidates)

    def search(level: int, chosen: list[PerturbedTrajectory], chosen_boxes: list[FloatArray], cost: float) -> None:
        nonlocal best_cost, best, checked
        ranking = rankings[level]
        floor = sum(floors[level + 1 :])
        start, size = 0, first_block
        while start < ranking.feasible.size:
            indices, distances = ranking.block(start, size)
            squared = distances**2
            viable = int(np.count_nonzero(cost + squared + floor < best_cost))
            if viable == 0:
                return  # ranks are ascending: nothing further can beat the best
            if checked + viable > max_checked:
                raise _BudgetSpentError
            checked += viable
            feasible = ranking.feasible
            deltas = feasible.deltas[indices[:viable]].astype(np.float64)
            batch = _RolloutBatch(feasible.reference, deltas, feasible.config)
            boxes = batch.boxes()  # (T, n, 5)
            clear = np.ones(viable, dtype=bool)
            for other in chosen_boxes:
                clear &= ~np.any(boxes_overlap(boxes, other[:, None, :]), axis=0)
            for column in np.nonzero(clear)[0]:
                total = cost + float(squared[column])
                if total + floor >= best_cost:
                    return
                trajectory = batch.trajectory(int(column))
                if level == count - 1:
                    best_cost, best = total, [*chosen, trajectory]
                    return  # later candidates of the last actor are farther
                search(level + 1, [*chosen, trajectory], [*chosen_boxes, boxes[:, column]], total)
            if viable < indices.size:
                return
            start, size = start + size, 4 * size

    with contextlib.suppress(_BudgetSpentError):
        search(0, [], [], 0.0)
    if not best:
        raise InfeasibleError(
            f"no collision-free combination of feasible candidates of actors {[r.feasible.actor_id for r in rankings]}"
            f" found within {max_checked} checked candidates"
        )
    return tuple(best)


def _logged_combination(rankings: Sequence[_Ranking]) -> tuple[float, list[PerturbedTrajectory]]:
    """The zero-delta candidates of every actor and their summed squared distance, if all are feasible together."""
    chosen: list[PerturbedTrajectory] = []
    cost = 0.0
    for ranking in rankings:
        feasible = ranking.feasible
        if feasible.size == 0 or np.any(feasible.deltas[0] != 0):
            return math.inf, []
        trajectory = feasible.trajectory(0)
        if any(np.any(boxes_overlap(trajectory.boxes(), other.boxes())) for other in chosen):
            return math.inf, []
        chosen.append(trajectory)
        cost += float(np.sum((feasible.positions[0].astype(np.float64) - ranking.query) ** 2))
    return cost, chosen


def project(sets: Sequence[FeasibleSet], delta: npt.ArrayLike) -> tuple[PerturbedTrajectory, ...]:
    """Project a concatenated delta (m D,) onto the feasible sets: one trajectory per actor, in order.

    Each block is rolled out and replaced by the feasible candidate whose positions over the
    horizon are L2-nearest; with several actors the sum of squared distances is minimised over
    combinations whose trajectories do not overlap each other. Deterministic: ties go to the
    lower candidate index.
    """
    if not sets:
        raise ScenarioError("project: no feasible sets given")
    config = sets[0].config
    values = np.asarray(delta, dtype=np.float64)
    dim = config.perturbation_dim
    if values.shape != (dim * len(sets),):
        raise ScenarioError(
            f"project: expected delta of {dim * len(sets)} entries for {len(sets)} actors, got {values.shape}"
        )
    empty = [feasible.actor_id for feasible in sets if feasible.size == 0]
    if empty:
        raise InfeasibleError(f"project: actors {empty} have no feasible candidates")
    rankings = [
        _Ranking(feasible, perturbation_to_trajectory(feasible.reference, values[i * dim : (i + 1) * dim], config))
        for i, feasible in enumerate(sets)
    ]
    return _joint_nearest(rankings, MAX_JOINT_CHECKED)


@dataclass(frozen=True)
class ActorReport:
    """Why an actor was or was not perturbed."""

    actor_id: str
    actor_class: str
    min_distance: float  # smallest gap to the SDV's box over the window's labelled frames [m]
    selected: bool
    reason: str  # "selected", or why not
    counts: PruningCounts | None  # pruning statistics when a feasible set was built
    fit_rmse: float | None  # bicycle-model fit of the logged track [m]


@dataclass(frozen=True, eq=False)
class ActorSelection:
    """The actors to perturb in a window, their feasible sets (delta block order) and a report on every actor."""

    window: Window
    sets: tuple[FeasibleSet, ...]
    reports: tuple[ActorReport, ...]

    @property
    def actor_ids(self) -> tuple[str, ...]:
        return tuple(feasible.actor_id for feasible in self.sets)

    @property
    def dimension(self) -> int:
        """Length of the concatenated delta the search works on."""
        return sum(feasible.config.perturbation_dim for feasible in self.sets)

    def project(self, delta: npt.ArrayLike) -> tuple[PerturbedTrajectory, ...]:
        return project(self.sets, delta)

    def project_perturbation(self, perturbation: Perturbation) -> tuple[PerturbedTrajectory, ...]:
        """A query's trajectories: none for the original scenario (empty delta), else the projection of its delta."""
        if perturbation.delta.size == 0:
            return ()
        if perturbation.actor_ids != self.actor_ids:
            raise InfeasibleError(
                f"query {perturbation.query_id} perturbs actors {list(perturbation.actor_ids)}, "
                f"the feasible sets are for {list(self.actor_ids)}"
            )
        return self.project(perturbation.delta)


def rank_actors(scenario: Scenario, window: Window, config: PerturberConfig) -> list[tuple[str, float]]:
    """Every actor present in the window with its smallest box gap to the SDV over the window [m], closest first."""
    stamps = window.stamps(scenario, config.frame_period)
    ego = ego_window_boxes(scenario, window, config)
    ranked: list[tuple[str, float]] = []
    for actor in scenario.actors:
        boxes, present = actor_window_boxes(actor, stamps)
        if np.any(present):
            ranked.append((actor.actor_id, float(np.min(box_distance(boxes[present], ego[present])))))
    ranked.sort(key=lambda item: (item[1], item[0]))
    return ranked


def select_actors(
    scenario: Scenario,
    window: Window,
    config: PerturberConfig,
    rng: np.random.Generator,
    *,
    drivable: DrivableArea | None = None,
) -> ActorSelection:
    """Perturb the config.num_actors actors closest to the SDV that keep >= config.min_feasible candidates.

    Actors are tried closest first; an actor of a class not in perturbable_classes, unlabelled at
    the window start or labelled in fewer than min_observed_steps frames is skipped, and with
    several actors one is added only if a collision-free combination with those already chosen
    exists. Raises InfeasibleError (its message lists every actor tried) if fewer are found.
    """
    if drivable is None:
        drivable = drivable_area_for(scenario, config.drivable, config.ego_forward_offset)
    obstacles = window_obstacles(scenario, window, config)
    stamps = window.stamps(scenario, config.frame_period)
    chosen: list[FeasibleSet] = []
    reports: list[ActorReport] = []
    for actor_id, gap in rank_actors(scenario, window, config):
        actor = scenario.actor(actor_id)
        steps, _ = _window_observations(actor, stamps)

        def report(reason: str, counts: PruningCounts | None = None, rmse: float | None = None) -> None:
            reports.append(
                ActorReport(actor_id, actor.actor_class.value, gap, reason == "selected", reason, counts, rmse)  # noqa: B023
            )

        if len(chosen) == config.num_actors:
            report("not needed: enough actors selected")
            continue
        if actor.actor_class.value not in config.perturbable_classes:
            report(f"class {actor.actor_class.value} is not perturbable")
            continue
        standing = is_standing(actor)
        if not standing and (steps.size == 0 or steps[0] != 0):
            report("not labelled at the window start")
            continue
        if not standing and steps.size < config.min_observed_steps:
            report(f"labelled in only {steps.size} of {window.num_steps} frames")
            continue
        feasible = build_feasible_set(scenario, window, actor_id, config, rng, drivable=drivable, obstacles=obstacles)
        rmse = feasible.reference.fit.position_rmse
        if feasible.size < config.min_feasible:
            report(f"only {feasible.size} feasible candidates (< {config.min_feasible})", feasible.counts, rmse)
            continue
        if chosen:
            try:
                zeros = np.zeros(config.perturbation_dim * (len(chosen) + 1))
                project([*chosen, feasible], zeros)
            except InfeasibleError:
                report("every candidate collides with the actors already selected", feasible.counts, rmse)
                continue
        chosen.append(feasible)
        report("selected", feasible.counts, rmse)
    selection = ActorSelection(window=window, sets=tuple(chosen), reports=tuple(reports))
    if len(chosen) < config.num_actors:
        lines = "; ".join(f"{r.actor_id}: {r.reason}" for r in reports) or "no actor is labelled in the window"
        raise InfeasibleError(
            f"scenario {scenario.scenario_id} window at frame {window.start_frame}: found {len(chosen)} of "
            f"{config.num_actors} perturbable actors ({lines})",
            tuple(reports),
        )
    return selection
