"""Families of synthetic scenes: who drives where in a synthetic street log, and when.

Each family stages one interaction of the kind AdvSim attacks, with every size, gap, speed
and timing drawn from the log's random generator within the ranges written beside it:

- ``street``: the ego passes parked cars, a slower car in the next lane, oncoming traffic
  and a pedestrian on the sidewalk (no interaction staged; the original synthetic log).
- ``lead_brake``: a lead vehicle in the ego's lane brakes hard; the ego brakes behind it.
- ``cut_in``: a vehicle in the next lane, slightly ahead, changes into the ego's lane.
- ``oncoming``: close oncoming traffic in the opposite inner lane, a car standing in the outer one.
- ``crossing``: an intersection; crossing vehicles pass just before and just after the ego.
- ``left_turn``: the ego turns left across an oncoming vehicle that passes just after it.
- ``occluded_pedestrian``: a pedestrian hidden behind a parked van runs out just after the ego.

Every family's log is collision-free as logged (the adversary's feasible sets keep the
logged ego trajectory free too), and its interaction falls inside the first 7 s, so that any
6-s window starting in the first second holds it. World frame as in ``io.synthetic``: x along
the street, y to the left, z up; traffic keeps right.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from advsim_ros.core.types import ActorClass, FloatArray, ScenarioError

LANE_WIDTH = 3.5  # [m]
EGO_LANE_Y = -0.5 * LANE_WIDTH  # the ego's lane: the inner lane of the +x direction [m]
ROAD_HALF_WIDTH = 9.0  # curb to road centre: two lanes each way plus a 2 m parking strip [m]
SIDEWALK_WIDTH = 4.0  # [m]
PARKING_Y = 2 * LANE_WIDTH + 1.0  # |y| of the parking strips' centres [m]
CROSSING_X = 32.0  # centre line of the cross street of the intersection families [m]
CROSSING_HALF_WIDTH = 9.0  # curb to centre line of the cross street [m]
FAMILY_NAMES = ("street", "lead_brake", "cut_in", "oncoming", "crossing", "left_turn", "occluded_pedestrian")
INTERSECTION_FAMILIES = ("crossing", "left_turn")
EGO_FRONT = 3.25  # the ego box's front ahead of the ego frame's origin (EgoGeometry's default) [m]


@dataclass(frozen=True, eq=False)
class Motion:
    """One actor's box over the log: size and where its centre is at every frame."""

    actor_id: str
    actor_class: ActorClass
    size: tuple[float, float, float]  # length, width, height [m]
    intensity: float  # LiDAR reflectivity of its surface
    xy: FloatArray  # (T, 2) box centre [m]
    yaw: FloatArray  # (T,) heading [rad]


@dataclass(frozen=True, eq=False)
class SceneLayout:
    """Where the ego and every actor are at each frame of a family's log."""

    family: str
    crossing_x: float | None  # centre line of a cross street, None on a straight street [m]
    ego_xy: FloatArray  # (T, 2) ego frame origin [m]
    ego_yaw: FloatArray  # (T,) [rad]
    actors: tuple[Motion, ...]
    interacting: tuple[str, ...]  # ids of the actors the staged interaction is about
    turn_lanes: tuple[FloatArray, ...] = ()  # lane centre lines through the crossroads the ego may take [m]


def crossing_of(family: str) -> float | None:
    """The cross street's centre line for a family (known before anything is drawn)."""
    if family not in FAMILY_NAMES:
        raise ScenarioError(f"synthetic family: expected one of {', '.join(FAMILY_NAMES)}, got {family!r}")
    return CROSSING_X if family in INTERSECTION_FAMILIES else None


@dataclass(frozen=True, eq=False)
class Stage:
    """What every family is staged on: the frame times, the ego's cruising speed, the street."""

    times: FloatArray  # (T,) since the first frame [s]
    speed: float  # the ego's speed before any interaction [m/s]
    crossing: float | None  # see crossing_of
    parked_per_side: int  # cars on each parking strip (fewer where they would block)


def scene_layout(
    family: str, rng: np.random.Generator, times: FloatArray, ego_speed: float, parked_per_side: int
) -> SceneLayout:
    """The layout of ``family`` drawn from ``rng`` for frames at ``times`` [s] (the same draws, the same scene)."""
    stage = Stage(np.asarray(times, dtype=float), ego_speed, crossing_of(family), parked_per_side)
    return _FAMILIES[family](rng, stage)


# --- motion building blocks ---------------------------------------------------------------------


def distance_travelled(
    times: FloatArray, speed: float, brake_at: float = np.inf, decel: float = 0.0, final_speed: float = 0.0
) -> FloatArray:
    """Arc length covered at ``speed`` until ``brake_at``, then slowing at ``decel`` down to ``final_speed`` [m]."""
    if not (np.isfinite(brake_at) and decel > 0.0):
        cruising: FloatArray = speed * times
        return cruising
    stop = brake_at + (speed - final_speed) / decel
    braking = np.clip(times - brake_at, 0.0, stop - brake_at)
    after = np.maximum(times - stop, 0.0)
    result: FloatArray = speed * np.minimum(times, brake_at) + speed * braking - 0.5 * decel * braking**2
    return result + final_speed * after


def along(path: FloatArray, s: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Points and headings at arc lengths ``s`` along a polyline (its last segment extended past the end)."""
    segments = np.diff(path, axis=0)
    lengths = np.linalg.norm(segments, axis=1)
    starts = np.concatenate([[0.0], np.cumsum(lengths)[:-1]])
    index = np.clip(np.searchsorted(starts, s, side="right") - 1, 0, len(segments) - 1)
    fraction = (s - starts[index]) / lengths[index]
    xy = path[index] + fraction[:, None] * segments[index]
    return xy, np.arctan2(segments[index, 1], segments[index, 0])


def left_turn_path(start_x: float, lane_y: float, exit_x: float, radius: float, length_after: float) -> FloatArray:
    """From (start_x, lane_y) heading +x: a quarter circle to the left onto x = exit_x, then ``length_after`` on +y."""
    arc_start = exit_x - radius
    angles = np.linspace(-0.5 * np.pi, 0.0, 60)
    arc = np.column_stack([arc_start + radius * np.cos(angles), lane_y + radius + radius * np.sin(angles)])
    end = arc[-1] + [0.0, length_after]
    return np.vstack([[start_x, lane_y], arc, end])


def _constant(
    actor_id: str,
    actor_class: ActorClass,
    size: tuple[float, float, float],
    intensity: float,
    start: tuple[float, float],
    yaw: float,
    speed: float,
    times: FloatArray,
) -> Motion:
    heading = np.array([np.cos(yaw), np.sin(yaw)])
    xy = np.asarray(start, dtype=float) + speed * times[:, None] * heading
    return Motion(actor_id, actor_class, size, intensity, xy, np.full(times.shape, yaw))


def _oncoming_car(
    actor_id: str,
    rng: np.random.Generator,
    times: FloatArray,
    x_range: tuple[float, float],
    speed_range: tuple[float, float],
    lane_y: float = 1.5 * LANE_WIDTH,
) -> Motion:
    """A car heading -x in an opposite lane (the outer one unless told), from ``x_range`` at a speed in ``speed_range``.

    Oncoming traffic that only sets the scene keeps to the outer lane, so that the actor the
    family stages its interaction with is the one closest to the ego (attacks perturb the closest).
    """
    start = (float(rng.uniform(*x_range)), lane_y)
    speed = float(rng.uniform(*speed_range))
    return _constant(actor_id, ActorClass.VEHICLE, _car_size(rng), _reflectivity(rng), start, np.pi, speed, times)


def _car_size(rng: np.random.Generator) -> tuple[float, float, float]:
    return (float(rng.uniform(4.1, 4.9)), float(rng.uniform(1.72, 1.92)), float(rng.uniform(1.42, 1.65)))


def _reflectivity(rng: np.random.Generator) -> float:
    return float(rng.uniform(0.1, 0.6))


def _parked_cars(
    rng: np.random.Generator, times: FloatArray, per_side: int, keep_clear: list[tuple[float, float]], first: int = 0
) -> list[Motion]:
    """Cars along both parking strips, none in the x ranges of ``keep_clear`` (intersections, vans)."""
    cars: list[Motion] = []
    index = first
    for side, yaw in ((-1.0, 0.0), (1.0, np.pi)):
        x = float(rng.uniform(-10.0, 5.0))
        for _ in range(per_side):
            size = _car_size(rng)
            x += 0.5 * size[0] + float(rng.uniform(2.0, 12.0))
            reflectivity = _reflectivity(rng)
            if not any(low - 0.5 * size[0] < x < high + 0.5 * size[0] for low, high in keep_clear):
                start = (x, side * PARKING_Y)
                cars.append(_constant(f"parked_{index}", ActorClass.VEHICLE, size, reflectivity, start, yaw, 0, times))
                index += 1
            x += 0.5 * size[0]
    return cars


def _straight_ego(
    times: FloatArray, speed: float, start_x: float = 0.0, **braking: float
) -> tuple[FloatArray, FloatArray]:
    s = start_x + distance_travelled(times, speed, **braking)
    return np.column_stack([s, np.full(times.shape, EGO_LANE_Y)]), np.zeros(times.shape)


# --- the families ---------------------------------------------------------------------------------


def _street(rng: np.random.Generator, stage: Stage) -> SceneLayout:
    times, speed, crossing = stage.times, stage.speed, stage.crossing
    """The original synthetic street (its draws in their original order: old seeds give the old logs)."""
    actors = _parked_cars(rng, times, stage.parked_per_side, [])
    lanes = (
        ("lead", (float(rng.uniform(12.0, 20.0)), -1.5 * LANE_WIDTH), 0.0, float(rng.uniform(5.0, 7.0))),
        ("oncoming", (float(rng.uniform(90.0, 120.0)), 0.5 * LANE_WIDTH), np.pi, float(rng.uniform(7.0, 10.0))),
        ("oncoming_outer", (float(rng.uniform(35.0, 55.0)), 1.5 * LANE_WIDTH), np.pi, float(rng.uniform(4.0, 6.0))),
    )
    for name, start, yaw, actor_speed in lanes:
        size = _car_size(rng)
        actors.append(_constant(name, ActorClass.VEHICLE, size, _reflectivity(rng), start, yaw, actor_speed, times))
    walker = (0.7, 0.6, float(rng.uniform(1.6, 1.85)))
    start = (float(rng.uniform(15.0, 35.0)), ROAD_HALF_WIDTH + 0.5 * SIDEWALK_WIDTH)  # the left sidewalk's middle
    actors.append(
        _constant("pedestrian", ActorClass.PEDESTRIAN, walker, 0.35, start, 0.0, float(rng.uniform(1.0, 1.6)), times)
    )
    ego_xy, ego_yaw = _straight_ego(times, speed)
    return SceneLayout("street", crossing, ego_xy, ego_yaw, tuple(actors), ())


def _lead_brake(rng: np.random.Generator, stage: Stage) -> SceneLayout:
    times, speed, crossing = stage.times, stage.speed, stage.crossing
    gap = float(rng.uniform(12.0, 18.0))  # centre to centre at t = 0 [m]
    brake_at = float(rng.uniform(2.5, 3.5))  # [s]
    decel = float(rng.uniform(3.0, 5.0))  # the lead's braking [m/s^2]
    reaction = float(rng.uniform(0.4, 0.8))  # the ego brakes this much later [s]
    standstill_gap = float(rng.uniform(2.0, 3.5))  # bumper to bumper when both stand [m]
    size = _car_size(rng)
    lead_stop = gap + speed * brake_at + speed**2 / (2 * decel)
    ego_brake_at = brake_at + reaction
    room = lead_stop - 0.5 * size[0] - EGO_FRONT - standstill_gap - speed * ego_brake_at
    ego_decel = min(speed**2 / (2 * max(room, 1.0)), 8.0)
    lead_s = gap + distance_travelled(times, speed, brake_at, decel)
    lead = Motion(
        "lead",
        ActorClass.VEHICLE,
        size,
        _reflectivity(rng),
        np.column_stack([lead_s, np.full(times.shape, EGO_LANE_Y)]),
        np.zeros(times.shape),
    )
    oncoming = _oncoming_car("oncoming", rng, times, (60.0, 90.0), (7.0, 10.0))
    parked = _parked_cars(rng, times, stage.parked_per_side, [])
    ego_xy, ego_yaw = _straight_ego(times, speed, brake_at=ego_brake_at, decel=ego_decel)
    return SceneLayout("lead_brake", crossing, ego_xy, ego_yaw, (lead, oncoming, *parked), ("lead",))


def _cut_in(rng: np.random.Generator, stage: Stage) -> SceneLayout:
    times, speed, crossing = stage.times, stage.speed, stage.crossing
    ahead = float(rng.uniform(6.0, 9.0))  # centre ahead of the ego's at t = 0 [m]
    cutter_speed = speed + float(rng.uniform(0.5, 1.5))  # [m/s]
    starts_at = float(rng.uniform(1.8, 2.8))  # lane change begins [s]
    lasts = float(rng.uniform(2.5, 3.5))  # [s]
    size = _car_size(rng)
    x = ahead + cutter_speed * times
    progress = np.clip((times - starts_at) / lasts, 0.0, 1.0)
    smooth = progress**2 * (3.0 - 2.0 * progress)  # smoothstep: no lateral jump at either end
    y = -1.5 * LANE_WIDTH + LANE_WIDTH * smooth
    lateral_speed = LANE_WIDTH * 6.0 * progress * (1.0 - progress) / lasts
    cutter = Motion(
        "cutter",
        ActorClass.VEHICLE,
        size,
        _reflectivity(rng),
        np.column_stack([x, y]),
        np.arctan2(lateral_speed, cutter_speed),
    )
    oncoming = _oncoming_car("oncoming", rng, times, (50.0, 80.0), (7.0, 10.0))
    parked = _parked_cars(rng, times, stage.parked_per_side, [])
    ego_xy, ego_yaw = _straight_ego(times, speed)
    return SceneLayout("cut_in", crossing, ego_xy, ego_yaw, (cutter, oncoming, *parked), ("cutter",))


def _oncoming(rng: np.random.Generator, stage: Stage) -> SceneLayout:
    times, speed, crossing = stage.times, stage.speed, stage.crossing
    first = _oncoming_car("oncoming", rng, times, (45.0, 65.0), (7.0, 11.0), lane_y=0.5 * LANE_WIDTH)
    second = _oncoming_car("oncoming_2", rng, times, (75.0, 95.0), (7.0, 11.0), lane_y=0.5 * LANE_WIDTH)
    blocker_x = float(rng.uniform(25.0, 40.0))  # a car standing in the opposite outer lane [m]
    blocker = _constant(
        "stopped",
        ActorClass.VEHICLE,
        _car_size(rng),
        _reflectivity(rng),
        (blocker_x, 1.5 * LANE_WIDTH),
        np.pi,
        0.0,
        times,
    )
    parked = _parked_cars(rng, times, stage.parked_per_side, [])
    ego_xy, ego_yaw = _straight_ego(times, speed)
    return SceneLayout(
        "oncoming", crossing, ego_xy, ego_yaw, (first, second, blocker, *parked), ("oncoming", "oncoming_2")
    )


def _time_at(positions: FloatArray, times: FloatArray, value: float) -> float:
    """When an increasing coordinate reaches ``value`` (linear between frames, extrapolated past the end)."""
    if value <= positions[-1]:
        return float(np.interp(value, positions, times))
    rate = (positions[-1] - positions[-2]) / (times[-1] - times[-2])
    return float(times[-1] + (value - positions[-1]) / rate)


def _crossing(rng: np.random.Generator, stage: Stage) -> SceneLayout:
    times, speed, crossing = stage.times, stage.speed, stage.crossing
    assert crossing is not None
    ego_start = -float(rng.uniform(0.0, 8.0))
    ego_xy, ego_yaw = _straight_ego(times, speed, start_x=ego_start)
    ego_at_crossing = _time_at(ego_xy[:, 0], times, crossing)  # the ego's origin on the cross street's centre line
    actors = []
    # from the right (heading +y, lane x = crossing + 1.75) after the ego, from the left (heading -y) before it
    for actor_id, lane_x, heading, offset in (
        ("crossing_after", crossing + 0.5 * LANE_WIDTH, 1.0, float(rng.uniform(1.2, 1.8))),
        ("crossing_before", crossing - 0.5 * LANE_WIDTH, -1.0, -float(rng.uniform(1.5, 2.1))),
    ):
        actor_speed = float(rng.uniform(6.0, 9.0))
        meets_at = ego_at_crossing + offset  # on the ego's lane centre at this time [s]
        y = EGO_LANE_Y + heading * actor_speed * (times - meets_at)
        actors.append(
            Motion(
                actor_id,
                ActorClass.VEHICLE,
                _car_size(rng),
                _reflectivity(rng),
                np.column_stack([np.full(times.shape, lane_x), y]),
                np.full(times.shape, heading * 0.5 * np.pi),
            )
        )
    oncoming = _oncoming_car("oncoming", rng, times, (70.0, 90.0), (7.0, 10.0))
    keep_clear = [(crossing - CROSSING_HALF_WIDTH - 4.0, crossing + CROSSING_HALF_WIDTH + 4.0)]
    parked = _parked_cars(rng, times, stage.parked_per_side, keep_clear)
    return SceneLayout(
        "crossing", crossing, ego_xy, ego_yaw, (*actors, oncoming, *parked), ("crossing_after", "crossing_before")
    )


def _left_turn(rng: np.random.Generator, stage: Stage) -> SceneLayout:
    times, speed, crossing = stage.times, stage.speed, stage.crossing
    assert crossing is not None
    turn_speed = min(speed, float(rng.uniform(5.5, 7.0)))  # [m/s]
    radius = float(rng.uniform(9.0, 11.0))  # [m]
    path = left_turn_path(-20.0, EGO_LANE_Y, crossing + 0.5 * LANE_WIDTH, radius, 60.0)
    start = float(rng.uniform(28.0, 34.0))  # the ego begins this far along the path (x = start - 20) [m]
    ego_xy, ego_yaw = along(path, start + distance_travelled(times, turn_speed))
    ego_yaw = np.unwrap(ego_yaw)
    # the oncoming car (heading -x in lane y = +1.75) passes the point where the ego's path crosses its lane
    crosses_at = _time_at(ego_xy[:, 1], times, 0.5 * LANE_WIDTH)
    x_cross = float(np.interp(crosses_at, times, ego_xy[:, 0]))
    oncoming_speed = float(rng.uniform(7.0, 10.0))
    after = float(rng.uniform(1.4, 2.0))  # [s] after the ego's origin crossed its lane
    x = x_cross - oncoming_speed * (times - crosses_at - after)
    oncoming = Motion(
        "oncoming",
        ActorClass.VEHICLE,
        _car_size(rng),
        _reflectivity(rng),
        np.column_stack([x, np.full(times.shape, 0.5 * LANE_WIDTH)]),
        np.full(times.shape, np.pi),
    )
    keep_clear = [(crossing - CROSSING_HALF_WIDTH - 4.0, crossing + CROSSING_HALF_WIDTH + 4.0)]
    parked = _parked_cars(rng, times, stage.parked_per_side, keep_clear)
    turn = path[1:]  # the left-turn lane: from where the arc begins onto the cross street
    return SceneLayout("left_turn", crossing, ego_xy, ego_yaw, (oncoming, *parked), ("oncoming",), (turn,))


def _occluded_pedestrian(rng: np.random.Generator, stage: Stage) -> SceneLayout:
    times, speed, crossing = stage.times, stage.speed, stage.crossing
    van = (float(rng.uniform(5.5, 6.5)), float(rng.uniform(2.1, 2.3)), float(rng.uniform(2.5, 2.8)))
    van_x = float(rng.uniform(22.0, 30.0))
    van_motion = _constant("van", ActorClass.VEHICLE, van, _reflectivity(rng), (van_x, -PARKING_Y), 0.0, 0.0, times)
    walker = (0.7, 0.6, float(rng.uniform(1.6, 1.85)))
    walk_speed = float(rng.uniform(2.2, 3.0))  # running out into the street [m/s]
    x = van_x + 0.5 * van[0] + float(rng.uniform(0.5, 0.9))  # just past the van's front
    # waits on the sidewalk where the van hides it from the approaching ego, then crosses the street
    y_start, y_end = -PARKING_Y - 2.5, 2 * LANE_WIDTH
    ego_xy, ego_yaw = _straight_ego(times, speed)
    ego_passes = _time_at(ego_xy[:, 0], times, x + 3.5)  # the ego's rear (1 m behind its origin) is past [s]
    reaches_lane = ego_passes + float(rng.uniform(0.6, 1.2))  # the pedestrian steps into the ego's lane [s]
    lane_edge = EGO_LANE_Y - 0.5 * LANE_WIDTH
    walk_starts = reaches_lane - (lane_edge - y_start) / walk_speed
    y = np.clip(y_start + walk_speed * np.maximum(times - walk_starts, 0.0), y_start, y_end)
    pedestrian = Motion(
        "pedestrian",
        ActorClass.PEDESTRIAN,
        walker,
        0.35,
        np.column_stack([np.full(times.shape, x), y]),
        np.full(times.shape, 0.5 * np.pi),
    )
    parked = _parked_cars(rng, times, stage.parked_per_side, [(van_x - 0.5 * van[0] - 2.0, x + 2.0)])
    return SceneLayout(
        "occluded_pedestrian", crossing, ego_xy, ego_yaw, (van_motion, pedestrian, *parked), ("pedestrian",)
    )


_FAMILIES: dict[str, Callable[[np.random.Generator, Stage], SceneLayout]] = {
    "street": _street,
    "lead_brake": _lead_brake,
    "cut_in": _cut_in,
    "oncoming": _oncoming,
    "crossing": _crossing,
    "left_turn": _left_turn,
    "occluded_pedestrian": _occluded_pedestrian,
}
