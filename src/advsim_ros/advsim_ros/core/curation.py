"""Scenario curation (AdvSim, Wang et al. CVPR 2021, supplementary material).

Every ``step_frames`` (2 s), take a candidate window of 1 s history + 5 s future. At its
decision frame, sample SDV trajectories in the ego's Frenet frame (the logged ego path
is the reference line): a grid of constant accelerations, each kept in lane or moved one
lane left or right by a smooth quintic lane change of a few durations. A trajectory
collides if the SDV box overlaps an actor's logged box at any future frame; the vehicle
directly ahead in the ego's lane and static actors are ignored, since following a lead
car or passing parked cars is not what makes a scenario safety-critical. The window
whose trajectories collide most often is the most interesting one to attack.

Windows are in frames, like the scenario player's WindowConfig: ``start_frame`` is its
``window_start_frame``; the decision frame is the last history frame.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from advsim_ros.core.geometry import BoolArray, boxes_overlap
from advsim_ros.core.params import config_from_mapping, load_node_params
from advsim_ros.core.types import ActorClass, ActorTrack, EgoTrajectory, FloatArray, Scenario, ScenarioError

CURATION_NODE = "curation"  # params/curation.yaml: /curation: ros__parameters: ...


@dataclass(frozen=True)
class CurationConfig:
    """Scenario-curation settings (params/curation.yaml)."""

    history_frames: int = 10  # frames up to and including the decision frame (1 s at 10 Hz)
    future_frames: int = 50  # frames after the decision frame that the SDV's plan covers (5 s)
    step_frames: int = 20  # candidate windows start this many frames apart (2 s)
    frame_period: float = 0.1  # expected spacing of the log's frames [s]
    accelerations: tuple[float, ...] = (-3.0, -2.0, -1.0, 0.0, 1.0, 2.0)  # longitudinal profiles [m/s^2]
    lane_width: float = 3.5  # lateral offset of a lane change, and the width of the ego's lane [m]
    lane_change_durations: tuple[float, ...] = (3.0, 5.0)  # time a lane change takes [s]
    max_speed: float = 15.0  # SDV speed limit of the sampled trajectories [m/s]
    static_speed: float = 0.5  # actors whose net displacement over the window is slower are static [m/s]
    lead_max_distance: float = 50.0  # the ignored lead vehicle is at most this far ahead [m]

    def __post_init__(self) -> None:
        for name in ("history_frames", "future_frames", "step_frames"):
            if getattr(self, name) < 1:
                raise ScenarioError(f"CurationConfig {name}: must be >= 1, got {getattr(self, name)}")
        for name in ("frame_period", "lane_width", "max_speed", "lead_max_distance"):
            if not getattr(self, name) > 0.0:
                raise ScenarioError(f"CurationConfig {name}: must be positive, got {getattr(self, name)}")
        if self.static_speed < 0.0:
            raise ScenarioError(f"CurationConfig static_speed: must be >= 0, got {self.static_speed}")
        if not self.accelerations:
            raise ScenarioError("CurationConfig accelerations: needs at least one value")
        if any(not duration > 0.0 for duration in self.lane_change_durations):
            raise ScenarioError(
                f"CurationConfig lane_change_durations: must be positive, got {self.lane_change_durations}"
            )

    @property
    def num_trajectories(self) -> int:
        """Sampled SDV trajectories per window: every acceleration, kept in lane or changed left/right."""
        return len(self.accelerations) * (1 + 2 * len(self.lane_change_durations))


def load_curation_config(path: Path) -> CurationConfig:
    """CurationConfig from a params file in the ROS shape (``/curation: ros__parameters: ...``)."""
    return config_from_mapping(CurationConfig, load_node_params(path, CURATION_NODE), f"{path} /{CURATION_NODE}")


@dataclass(frozen=True)
class CurationWindow:
    """One candidate window and how often sampled SDV trajectories collide in it."""

    start_frame: int  # first history frame (WindowConfig.window_start_frame)
    decision_frame: int  # last history frame: the stack plans from here
    end_frame: int  # last future frame
    start_ns: int  # stamp of start_frame [ns]
    decision_ns: int  # stamp of decision_frame [ns]
    end_ns: int  # stamp of end_frame [ns]
    collision_rate: float  # fraction of sampled SDV trajectories that collide [0, 1]
    num_trajectories: int  # trajectories sampled
    num_actors: int  # moving actors checked (static actors and the lead vehicle left out)
    lead_actor_id: str  # the ignored vehicle directly ahead; "" when there is none


def _reference_path(ego: EgoTrajectory, decision: int, end: int, reach: float) -> FloatArray:
    """(P, 2) the ego's logged path from the decision frame on, extended straight by ``reach`` [m]."""
    xy = ego.xy[decision : end + 1]
    keep = [0]
    for index in range(1, xy.shape[0]):
        if np.linalg.norm(xy[index] - xy[keep[-1]]) > 0.1:  # drop standstill jitter below 10 cm
            keep.append(index)
    path = xy[keep]
    if path.shape[0] >= 2:
        direction = path[-1] - path[-2]
    else:
        yaw = float(ego.yaws[decision])
        direction = np.array([np.cos(yaw), np.sin(yaw)])
    direction = direction / np.linalg.norm(direction)
    extended: FloatArray = np.vstack([path, path[-1] + reach * direction])
    return extended


def _arc_lengths(path: FloatArray) -> FloatArray:
    steps = np.linalg.norm(np.diff(path, axis=0), axis=1)
    arc: FloatArray = np.concatenate([[0.0], np.cumsum(steps)])
    return arc


def frenet_to_world(path: FloatArray, s: FloatArray, d: FloatArray) -> FloatArray:
    """(..., 2) world points at arc length s [m] along the path and lateral offset d [m] (left positive)."""
    arc = _arc_lengths(path)
    segment = np.clip(np.searchsorted(arc, s, side="right") - 1, 0, path.shape[0] - 2)
    tangent = path[segment + 1] - path[segment]
    tangent = tangent / np.linalg.norm(tangent, axis=-1, keepdims=True)
    normal = np.stack([-tangent[..., 1], tangent[..., 0]], axis=-1)
    along = (s - arc[segment])[..., None]
    points: FloatArray = path[segment] + along * tangent + d[..., None] * normal
    return points


def world_to_frenet(path: FloatArray, points: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Arc length s [m] and signed lateral offset d [m] of (N, 2) points projected onto the path."""
    starts, ends = path[:-1], path[1:]
    segment = ends - starts
    length_sq = np.sum(segment * segment, axis=-1)
    offset = points[:, None, :] - starts[None]
    fraction = np.clip(np.sum(offset * segment[None], axis=-1) / length_sq[None], 0.0, 1.0)
    closest = starts[None] + fraction[..., None] * segment[None]
    nearest = np.argmin(np.linalg.norm(points[:, None, :] - closest, axis=-1), axis=1)
    rows = np.arange(points.shape[0])
    arc = _arc_lengths(path)
    s = arc[nearest] + fraction[rows, nearest] * np.sqrt(length_sq[nearest])
    tangent = segment[nearest] / np.sqrt(length_sq[nearest])[:, None]
    relative = points - closest[rows, nearest]
    d = tangent[:, 0] * relative[:, 1] - tangent[:, 1] * relative[:, 0]
    return s, d


def _distance_travelled(speed: float, acceleration: float, times: FloatArray, max_speed: float) -> FloatArray:
    """Distance [m] after ``times`` [s] from ``speed`` [m/s] at constant acceleration, speed kept in [0, max]."""
    if acceleration < 0.0:
        limit_time = speed / -acceleration
        limit_speed = 0.0
    elif acceleration > 0.0 and speed < max_speed:
        limit_time = (max_speed - speed) / acceleration
        limit_speed = max_speed
    else:
        result: FloatArray = np.minimum(speed, max_speed) * times
        return result
    ramp = np.minimum(times, limit_time)
    distance: FloatArray = speed * ramp + 0.5 * acceleration * ramp**2 + limit_speed * (times - ramp)
    return distance


def _smoothstep(fraction: FloatArray) -> FloatArray:
    """Quintic 0 -> 1 with zero velocity and acceleration at both ends."""
    u = np.clip(fraction, 0.0, 1.0)
    result: FloatArray = u**3 * (10.0 - 15.0 * u + 6.0 * u**2)
    return result


def sample_sdv_trajectories(
    path: FloatArray, speed: float, times: FloatArray, config: CurationConfig
) -> tuple[FloatArray, FloatArray]:
    """(N, K, 2) positions [m] and (N, K) headings [rad] of the sampled SDV trajectories at ``times`` [s].

    Rows: for each acceleration, keep lane, then for each duration a change left and right.
    """
    laterals = [(0.0, 1.0)]
    for duration in config.lane_change_durations:
        laterals += [(config.lane_width, duration), (-config.lane_width, duration)]
    s_rows, d_rows = [], []
    for acceleration in config.accelerations:
        s = _distance_travelled(speed, acceleration, times, config.max_speed)
        for offset, duration in laterals:
            s_rows.append(s)
            d_rows.append(offset * _smoothstep(times / duration))
    start = np.zeros((len(s_rows), 1))  # every trajectory starts at the SDV: s = d = 0 at t = 0
    s_full = np.concatenate([start, np.array(s_rows)], axis=1)
    d_full = np.concatenate([start, np.array(d_rows)], axis=1)
    xy = frenet_to_world(path, s_full, d_full)
    velocity = np.gradient(xy, np.concatenate([[0.0], times]), axis=1)
    moving = np.linalg.norm(velocity, axis=-1) > 1e-3
    # A standing SDV keeps the path's heading; a moving one heads where it goes.
    ahead = frenet_to_world(path, s_full + 0.5, d_full) - frenet_to_world(path, s_full, d_full)
    headings = np.where(
        moving, np.arctan2(velocity[..., 1], velocity[..., 0]), np.arctan2(ahead[..., 1], ahead[..., 0])
    )
    return xy[:, 1:], headings[:, 1:]


def _net_speed(actor: ActorTrack, first_ns: int, last_ns: int) -> float:
    """Net displacement over the window divided by the time between first and last observation [m/s]."""
    inside = (actor.stamps_ns >= first_ns) & (actor.stamps_ns <= last_ns)
    if np.count_nonzero(inside) < 2:
        return 0.0
    centers, stamps = actor.centers[inside], actor.stamps_ns[inside]
    elapsed = (stamps[-1] - stamps[0]) * 1e-9
    return float(np.linalg.norm(centers[-1, :2] - centers[0, :2]) / elapsed)


def _lead_vehicle(scenario: Scenario, path: FloatArray, decision_ns: int, ego_s: float, config: CurationConfig) -> str:
    """The vehicle directly ahead of the SDV in its lane at the decision frame ("" if none)."""
    best_id, best_s = "", np.inf
    for actor in scenario.actors:
        if actor.actor_class is not ActorClass.VEHICLE:
            continue
        index = np.flatnonzero(actor.stamps_ns == decision_ns)
        if not index.size:
            continue
        s, d = world_to_frenet(path, actor.centers[index, :2])
        ahead = float(s[0]) - ego_s
        if 0.0 < ahead <= config.lead_max_distance and abs(float(d[0])) < config.lane_width / 2 and ahead < best_s:
            best_id, best_s = actor.actor_id, ahead
    return best_id


def _actor_boxes(actors: list[ActorTrack], future_ns: np.ndarray) -> tuple[FloatArray, BoolArray]:
    """(M, K, 5) boxes [x, y, yaw, length, width] at the future frames and (M, K) where they are observed."""
    boxes = np.zeros((len(actors), future_ns.shape[0], 5))
    present = np.zeros((len(actors), future_ns.shape[0]), dtype=bool)
    for row, actor in enumerate(actors):
        columns = np.flatnonzero(np.isin(future_ns, actor.stamps_ns))
        observations = np.searchsorted(actor.stamps_ns, future_ns[columns])
        boxes[row, columns, :2] = actor.centers[observations, :2]
        boxes[row, columns, 2] = actor.yaws[observations]
        boxes[row, columns, 3:] = actor.size[:2]
        present[row, columns] = True
    return boxes, present


def evaluate_window(scenario: Scenario, start_frame: int, config: CurationConfig) -> CurationWindow:
    """Collision rate of the sampled SDV trajectories in the window that starts at ``start_frame``."""
    decision = start_frame + config.history_frames - 1
    end = decision + config.future_frames
    if start_frame < 0 or end >= scenario.num_frames:
        raise ScenarioError(
            f"curation window frames {start_frame}..{end} leave scenario {scenario.scenario_id} "
            f"({scenario.num_frames} frames)"
        )
    stamps = scenario.frame_stamps_ns
    future_ns = stamps[decision + 1 : end + 1]
    times = (future_ns - stamps[decision]) * 1e-9
    reach = config.max_speed * float(times[-1]) + 10.0
    path = _reference_path(scenario.ego, decision, end, reach)
    step = (stamps[decision + 1] - stamps[decision - 1]) * 1e-9 if decision > 0 else (stamps[1] - stamps[0]) * 1e-9
    low = max(decision - 1, 0)
    speed = float(np.linalg.norm(scenario.ego.xy[decision + 1] - scenario.ego.xy[low]) / step)
    xy, headings = sample_sdv_trajectories(path, speed, times, config)
    sdv = scenario.ego_geometry.boxes(xy, headings)
    ego_s = float(world_to_frenet(path, scenario.ego.xy[decision : decision + 1])[0][0])
    lead = _lead_vehicle(scenario, path, int(stamps[decision]), ego_s, config)
    moving = [
        actor
        for actor in scenario.actors
        if actor.actor_id != lead
        and _net_speed(actor, int(stamps[start_frame]), int(stamps[end])) >= config.static_speed
    ]
    collides = np.zeros(sdv.shape[0], dtype=bool)
    if moving:
        boxes, present = _actor_boxes(moving, future_ns)
        overlap = boxes_overlap(sdv[:, None, :, :], boxes[None, :, :, :]) & present[None]  # (N, M, K)
        collides = np.any(overlap, axis=(1, 2))
    return CurationWindow(
        start_frame=start_frame,
        decision_frame=decision,
        end_frame=end,
        start_ns=int(stamps[start_frame]),
        decision_ns=int(stamps[decision]),
        end_ns=int(stamps[end]),
        collision_rate=float(np.mean(collides)),
        num_trajectories=int(sdv.shape[0]),
        num_actors=len(moving),
        lead_actor_id=lead,
    )


def curate_windows(scenario: Scenario, config: CurationConfig) -> tuple[CurationWindow, ...]:
    """Every candidate window, ``step_frames`` apart from the first frame; ScenarioError if the log is too short."""
    span = config.history_frames + config.future_frames
    if scenario.num_frames < span:
        raise ScenarioError(
            f"scenario {scenario.scenario_id} has {scenario.num_frames} frames; a curation window needs {span} "
            f"({config.history_frames} history + {config.future_frames} future)"
        )
    spacing = np.diff(scenario.frame_stamps_ns) * 1e-9
    if np.max(np.abs(spacing - config.frame_period)) > 0.5 * config.frame_period:
        raise ScenarioError(
            f"scenario {scenario.scenario_id}: frames are {spacing.min():.3f}..{spacing.max():.3f} s apart, "
            f"expected {config.frame_period} s"
        )
    starts = range(0, scenario.num_frames - span + 1, config.step_frames)
    return tuple(evaluate_window(scenario, start, config) for start in starts)


def best_window(windows: tuple[CurationWindow, ...]) -> CurationWindow:
    """The window with the highest collision rate (the earliest among equals)."""
    if not windows:
        raise ScenarioError("best_window: no windows")
    return max(windows, key=lambda window: (window.collision_rate, -window.start_frame))


def crop_scenario(scenario: Scenario, window: CurationWindow) -> Scenario:
    """The scenario restricted to the window's frames: ego, actors observed in it, sweeps, same map."""
    last = int(np.searchsorted(scenario.frame_stamps_ns, window.end_ns, side="right")) - 1
    return crop_frames(scenario, window.start_frame, last)


def crop_frames(scenario: Scenario, first_frame: int, last_frame: int) -> Scenario:
    """The scenario restricted to frames first..last (inclusive), named ``<id>@<first>``; map and geometry kept."""
    first, last = int(scenario.frame_stamps_ns[first_frame]), int(scenario.frame_stamps_ns[last_frame])
    keep = (scenario.frame_stamps_ns >= first) & (scenario.frame_stamps_ns <= last)
    frames = scenario.frame_stamps_ns[keep]
    actors = [cropped for actor in scenario.actors if (cropped := actor.between(first, last)) is not None]
    return Scenario(
        scenario_id=f"{scenario.scenario_id}@{first_frame}",
        frame_stamps_ns=frames,
        ego=EgoTrajectory(stamps_ns=frames, poses=scenario.ego.poses[keep]),
        actors=tuple(actors),
        sweeps=tuple(sweep for sweep in scenario.sweeps if first <= sweep.stamp_ns <= last),
        ego_T_sensor=scenario.ego_T_sensor,
        sensor=scenario.sensor,
        road_map=scenario.road_map,
        ego_geometry=scenario.ego_geometry,
        sensor_frame=scenario.sensor_frame,
        drivable_area=scenario.drivable_area,
    )
