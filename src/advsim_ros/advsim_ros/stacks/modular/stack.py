"""The modular LiDAR stack: ground removal -> clustering detector -> tracker -> prediction -> sampling planner."""

from __future__ import annotations

import time

import numpy as np

from advsim_ros.core.types import ActorClass, DrivableArea, FloatArray, Plan, RoadMap
from advsim_ros.stacks.interface import (
    ObjectTrajectories,
    StackFrame,
    StackOutput,
    plan_stamps,
    transform_points,
    yaw_of,
)
from advsim_ros.stacks.modular.config import ModularStackConfig
from advsim_ros.stacks.modular.detector import CLASS_ORDER, Detections, detect
from advsim_ros.stacks.modular.ground import split_ground
from advsim_ros.stacks.modular.occupancy import clear_boxes, obstacle_grid
from advsim_ros.stacks.modular.planner import EgoState, drivable_from_map, plan
from advsim_ros.stacks.modular.prediction import predict_tracks
from advsim_ros.stacks.modular.tracker import MultiObjectTracker, TrackSet


def detections_to_world(detections: Detections, world_T_ego: FloatArray) -> Detections:
    """The same boxes in the world frame (the ego pose is planar enough for BEV boxes)."""
    rotation = world_T_ego[:2, :2]
    centres = detections.boxes[:, :2] @ rotation.T + world_T_ego[:2, 3]
    yaws = np.angle(np.exp(1j * (detections.boxes[:, 2] + yaw_of(world_T_ego))))
    boxes = np.column_stack([centres, yaws, detections.boxes[:, 3:5]])
    return Detections(
        boxes, detections.z + world_T_ego[2, 3], detections.heights, detections.classes, detections.confidences,
        detections.num_points,
    )  # fmt: skip


class ModularStack:
    """Stateful modular stack; one step() per sweep."""

    name = "modular"
    perceives = True

    def __init__(self, config: ModularStackConfig | None = None) -> None:
        self.config = config or ModularStackConfig()
        self._tracker = MultiObjectTracker(self.config.tracker, self.config.prediction)
        self._road_map: RoadMap | None = None
        self._drivable: DrivableArea | None = None

    def reset(self) -> None:
        self._tracker.reset()

    def set_road_map(self, road_map: RoadMap | None) -> None:
        self._road_map = road_map
        self._drivable = drivable_from_map(road_map, self.config.planner) if road_map is not None else None

    def _objects(
        self, ids: list[str], classes: list[ActorClass], tracks: TrackSet, pick: np.ndarray, stamps: np.ndarray,
        xy: FloatArray, yaws: FloatArray, speeds: FloatArray, confidences: FloatArray,
    ) -> ObjectTrajectories:  # fmt: skip
        return ObjectTrajectories(
            actor_ids=tuple(ids[index] for index in pick),
            actor_classes=tuple(classes[index] for index in pick),
            sizes=tracks.size[pick],
            confidences=confidences[pick],
            stamps_ns=stamps,
            xy=xy[pick],
            z=tracks.z[pick],
            yaws=yaws[pick],
            velocities=speeds[pick],
        )

    def step(self, frame: StackFrame) -> StackOutput:
        config = self.config
        timings: dict[str, float] = {}
        start = time.perf_counter()
        xyz_ego = transform_points(np.asarray(frame.xyz, dtype=np.float32), frame.ego_T_sensor)
        split = split_ground(xyz_ego, config.ground)
        timings["ground"] = time.perf_counter() - start

        mark = time.perf_counter()
        detections = detect(split, config.ground, config.detector, frame.ego_T_sensor[:2, 3])
        world = detections_to_world(detections, frame.world_T_ego)
        timings["detection"] = time.perf_counter() - mark

        mark = time.perf_counter()
        tracks = self._tracker.update(frame.stamp_ns, world)
        future = plan_stamps(frame.stamp_ns, config.planner.horizon_s, config.planner.step_s)
        xy, yaws, speeds = predict_tracks(tracks, frame.stamp_ns, future, config.prediction, config.tracker)
        timings["tracking"] = time.perf_counter() - mark

        mark = time.perf_counter()
        ego_yaw = yaw_of(frame.world_T_ego)
        ego = EgoState(
            xy=frame.world_T_ego[:2, 3].copy(),
            yaw=ego_yaw,
            speed=frame.motion.speed,
            acceleration=frame.motion.acceleration,
            yaw_rate=frame.motion.yaw_rate,
            length=config.planner.ego_length,
            width=config.planner.ego_width,
            forward_offset=config.planner.ego_forward_offset,
        )
        # Confirmed road users that move are predicted boxes; everything else is static occupancy.
        lengths = np.broadcast_to(tracks.size[:, None, 0], yaws.shape)
        widths = np.broadcast_to(tracks.size[:, None, 1], yaws.shape)
        boxes = np.stack([xy[..., 0], xy[..., 1], yaws, lengths, widths], axis=-1)
        moving = tracks.moving & (tracks.classes != CLASS_ORDER.index(ActorClass.OTHER))
        static = obstacle_grid(
            split,
            config.ground,
            config.detector.cell_size,
            config.planner.static_max_height,
            config.planner.static_min_points,
            frame.world_T_ego,
        )
        # The grid is this sweep's: clear each moving object where this sweep saw it, not at the first plan
        # step (0.1 s on: at 8 m/s the returns of its rear would stay behind as an obstacle in the ego's path).
        current = np.column_stack([tracks.state[:, :2], tracks.yaw, tracks.size[:, :2]])
        current = np.where((tracks.misses == 0)[:, None], tracks.detected_box, current)
        static = clear_boxes(static, current[moving], config.planner.moving_clearance)
        # Returns on or right beside the ego body (mirrors, sensor rig) are not obstacles to plan around.
        forward = config.planner.ego_forward_offset * np.array([np.cos(ego_yaw), np.sin(ego_yaw)])
        ego_box = np.array([[*(ego.xy + forward), ego_yaw, ego.length, ego.width]])
        static = clear_boxes(static, ego_box, config.planner.safety_margin)
        choice = plan(ego, boxes[moving], config.planner, self._road_map, self._drivable, static)
        timings["planning"] = time.perf_counter() - mark

        ids = [str(track_id) for track_id in tracks.ids.tolist()]
        classes = [CLASS_ORDER[int(code)] for code in tracks.classes]
        seen_now = np.flatnonzero(tracks.misses == 0)
        now = np.array([frame.stamp_ns], dtype=np.int64)
        detected = tracks.detected_box
        detection_output = self._objects(
            ids, classes, tracks, seen_now, now, detected[:, None, :2], detected[:, None, 2],
            np.hypot(tracks.state[:, 2], tracks.state[:, 3])[:, None], tracks.confidence,
        )  # fmt: skip
        # Predictions are of confirmed road users, as the planner uses them; unclassified clutter (walls,
        # poles: most tracks) is static occupancy and would only cost a message of ~15k states per sweep.
        road_user = tracks.classes != CLASS_ORDER.index(ActorClass.OTHER)
        confirmed = np.flatnonzero((tracks.hits >= config.tracker.min_hits) & road_user)
        prediction_output = self._objects(ids, classes, tracks, confirmed, future, xy, yaws, speeds, tracks.confidence)
        timings["total"] = time.perf_counter() - start
        return StackOutput(
            plan=Plan(stamps_ns=future, xy=choice.xy, yaws=choice.yaw),
            plan_z=float(frame.world_T_ego[2, 3]),
            detections=detection_output,
            predictions=prediction_output,
            timings_s=timings,
        )
