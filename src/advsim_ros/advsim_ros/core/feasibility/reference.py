"""An actor's logged track over a window, explained by the bicycle model: what delta = 0 replays."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from advsim_ros.core.dynamics import TrackFit, fit_track, standing_fit
from advsim_ros.core.feasibility.config import PerturberConfig
from advsim_ros.core.feasibility.errors import InfeasibleError
from advsim_ros.core.feasibility.window import Window, is_standing, window_observations
from advsim_ros.core.types import ActorClass, BoolArray, FloatArray, IntArray, Scenario


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


def fit_reference(scenario: Scenario, window: Window, actor_id: str, config: PerturberConfig) -> ActorReference:
    """Fit the bicycle model to an actor's logged track over the window.

    The actor must be labelled at the window's first frame, unless it stands still over the
    whole log (then it stands at its median position throughout).
    """
    track = scenario.actor(actor_id)
    stamps = window.stamps(scenario, config.frame_period)
    count = stamps.shape[0]
    dt = float(np.mean(np.diff(stamps))) * 1e-9
    steps, indices = window_observations(track, stamps)
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
