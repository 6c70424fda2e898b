"""Pruning of sampled candidates, cheapest test first.

Kinematic bounds (speed and curvature only), poses and drivable area, then a coarse raster of
where other boxes could be touched (core.feasibility.cull_raster), then exact oriented-box
tests on what the raster flags.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from advsim_ros.core.dynamics import integrate_curvature, integrate_poses, integrate_speed, knot_weights
from advsim_ros.core.feasibility.config import PerturberConfig
from advsim_ros.core.feasibility.cull_raster import GROUP_BITS, CullRaster
from advsim_ros.core.feasibility.obstacles import WindowObstacles
from advsim_ros.core.feasibility.reference import ActorReference
from advsim_ros.core.feasibility.rollout import delta_controls
from advsim_ros.core.geometry import overlap_from_components
from advsim_ros.core.types import BoolArray, DrivableArea, IntArray

Float32Array = npt.NDArray[np.float32]

COARSE_STRIDE = 4  # actors are first tested at every COARSE_STRIDE-th step


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


def _columns(values: Float32Array, columns: IntArray) -> Float32Array:
    """values[:, columns] in C order (plain indexing returns Fortran order, which slows every later step)."""
    result: Float32Array = np.take(values, columns, axis=1)
    return result


KINEMATIC_CHECKS = ("curvature_rate", "curvature", "speed", "accel", "lateral_accel")  # in the order they run


class Pruner:
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
        self.raster = CullRaster(self.others, origin, half_size, config.cull_cell, reach)
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
            [j for j in range(1, len(self.others.ids)) if 1 + (j - 1) % GROUP_BITS == bit]
            for bit in range(1, GROUP_BITS + 1)
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
        initial, accel, rate = delta_controls(self.reference, deltas, self.config, self.weights)
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
