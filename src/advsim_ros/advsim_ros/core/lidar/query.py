"""The LiDAR sweep one query's stack sees at one frame: a pure function of the perturbed world.

The ray drop of re-simulated points is random; its generator is seeded from the attack's seed,
the frame and the *content* of the perturbed tracks (never from the query's number), so the
same perturbation gives the same sweep whenever it is queried: a re-run of the best query sees
exactly what the search saw.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from advsim_ros.core.digest import Digest
from advsim_ros.core.lidar.resim import ResimModel
from advsim_ros.core.types import ActorTrack, FloatArray, Scenario, Sweep, replace_actors


def world_rng(seed: int, moved: Sequence[ActorTrack], log_stamp_ns: int) -> np.random.Generator:
    """The generator of one frame of one perturbed world."""
    digest = Digest("resim ray drop")
    digest.integer(seed)
    digest.integer(log_stamp_ns)
    for track in sorted(moved, key=lambda t: t.actor_id):
        digest.text(track.actor_id)
        digest.array(track.stamps_ns)
        digest.array(track.centers)
        digest.array(track.yaws)
        digest.array(track.size)
    return np.random.default_rng(digest.seed_words())


def query_sweep(
    model: ResimModel | None,
    scenario: Scenario,
    logged: Sweep,
    world_T_ego: FloatArray,
    moved: Sequence[ActorTrack],
    seed: int,
) -> np.ndarray:
    """The points (sweep's own fields) of the logged sweep with ``moved`` actors re-simulated, seen from world_T_ego.

    Every moved actor is re-simulated, also where its pose equals the logged one: the identity
    control (the actors re-inserted on their logged tracks) then measures exactly the rendering
    every perturbed actor gets. Without moved actors the logged points come back unchanged (no
    model is needed then).
    """
    if not moved:
        return logged.points
    if model is None:
        raise ValueError("query_sweep: actors moved but no re-simulation model was given")
    sweep = Sweep(logged.stamp_ns, logged.frame_id, logged.points, world_T_ego @ scenario.ego_T_sensor)
    world = replace_actors(scenario.actors, moved)
    rng = world_rng(seed, moved, logged.stamp_ns)
    return model.resimulate(sweep, scenario.actors, world, rng=rng, moved={track.actor_id for track in moved})
