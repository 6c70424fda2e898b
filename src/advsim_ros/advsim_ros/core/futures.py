"""Poses at given stamps: linear interpolation in time, and the actors' futures over their observed spans.

An actor exists only where the log (or the perturber) says it does: over the span from its first
to its last observation, linear in time in between (also across frames it was not labelled in),
and for at most ``extrapolation`` seconds beyond either end, continued at the constant velocity of
its first or last two observations (heading held). Outside that it is absent: ``ActorFutures.present``
is False there and its state is NaN, so no collision, gap, range or prediction test can see it.

Why a small extrapolation and not none: plan stamps are the decision stamp plus multiples of the
plan step, frames are the sensor's own stamps. On the Argoverse 2 logs frames are 100.196 ms apart
with up to 3.6 ms of jitter, so 5 s after the decision a plan stamp is ~10 ms from the frame it
belongs to (the closed loop samples every 20 ms). Half a 10 Hz frame period (the default, 0.05 s)
gives every instant to its nearest frame: an actor exists at the instants nearest the frames it
was seen in, never for a whole frame in which it was not. Holding it (the old rule) made a track
that begins 4 s after the decision stand at its first position from the decision on.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from advsim_ros.core.geometry import wrap_angle
from advsim_ros.core.types import ActorTrack, FloatArray, ScenarioError

NS_PER_S = 1_000_000_000
ACTOR_EXTRAPOLATION = 0.05  # default reach beyond an actor's first and last observation [s] (module docstring)
MAX_ACTOR_EXTRAPOLATION = 0.5  # a larger reach would invent an actor for several frames it was not seen in [s]
BoolArray = npt.NDArray[np.bool_]


def interpolate_trajectory(
    stamps_ns: npt.NDArray[np.int64],
    xy: FloatArray,
    yaws: FloatArray,
    query_ns: npt.NDArray[np.int64],
) -> tuple[FloatArray, FloatArray, BoolArray]:
    """Poses at query stamps, linear in time (headings unwrapped); valid marks queries inside the span.

    Outside the span the first or last pose is returned: callers use ``valid`` to leave those out.
    """
    reference = stamps_ns[0]
    times = (stamps_ns - reference).astype(np.float64)
    queries = (np.asarray(query_ns, dtype=np.int64) - reference).astype(np.float64)
    valid = (query_ns >= stamps_ns[0]) & (query_ns <= stamps_ns[-1])
    unwrapped = np.unwrap(yaws)
    out_xy = np.stack([np.interp(queries, times, xy[:, 0]), np.interp(queries, times, xy[:, 1])], axis=-1)
    out_yaw = wrap_angle(np.interp(queries, times, unwrapped))
    return out_xy, np.asarray(out_yaw, dtype=np.float64), valid


@dataclass(frozen=True, eq=False)
class ActorFutures:
    """The actors' futures sampled at the plan's stamps, in the world frame, with where each exists.

    ``valid`` defaults to everywhere (a perturbed or hand-made future that spans the plan); ``present`` is
    the mask as given. States where an actor is absent are set to NaN: a consumer must mask with
    ``present``, never read a held state.
    """

    states: FloatArray  # (N, H, 3) box centre x, y [m] and heading [rad] at each plan stamp; NaN where absent
    sizes: FloatArray  # (N, 2) box length, width [m]
    valid: BoolArray | None = None  # (N, H) whether the actor exists at each plan stamp; None: everywhere

    def __post_init__(self) -> None:
        states = np.array(self.states, dtype=np.float64)
        sizes = np.asarray(self.sizes, dtype=np.float64)
        if states.ndim != 3 or states.shape[2] != 3:
            raise ScenarioError(f"ActorFutures states: expected shape (N, H, 3) = [x, y, yaw], got {states.shape}")
        if sizes.shape != (states.shape[0], 2):
            raise ScenarioError(f"ActorFutures sizes: expected shape ({states.shape[0]}, 2), got {sizes.shape}")
        valid = np.ones(states.shape[:2], dtype=bool) if self.valid is None else np.asarray(self.valid, dtype=bool)
        if valid.shape != states.shape[:2]:
            raise ScenarioError(f"ActorFutures valid: expected shape {states.shape[:2]}, got {valid.shape}")
        if not (np.all(np.isfinite(states[valid])) and np.all(np.isfinite(sizes))):
            raise ScenarioError("ActorFutures: states (where valid) and sizes must be finite")
        if np.any(sizes <= 0.0):
            raise ScenarioError("ActorFutures sizes: lengths and widths must be positive")
        states[~valid] = np.nan
        object.__setattr__(self, "states", states)
        object.__setattr__(self, "sizes", sizes)
        object.__setattr__(self, "valid", valid)

    @property
    def num_actors(self) -> int:
        return int(self.states.shape[0])

    @property
    def present(self) -> BoolArray:
        """(N, H) where each actor exists."""
        assert self.valid is not None  # set in __post_init__
        return self.valid

    def boxes(self) -> FloatArray:
        """(N, H, 5) boxes [x, y, yaw, length, width]; NaN where the actor is absent."""
        count, steps = self.states.shape[:2]
        sizes = np.broadcast_to(self.sizes[:, None, :], (count, steps, 2))
        return np.concatenate([self.states, sizes], axis=-1)

    def finite_boxes(self) -> FloatArray:
        """boxes() with absent entries at the origin, for vectorised geometry whose results are then masked."""
        boxes: FloatArray = np.nan_to_num(self.boxes(), nan=0.0)
        return boxes


def _continued(track: ActorTrack, end: int, offsets_s: FloatArray) -> FloatArray:
    """(K, 2) positions ``offsets_s`` seconds from the track's first (end 0) or last (end -1) observation,
    at the constant velocity of its two observations there (standing when it has one)."""
    xy = track.centers[:, :2]
    if xy.shape[0] < 2:
        return np.repeat(xy[end][None], offsets_s.shape[0], axis=0)
    pair = slice(0, 2) if end == 0 else slice(-2, None)
    elapsed = float(np.diff(track.stamps_ns[pair])[0]) / NS_PER_S
    velocity = np.diff(xy[pair], axis=0)[0] / elapsed
    continued: FloatArray = xy[end] + offsets_s[:, None] * velocity
    return continued


def actor_futures_at(
    tracks: Iterable[ActorTrack], stamps_ns: npt.NDArray[np.int64], extrapolation: float = ACTOR_EXTRAPOLATION
) -> ActorFutures:
    """The actors' states at the given stamps (the plan's) over their observed spans (module docstring).

    ``extrapolation`` [s] is MetricsConfig.actor_extrapolation wherever a metrics config is at hand.
    """
    if not (np.isfinite(extrapolation) and 0.0 <= extrapolation <= MAX_ACTOR_EXTRAPOLATION):
        raise ScenarioError(f"actor extrapolation: must be in [0, {MAX_ACTOR_EXTRAPOLATION}] s, got {extrapolation}")
    tracks = tuple(tracks)
    stamps = np.asarray(stamps_ns, dtype=np.int64)
    reach = round(extrapolation * NS_PER_S)
    states = np.empty((len(tracks), stamps.shape[0], 3))
    valid = np.zeros((len(tracks), stamps.shape[0]), dtype=bool)
    for index, track in enumerate(tracks):
        xy, yaws, inside = interpolate_trajectory(track.stamps_ns, track.centers[:, :2], track.yaws, stamps)
        first, last = int(track.stamps_ns[0]), int(track.stamps_ns[-1])
        before = (stamps < first) & (stamps >= first - reach)
        after = (stamps > last) & (stamps <= last + reach)
        xy[before] = _continued(track, 0, (stamps[before] - first).astype(np.float64) / NS_PER_S)
        xy[after] = _continued(track, -1, (stamps[after] - last).astype(np.float64) / NS_PER_S)
        states[index, :, :2], states[index, :, 2] = xy, yaws  # headings: the nearest observation's beyond the ends
        valid[index] = inside | before | after
    sizes = np.array([track.size[:2] for track in tracks]).reshape(-1, 2)
    return ActorFutures(states, sizes, valid)
