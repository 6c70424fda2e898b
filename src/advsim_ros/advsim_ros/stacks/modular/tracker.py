"""Multi-object tracker in the world frame: constant-velocity Kalman filters and Hungarian assignment.

State per track: [x, y, vx, vy] (world frame, m and m/s) with covariance; measurements are
box centres. Detections are assigned to tracks of the same class by minimum total centre
distance (scipy's linear_sum_assignment) within a gate. Unassigned detections start
tracks; tracks missed for more than ``max_misses`` sweeps end. Box size is the last
detection's, heading follows the motion when the track moves and the box otherwise, and a
turn rate is estimated from the heading's change for CTRV. A track counts as moving only
once it is confirmed, faster than ``static_speed``, ``static_displacement`` away from
where it was born and, for vehicles and cyclists, moving along its box: box centres of
parked cars and walls shift from sweep to sweep as different parts come into view while
the ego drives by, which a filter alone turns into phantom speeds.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.optimize import linear_sum_assignment

from advsim_ros.core.types import ActorClass, FloatArray
from advsim_ros.stacks.modular.config import PredictionConfig, TrackerConfig
from advsim_ros.stacks.modular.detector import CLASS_ORDER, Detections

IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]

_NO_MATCH = 1e6  # assignment cost of a pair outside the gate
_VEHICLE = CLASS_ORDER.index(ActorClass.VEHICLE)
_HEADED = [CLASS_ORDER.index(ActorClass.VEHICLE)]  # move along their box (a bicycle's box heading is too noisy)


def _wrap(angles: FloatArray) -> FloatArray:
    result: FloatArray = np.mod(angles + np.pi, 2.0 * np.pi) - np.pi
    return result


@dataclass(frozen=True, eq=False)
class TrackSet:
    """Tracks after an update: arrays over tracks, the world frame."""

    ids: IntArray  # (N,) track ids, never reused within one tracker's life (resets included)
    state: FloatArray  # (N, 4) x, y [m], vx, vy [m/s]
    yaw: FloatArray  # (N,) heading [rad]
    yaw_rate: FloatArray  # (N,) turn rate [rad/s]
    size: FloatArray  # (N, 3) length, width, height [m]
    z: FloatArray  # (N,) box centre height [m]
    classes: IntArray  # (N,) index into detector.CLASS_ORDER
    confidence: FloatArray  # (N,) last matched detection's score
    hits: IntArray  # (N,) updates so far
    misses: IntArray  # (N,) sweeps since the last update
    detected_box: FloatArray  # (N, 5) this sweep's detection [x, y, yaw, l, w] when misses == 0
    moving: BoolArray  # (N,) confirmed, faster than static_speed, moved static_displacement since birth and,
    # for vehicles and cyclists, moving along the box (see TrackerConfig.heading_tolerance_deg)

    @property
    def count(self) -> int:
        return int(self.ids.shape[0])

    @property
    def speed(self) -> FloatArray:
        result: FloatArray = np.hypot(self.state[:, 2], self.state[:, 3])
        return result


class MultiObjectTracker:
    """Stateful tracker; call update() once per sweep with that sweep's detections in the world frame."""

    def __init__(self, config: TrackerConfig, prediction: PredictionConfig) -> None:
        self._config = config
        self._prediction = prediction
        self._next_id = 1  # never reset: a track id is not reused within the tracker's life
        self.reset()

    def reset(self) -> None:
        """Forget every track (a new drive, or a jump in time)."""
        self._stamp_ns: int | None = None
        self._ids = np.zeros(0, dtype=np.int64)
        self._x = np.zeros((0, 4))
        self._p = np.zeros((0, 4, 4))
        self._yaw = np.zeros(0)
        self._yaw_rate = np.zeros(0)
        self._size = np.zeros((0, 3))
        self._z = np.zeros(0)
        self._classes = np.zeros(0, dtype=np.int64)
        self._confidence = np.zeros(0)
        self._hits = np.zeros(0, dtype=np.int64)
        self._misses = np.zeros(0, dtype=np.int64)
        self._box = np.zeros((0, 5))
        self._origin = np.zeros((0, 2))
        self._aligned = np.zeros(0, dtype=bool)

    def _predict(self, dt: float) -> None:
        transition = np.eye(4)
        transition[0, 2] = transition[1, 3] = dt
        sigma = self._config.acceleration_noise**2
        block = np.array([[dt**4 / 4.0, dt**3 / 2.0], [dt**3 / 2.0, dt**2]]) * sigma
        noise = np.zeros((4, 4))
        noise[np.ix_([0, 2], [0, 2])] = block
        noise[np.ix_([1, 3], [1, 3])] = block
        self._x = self._x @ transition.T
        self._p = transition @ self._p @ transition.T + noise
        self._yaw = self._yaw + self._yaw_rate * dt

    def _associate(self, world: Detections) -> tuple[IntArray, IntArray]:
        if self._ids.shape[0] == 0 or world.count == 0:
            return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
        # sqrt(dx^2 + dy^2) written out: the same numbers as np.linalg.norm(axis=-1), whose reduction over a
        # length-2 axis is several times slower on a tracks x detections matrix.
        dx = self._x[:, None, 0] - world.boxes[None, :, 0]
        dy = self._x[:, None, 1] - world.boxes[None, :, 1]
        distance = np.sqrt(dx * dx + dy * dy)
        gate = np.where(self._classes == _VEHICLE, self._config.gate, self._config.small_gate)
        allowed = (distance <= gate[:, None]) & (self._classes[:, None] == world.classes[None, :])
        cost = np.where(allowed, distance, _NO_MATCH)
        rows, columns = linear_sum_assignment(cost)
        good = cost[rows, columns] < _NO_MATCH
        return rows[good].astype(np.int64), columns[good].astype(np.int64)

    def _update(self, rows: IntArray, columns: IntArray, world: Detections, dt: float) -> None:
        if rows.shape[0] == 0:
            return
        measurement_noise = np.eye(2) * self._config.position_noise**2
        p = self._p[rows]
        innovation = world.boxes[columns, :2] - self._x[rows, :2]
        s = p[:, :2, :2] + measurement_noise
        gain = p[:, :, :2] @ np.linalg.inv(s)  # (R, 4, 2)
        self._x[rows] = self._x[rows] + np.einsum("rij,rj->ri", gain, innovation)
        self._p[rows] = p - gain @ p[:, :2, :]
        # Heading: the box's, flipped to agree with the motion (boxes are symmetric under a half turn).
        velocity = self._x[rows, 2:]
        moving = np.hypot(velocity[:, 0], velocity[:, 1]) > max(self._config.static_speed, 1e-3)  # heading from motion
        box_yaw = world.boxes[columns, 2]
        reference = np.where(moving, np.arctan2(velocity[:, 1], velocity[:, 0]), self._yaw[rows])
        flipped = np.abs(_wrap(box_yaw - reference)) > 0.5 * np.pi
        box_yaw = _wrap(np.where(flipped, box_yaw + np.pi, box_yaw))
        new_yaw = np.where(moving, np.arctan2(velocity[:, 1], velocity[:, 0]), box_yaw)
        if dt > 0:
            measured_rate = np.where(moving, _wrap(new_yaw - self._yaw[rows]) / dt, 0.0)
            weight = self._prediction.yaw_rate_smoothing
            rate = (1.0 - weight) * self._yaw_rate[rows] + weight * measured_rate
            limit = self._prediction.max_yaw_rate
            self._yaw_rate[rows] = np.clip(rate, -limit, limit)
        self._yaw[rows] = new_yaw
        # Vehicles and bicycles move along their boxes; a parked car whose visible outline slides sideways does not.
        along_box = np.abs(np.cos(np.arctan2(velocity[:, 1], velocity[:, 0]) - world.boxes[columns, 2]))
        self._aligned[rows] = along_box >= np.cos(np.deg2rad(self._config.heading_tolerance_deg))
        self._size[rows, :2] = world.boxes[columns, 3:5]
        self._size[rows, 2] = world.heights[columns]
        self._z[rows] = world.z[columns]
        self._confidence[rows] = world.confidences[columns]
        self._hits[rows] += 1
        self._misses[rows] = 0
        self._box[rows] = world.boxes[columns]

    def _birth(self, new: IntArray, world: Detections) -> None:
        count = new.shape[0]
        if count == 0:
            return
        state = np.zeros((count, 4))
        state[:, :2] = world.boxes[new, :2]
        covariance = np.zeros((count, 4, 4))
        covariance[:, 0, 0] = covariance[:, 1, 1] = self._config.position_noise**2
        covariance[:, 2, 2] = covariance[:, 3, 3] = self._config.initial_speed_noise**2
        ids = np.arange(self._next_id, self._next_id + count, dtype=np.int64)
        self._next_id += count
        self._ids = np.concatenate([self._ids, ids])
        self._x = np.concatenate([self._x, state])
        self._p = np.concatenate([self._p, covariance])
        self._yaw = np.concatenate([self._yaw, world.boxes[new, 2]])
        self._yaw_rate = np.concatenate([self._yaw_rate, np.zeros(count)])
        self._size = np.concatenate([self._size, np.column_stack([world.boxes[new, 3:5], world.heights[new]])])
        self._z = np.concatenate([self._z, world.z[new]])
        self._classes = np.concatenate([self._classes, world.classes[new]])
        self._confidence = np.concatenate([self._confidence, world.confidences[new]])
        self._hits = np.concatenate([self._hits, np.ones(count, dtype=np.int64)])
        self._misses = np.concatenate([self._misses, np.zeros(count, dtype=np.int64)])
        self._box = np.concatenate([self._box, world.boxes[new]])
        self._origin = np.concatenate([self._origin, world.boxes[new, :2]])
        self._aligned = np.concatenate([self._aligned, np.zeros(count, dtype=bool)])

    def _keep(self, keep: BoolArray) -> None:
        for name in ("_ids", "_x", "_p", "_yaw", "_yaw_rate", "_size", "_z", "_classes", "_confidence", "_hits"):
            setattr(self, name, getattr(self, name)[keep])
        self._misses = self._misses[keep]
        self._box = self._box[keep]
        self._origin = self._origin[keep]
        self._aligned = self._aligned[keep]

    def update(self, stamp_ns: int, world: Detections) -> TrackSet:
        """Advance to stamp_ns and take in that sweep's detections (world frame)."""
        if self._stamp_ns is not None:
            gap_s = (stamp_ns - self._stamp_ns) * 1e-9
            if gap_s <= 0.0 or gap_s > self._config.max_gap_s:
                self.reset()
        dt = 0.0 if self._stamp_ns is None else (stamp_ns - self._stamp_ns) * 1e-9
        if dt > 0:
            self._predict(dt)
        self._stamp_ns = stamp_ns
        self._misses += 1
        rows, columns = self._associate(world)
        self._update(rows, columns, world, dt)
        unmatched = np.ones(world.count, dtype=bool)
        unmatched[columns] = False
        self._birth(np.flatnonzero(unmatched), world)
        self._keep(self._misses <= self._config.max_misses)
        config = self._config
        moving = (self._hits >= config.min_hits) & (np.hypot(self._x[:, 2], self._x[:, 3]) > config.static_speed)
        moving &= np.linalg.norm(self._x[:, :2] - self._origin, axis=1) > config.static_displacement
        moving &= self._aligned | ~np.isin(self._classes, _HEADED)
        return TrackSet(
            ids=self._ids.copy(),
            state=self._x.copy(),
            yaw=self._yaw.copy(),
            yaw_rate=self._yaw_rate.copy(),
            size=self._size.copy(),
            z=self._z.copy(),
            classes=self._classes.copy(),
            confidence=self._confidence.copy(),
            hits=self._hits.copy(),
            misses=self._misses.copy(),
            detected_box=self._box.copy(),
            moving=moving,
        )
