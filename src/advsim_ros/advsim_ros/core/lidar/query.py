"""The LiDAR sweep one query's stack sees at one frame: a pure function of the perturbed world.

A requested frame's sweep (``frame_sweep``, what lidar_resim answers a FrameRequest with) is the
logged sweep with the moved actors re-simulated (``query_sweep``), seen from where the request puts
the ego. In closed loop a request may place the ego away from where it was logged: beyond
render_distance / render_yaw (``moved_away``) the sweep is rendered from the model at that pose
(core.lidar.novel_view) instead, as it is for a frame the log has no sweep of.

The ray drop of re-simulated points is random; its generator is seeded from the attack's seed,
the frame and the *content* of the perturbed tracks (never from the query's number), so the
same perturbation gives the same sweep whenever it is queried: a re-run of the best query sees
exactly what the search saw.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from advsim_ros.core.digest import Digest
from advsim_ros.core.lidar.config import ResimNodeConfig
from advsim_ros.core.lidar.novel_view import render_from_model
from advsim_ros.core.lidar.resim import ResimModel
from advsim_ros.core.types import ActorTrack, FloatArray, Scenario, ScenarioError, Sweep, replace_actors


def world_rng(seed: int, moved: Sequence[ActorTrack], log_stamp_ns: int) -> np.random.Generator:
    """The generator of one frame of one perturbed world."""
    digest = Digest("resim ray drop")
    digest.integer(seed)
    digest.integer(log_stamp_ns)
    _add_tracks(digest, moved)
    return np.random.default_rng(digest.seed_words())


def tracks_digest(moved: Sequence[ActorTrack]) -> str:
    """The content of a perturbed world's moved tracks: equal digests, equal re-simulated sweeps."""
    digest = Digest("moved tracks")
    _add_tracks(digest, moved)
    return digest.hexdigest()


def _add_tracks(digest: Digest, moved: Sequence[ActorTrack]) -> None:
    for track in sorted(moved, key=lambda t: t.actor_id):
        digest.text(track.actor_id)
        digest.array(track.stamps_ns)
        digest.array(track.centers)
        digest.array(track.yaws)
        digest.array(track.size)


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


def moved_away(world_T_ego: FloatArray, logged: FloatArray, distance: float, yaw: float) -> bool:
    """Whether the ego is further from its logged pose than the re-simulation of the logged sweep allows."""
    offset = float(np.linalg.norm(world_T_ego[:2, 3] - logged[:2, 3]))
    turned = abs(float(np.arctan2(world_T_ego[1, 0], world_T_ego[0, 0]) - np.arctan2(logged[1, 0], logged[0, 0])))
    return offset > distance or min(turned, 2 * np.pi - turned) > yaw


def frame_sweep(
    model: ResimModel | None,
    scenario: Scenario,
    sweeps: Mapping[int, Sweep],
    log_frame: int,
    sim_stamp_ns: int,
    world_T_ego: FloatArray,
    moved: tuple[ActorTrack, ...],
    config: ResimNodeConfig,
) -> Sweep:
    """The sweep of log frame ``log_frame`` in the perturbed world, stamped sim_stamp_ns, the ego at world_T_ego.

    ``sweeps``: the logged sweeps kept, by stamp. It keeps the logged sweep's frame and fields; a sweep
    rendered from the model (closed loop, module docstring) gets the first kept sweep's frame.
    """
    stamp = int(scenario.frame_stamps_ns[log_frame])
    logged = sweeps.get(stamp)
    logged_pose = scenario.ego.poses[log_frame]
    if logged is None or moved_away(world_T_ego, logged_pose, config.render_distance, config.render_yaw):
        # closed loop: the sweep from where the ego drove (or of a frame the log has no sweep of)
        if model is None:
            raise ScenarioError("closed loop: a sweep must be rendered from the model, and none was built")
        sensor_pose = world_T_ego @ scenario.ego_T_sensor
        world = replace_actors(scenario.actors, moved)
        rng = world_rng(config.seed, moved, stamp)
        points = render_from_model(model, scenario, sensor_pose, world, stamp, rng)
        return Sweep(sim_stamp_ns, scenario.sweeps[0].frame_id, points, sensor_pose)
    points = query_sweep(model, scenario, logged, world_T_ego, moved, config.seed)
    return Sweep(sim_stamp_ns, logged.frame_id, points, logged.sensor_pose)
