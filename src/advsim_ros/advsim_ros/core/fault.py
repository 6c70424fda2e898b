"""Fault and avoidability of a colliding query: could an ego within its limits have avoided it, and who hit whom.

A collision the search finds counts against the stack only if a careful and competent driver in the ego's
place could have avoided it: the idea of UN Regulation No. 157 (Automated Lane Keeping Systems), whose
guidance on traffic disturbance critical scenarios separates preventable from unpreventable collisions by
what a careful and competent human driver model does; that model only brakes (Mattas et al., 2022). Here
the reference driver is the ego itself within its own limits, with no reaction time (the stack plans from the
decision), and it may also steer:

- **avoidable**: some trajectory of the evasion family (core.evasion: braking in lane at decelerations up to
  max_decel, keeping or gaining speed, and the modular planner's Frenet family of lateral offsets x speed
  profiles along the human's path), starting from the human's pose and speed at the decision time and within
  the ego's limits (ControllerConfig's acceleration, braking, jerk, steering angle and rate; the friction circle
  at max_decel), keeps its box clear of every actor's box at every plan stamp over the horizon — the same
  separating-axis test and the same actors (present, in range) as the collision metric;
- **unavoidable** otherwise: e.g. rammed from behind or from the side while on the human's path.

Who moved into whom (first_contact), after the blame rule of Responsibility-Sensitive Safety (Shalev-Shwartz,
Shammah, Shashua, "On a Formal Model of Safe and Scalable Self-driving Cars", arXiv:1708.06374, 2017) read
kinematically: at the first contact, the contact normal is the separating axis (a face normal of either box)
that closed last; each party's velocity component along it towards the other is its share of the closing
speed. A party moved into the other when its share exceeds ``into_speed`` (0.5 m/s); both when both do,
otherwise the one with the larger share. docs/search.md, "Fault and avoidability", states the rule in full.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from enum import StrEnum
from typing import TypedDict

import numpy as np

from advsim_ros.core.evasion import EgoLimits, EgoStart, EvasionFamily, evasion_candidates
from advsim_ros.core.futures import NS_PER_S, ActorFutures, BoolArray, actor_futures_at
from advsim_ros.core.geometry import (
    bev_iou,
    box_corners,
    boxes_overlap,
    overlap_from_components,
    wrap_angle,
)
from advsim_ros.core.metrics import MetricsConfig, actors_in_range, plan_from_decision, require_aligned
from advsim_ros.core.types import (
    ActorTrack,
    DrivableArea,
    EgoGeometry,
    EgoTrajectory,
    FloatArray,
    IntArray,
    Plan,
    Scenario,
    ScenarioError,
    replace_actors,
)

INTO_SPEED = 0.5  # a party moved into the other when it closed in faster than this along the normal [m/s]
SAMPLES, REFINEMENTS = 64, 2  # first contact is found between plan stamps to 0.1 s / 64^2 (25 us)


class Verdict(StrEnum):
    AVOIDABLE = "avoidable"
    UNAVOIDABLE = "unavoidable"


class Mover(StrEnum):
    EGO_INTO_ACTOR = "ego_into_actor"
    ACTOR_INTO_EGO = "actor_into_ego"
    BOTH = "both"


class EgoSide(StrEnum):
    FRONT = "front"
    REAR = "rear"
    LEFT = "left"
    RIGHT = "right"


@dataclass(frozen=True)
class Avoidability:
    """Whether an ego within its limits could have avoided every actor, and how many trajectories could."""

    verdict: Verdict
    tried: int  # trajectories in the evasion family [1]
    within_limits: int  # of those, within the ego's limits (and on the drivable area when one is given) [1]
    collision_free: int  # of those, clear of every actor at every stamp [1]
    in_lane_free: int  # of those, on the human's path (braking or keeping speed in lane) [1]
    first_free: str  # the first collision-free trajectory in the family's order; "" when none
    horizon_s: float  # the stamps judged reach this far after the decision [s]


def avoidability(
    start: EgoStart,
    human: EgoTrajectory,
    ego: EgoGeometry,
    actors: ActorFutures,
    stamps_ns: IntArray,
    limits: EgoLimits | None = None,
    family: EvasionFamily | None = None,
    drivable: DrivableArea | None = None,
    active: BoolArray | None = None,
) -> Avoidability:
    """Try the evasion family from ``start`` along the human's path against the actors' futures.

    ``actors`` holds one state per stamp of ``stamps_ns`` (log time, from the decision on: the plan's stamps
    with the decision in front); ``active`` (N,) picks the actors that count (default: all). With ``drivable``,
    a trajectory whose box centre leaves the drivable area at some stamp is not within the limits (the rule the
    perturbed actors are held to).
    """
    limits, family = limits or EgoLimits(), family or EvasionFamily()
    stamps = np.asarray(stamps_ns, dtype=np.int64)
    if actors.states.shape[1] != stamps.shape[0]:
        raise ScenarioError(f"avoidability: {actors.states.shape[1]} actor states for {stamps.shape[0]} stamps")
    if stamps.size and int(stamps[0]) < start.stamp_ns:
        raise ScenarioError("avoidability: the stamps must not begin before the decision (the ego's start)")
    times = (stamps - start.stamp_ns).astype(np.float64) / NS_PER_S
    candidates = evasion_candidates(start, human, times, limits, family)
    ok = candidates.within_limits.copy()
    if drivable is not None:
        centres = ego.boxes(candidates.xy, candidates.yaws)
        ok &= np.all(drivable.contains(centres[..., 0], centres[..., 1]), axis=1)
    chosen = np.flatnonzero(ok)
    mask = np.ones(actors.num_actors, dtype=bool) if active is None else np.asarray(active, dtype=bool)
    hits = _collides(candidates.xy[chosen], candidates.yaws[chosen], ego, actors, mask)
    free = chosen[~hits]
    return Avoidability(
        verdict=Verdict.AVOIDABLE if free.size else Verdict.UNAVOIDABLE,
        tried=int(ok.shape[0]),
        within_limits=int(chosen.shape[0]),
        collision_free=int(free.shape[0]),
        in_lane_free=int(np.count_nonzero(candidates.in_lane[free])),
        first_free=candidates.label(int(free[0])) if free.size else "",
        horizon_s=float(times[-1]) if times.size else 0.0,
    )


def _collides(xy: FloatArray, yaws: FloatArray, ego: EgoGeometry, actors: ActorFutures, active: BoolArray) -> BoolArray:
    """(C,) whether each ego trajectory's box overlaps an active actor's box at some stamp.

    Cheap tests first: actor states outside every trajectory's reach at that stamp are skipped, then pairs whose
    circumscribed circles do not meet; the separating-axis test runs on what is left.
    """
    hit = np.zeros(xy.shape[0], dtype=bool)
    boxes = actors.finite_boxes()[active]  # (N, T, 5)
    if xy.shape[0] == 0 or boxes.shape[0] == 0:
        return hit
    cos, sin = np.cos(yaws), np.sin(yaws)  # (C, T)
    centre_x, centre_y = xy[..., 0] + ego.forward_offset * cos, xy[..., 1] + ego.forward_offset * sin
    ego_radius = 0.5 * float(np.hypot(ego.length, ego.width))
    radius = 0.5 * np.hypot(actors.sizes[active, 0], actors.sizes[active, 1])[:, None] + ego_radius  # (N, 1)
    near = actors.present[active] & (boxes[..., 0] >= centre_x.min(axis=0) - radius)  # every trajectory's reach
    near &= (boxes[..., 0] <= centre_x.max(axis=0) + radius) & (boxes[..., 1] >= centre_y.min(axis=0) - radius)
    near &= boxes[..., 1] <= centre_y.max(axis=0) + radius
    actor, step = np.nonzero(near)
    if actor.size == 0:
        return hit
    other = boxes[actor, step]  # (P, 5)
    dx = other[None, :, 0] - centre_x[:, step]  # (C, P)
    dy = other[None, :, 1] - centre_y[:, step]
    candidate, pair = np.nonzero(dx * dx + dy * dy <= radius[actor, 0] ** 2)
    if candidate.size == 0:
        return hit
    at, other = step[pair], other[pair]
    overlapping = overlap_from_components(
        dx[candidate, pair], dy[candidate, pair], cos[candidate, at], sin[candidate, at], np.cos(other[:, 2]),
        np.sin(other[:, 2]), 0.5 * ego.length, 0.5 * ego.width, 0.5 * other[:, 3], 0.5 * other[:, 4],
    )  # fmt: skip
    hit[candidate[overlapping]] = True
    return hit


@dataclass(frozen=True)
class Contact:
    """The first contact of a plan with an actor."""

    actor_index: int  # into the actor futures [1]
    time_s: float  # after the plan's first stamp, refined between stamps [s]
    stamp_ns: int  # the first plan stamp at which the boxes overlap [ns]
    side: EgoSide  # where on the ego box the contact point lies
    point_ego: tuple[float, float]  # contact point in the ego frame (x forward, y left, the ego frame's origin) [m]
    ego_speed: float  # the ego's velocity along the contact normal, towards the actor [m/s]
    actor_speed: float  # the actor's velocity along the contact normal, towards the ego [m/s]
    mover: Mover

    @property
    def closing_speed(self) -> float:
        return self.ego_speed + self.actor_speed  # [m/s]


def first_contact(
    plan: Plan,
    actors: ActorFutures,
    ego: EgoGeometry,
    active: BoolArray | None = None,
    into_speed: float = INTO_SPEED,
) -> Contact | None:
    """The first contact of the plan's box with an active actor's box; None when they never overlap.

    At the first overlapping stamp the actor overlapping most (BEV IoU) is the one hit. Between that stamp
    and the one before, both move linearly (headings by the shorter turn) and the first overlap is searched;
    the contact normal is the separating axis that closed last (at the first stamp, without a stamp before it
    or with the actor appearing there: the axis of least penetration). Velocities are the box centres' over the
    step into contact (out of it when there is none before).
    """
    require_aligned(plan, actors)
    mask = np.ones(actors.num_actors, dtype=bool) if active is None else np.asarray(active, dtype=bool)
    ego_boxes = ego.boxes(plan.xy, plan.yaws)  # (H, 5)
    actor_boxes = actors.finite_boxes()
    overlapping = boxes_overlap(actor_boxes, ego_boxes[None]) & actors.present & mask[:, None]  # (N, H)
    steps = np.flatnonzero(overlapping.any(axis=0))
    if steps.size == 0:
        return None
    k = int(steps[0])
    touching = np.flatnonzero(overlapping[:, k])
    index = int(touching[np.argmax(bev_iou(actor_boxes[touching, k], ego_boxes[k][None]))])
    own, other = ego_boxes[k], actor_boxes[index, k]
    separated_own, separated_other, fraction = own, other, 1.0
    if k > 0 and actors.present[index, k - 1]:
        # Twice 64 evenly spaced instants, the second time within the step where the first overlap fell.
        low, high = 0.0, 1.0
        for _ in range(REFINEMENTS):
            fractions = np.linspace(low, high, SAMPLES + 1)[1:]
            sampled = boxes_overlap(_between(ego_boxes, k, fractions), _between(actor_boxes[index], k, fractions))
            first = int(np.argmax(sampled))  # the last fraction always overlaps (at high)
            low, high = (float(fractions[first - 1]) if first else low), float(fractions[first])
        separated_own, separated_other = _between(ego_boxes, k, low), _between(actor_boxes[index], k, low)
        own, other, fraction = _between(ego_boxes, k, high), _between(actor_boxes[index], k, high), high
    normal = _contact_normal(separated_own, separated_other)
    ego_velocity = _velocity(plan.stamps_ns, ego_boxes, np.ones(ego_boxes.shape[0], dtype=bool), k)
    actor_velocity = _velocity(plan.stamps_ns, actor_boxes[index], actors.present[index], k)
    ego_speed, actor_speed = float(ego_velocity @ normal), float(-actor_velocity @ normal)
    point = _contact_point(own, other)
    local = _in_box_frame(point, own)
    times = (plan.stamps_ns - plan.stamps_ns[0]).astype(np.float64) / NS_PER_S
    time = float(times[k]) if k == 0 else float(times[k - 1] + fraction * (times[k] - times[k - 1]))
    return Contact(
        actor_index=index,
        time_s=time,
        stamp_ns=int(plan.stamps_ns[k]),
        side=_side(local, ego),
        point_ego=(float(local[0] + ego.forward_offset), float(local[1])),
        ego_speed=ego_speed,
        actor_speed=actor_speed,
        mover=_mover(ego_speed, actor_speed, into_speed),
    )


def _between(boxes: FloatArray, k: int, fraction: float | FloatArray) -> FloatArray:
    """(..., 5) boxes linearly between stamps k - 1 (fraction 0) and k (fraction 1), headings by the shorter turn."""
    before, after = boxes[k - 1], boxes[k]
    share = np.asarray(fraction, dtype=np.float64)[..., None]
    result: FloatArray = before + share * (after - before)
    result[..., 2] = before[2] + share[..., 0] * float(wrap_angle(after[2] - before[2]))
    return result


def _contact_normal(own: FloatArray, other: FloatArray) -> FloatArray:
    """(2,) unit normal from the ego towards the actor: the face axis of either box with the largest gap."""
    offset = other[:2] - own[:2]
    axes, reaches = [], []
    for box, counterpart in ((own, other), (other, own)):
        along = np.array([np.cos(box[2]), np.sin(box[2])])
        across = np.array([-along[1], along[0]])
        cos_rel = abs(float(np.cos(counterpart[2] - box[2])))
        sin_rel = abs(float(np.sin(counterpart[2] - box[2])))
        axes += [along, across]
        reaches += [
            0.5 * (box[3] + counterpart[3] * cos_rel + counterpart[4] * sin_rel),
            0.5 * (box[4] + counterpart[3] * sin_rel + counterpart[4] * cos_rel),
        ]
    gaps = [abs(float(offset @ axis)) - reach for axis, reach in zip(axes, reaches, strict=True)]
    best = int(np.argmax(gaps))
    axis = axes[best]
    normal: FloatArray = axis if float(offset @ axis) >= 0.0 else -axis
    return normal


def _velocity(stamps_ns: IntArray, boxes: FloatArray, present: BoolArray, k: int) -> FloatArray:
    """(2,) box-centre velocity over the step into stamp k, else out of it, else standing [m/s]."""
    for first, second in ((k - 1, k), (k, k + 1)):
        if first >= 0 and second < boxes.shape[0] and present[first] and present[second]:
            elapsed = float(stamps_ns[second] - stamps_ns[first]) / NS_PER_S
            velocity: FloatArray = (boxes[second, :2] - boxes[first, :2]) / elapsed
            return velocity
    return np.zeros(2)


def _contact_point(own: FloatArray, other: FloatArray) -> FloatArray:
    """(2,) centroid of the two boxes' intersection (exact polygons); the midpoint of the centres if it is empty."""
    import shapely  # only the contact point needs polygon clipping

    shapes = shapely.polygons(box_corners(np.stack([own, other])).astype(np.float64))
    meet = shapely.intersection(shapes[0], shapes[1])
    if meet.is_empty:
        return np.asarray(0.5 * (own[:2] + other[:2]), dtype=np.float64)
    return np.array([meet.centroid.x, meet.centroid.y])


def _in_box_frame(point: FloatArray, box: FloatArray) -> FloatArray:
    """(2,) a world point relative to a box centre, along and across its heading [m]."""
    offset = point - box[:2]
    cos, sin = np.cos(box[2]), np.sin(box[2])
    return np.array([cos * offset[0] + sin * offset[1], -sin * offset[0] + cos * offset[1]])


def _side(local: FloatArray, ego: EgoGeometry) -> EgoSide:
    """The ego box face nearest the point, distances scaled by the half extents (a square's diagonals split it)."""
    along, across = local[0] / (0.5 * ego.length), local[1] / (0.5 * ego.width)
    if abs(along) >= abs(across):
        return EgoSide.FRONT if along >= 0.0 else EgoSide.REAR
    return EgoSide.LEFT if across >= 0.0 else EgoSide.RIGHT


def _mover(ego_speed: float, actor_speed: float, into_speed: float) -> Mover:
    if ego_speed > into_speed and actor_speed > into_speed:
        return Mover.BOTH
    return Mover.EGO_INTO_ACTOR if ego_speed >= actor_speed else Mover.ACTOR_INTO_EGO


class Candidates(TypedDict):
    tried: int
    within_limits: int
    collision_free: int
    in_lane_free: int


class ContactRecord(TypedDict):
    actor_id: str
    perturbed: bool
    time_s: float
    side: str  # EgoSide's value
    point_ego: list[float]
    mover: str  # Mover's value: ego_into_actor | actor_into_ego | both
    ego_speed: float
    actor_speed: float
    closing_speed: float


# CollisionFault.as_json, as summary.json holds it ("class" is a keyword, hence the functional form)
FaultRecord = TypedDict(
    "FaultRecord",
    {"class": str, "candidates": Candidates, "escape": str | None, "horizon_s": float, "contact": ContactRecord},
)


@dataclass(frozen=True)
class CollisionFault:
    """Fault and avoidability of one colliding query."""

    avoidability: Avoidability
    contact: Contact
    actor_id: str  # the actor of the first contact
    perturbed: bool  # whether the search moved that actor

    def as_json(self) -> FaultRecord:
        """A JSON-ready record (units in the keys' docs: docs/search.md, "Fault and avoidability")."""
        found, contact = self.avoidability, self.contact
        return {
            "class": found.verdict.value,
            "candidates": {
                "tried": found.tried,
                "within_limits": found.within_limits,
                "collision_free": found.collision_free,
                "in_lane_free": found.in_lane_free,
            },
            "escape": found.first_free or None,
            "horizon_s": round(found.horizon_s, 3),
            "contact": {
                "actor_id": self.actor_id,
                "perturbed": self.perturbed,
                "time_s": round(contact.time_s, 3),
                "side": contact.side.value,
                "point_ego": [round(value, 3) for value in contact.point_ego],
                "mover": contact.mover.value,
                "ego_speed": round(contact.ego_speed, 3),
                "actor_speed": round(contact.actor_speed, 3),
                "closing_speed": round(contact.closing_speed, 3),
            },
        }


def classify_collision(
    plan: Plan,
    scenario: Scenario,
    moved: Sequence[ActorTrack],
    decision_frame: int,
    metrics: MetricsConfig | None = None,
    limits: EgoLimits | None = None,
    family: EvasionFamily | None = None,
    drivable: DrivableArea | None = None,
) -> CollisionFault | None:
    """Fault and avoidability of one query, from the same inputs as core.scoring.evaluate_query.

    ``plan`` is the stack's plan in log time, planned from the sweep of ``decision_frame``; ``moved`` the
    query's perturbed actors. The plan gets the decision pose in front (plan_from_decision) and is judged at its
    stamps from the decision to the longest metric horizon, against the actors in range with their futures at
    those stamps (MetricsConfig.actor_extrapolation), as the collision metric judges it. ``drivable``: the
    scorer's raster, when the evasions should stay on the road. None when the plan does not collide.
    """
    metrics = metrics or MetricsConfig()
    decision_ns = int(scenario.frame_stamps_ns[decision_frame])
    full = plan_from_decision(plan, scenario.ego.poses[decision_frame], decision_ns)
    horizon_ns = decision_ns + round(max(metrics.horizons) * NS_PER_S)
    within = (full.stamps_ns >= decision_ns) & (full.stamps_ns <= horizon_ns)
    full = Plan(full.stamps_ns[within], full.xy[within], full.yaws[within])
    actors = replace_actors(scenario.actors, moved)
    futures = actor_futures_at(actors, full.stamps_ns, metrics.actor_extrapolation)
    active = actors_in_range(full, futures, metrics)
    contact = first_contact(full, futures, scenario.ego_geometry, active)
    if contact is None:
        return None
    start = EgoStart.from_log(scenario.ego, decision_frame)
    found = avoidability(
        start, scenario.ego, scenario.ego_geometry, futures, full.stamps_ns, limits, family, drivable, active
    )
    actor_id = actors[contact.actor_index].actor_id
    return CollisionFault(found, contact, actor_id, actor_id in {track.actor_id for track in moved})
