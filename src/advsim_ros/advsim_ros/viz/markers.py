"""visualization_msgs/MarkerArray of a scenario for Foxglove and RViz: actors, the human trajectory, the plan.

``scenario_markers`` returns (topic, type, stamp [ns], CDR) tuples, exactly what
``write_scenario_bag(..., extra=...)`` takes, so an adversarial bag carries its own drawing.
Every array is in the world frame and stamped at a frame of the scenario; each one starts with
a DELETEALL marker so that RViz and Foxglove show only the current frame's boxes when a bag is
played or scrubbed. Topics (docs/outputs.md, "Markers"):

- ``/advsim/markers/actors``: per frame, a box (CUBE) per actor seen then and a text label
  "<id> <class>" above it; perturbed actors in red with their whole perturbed path (LINE_STRIP),
  the others in blue; the SDV's logged box in green.
- ``/advsim/markers/human``: per frame, the ego's logged (human) trajectory over the window.
- ``/advsim/markers/plan``: from the decision frame on, the stack's plan (LINE_STRIP) and the SDV's
  box where the plan puts it at that frame's time (orange; red from the first collision on).
- ``/advsim/markers/detections`` and ``/advsim/markers/predictions``: at the decision frame, the
  stack's detections (yellow boxes) and predicted paths, only when the stack gave them.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from advsim_ros.contract import codec, names, qos
from advsim_ros.contract.codec import Msg, header_msg, message
from advsim_ros.contract.topics import TopicSpec
from advsim_ros.core.futures import ActorFutures, actor_futures_at
from advsim_ros.core.metrics import MetricsConfig, collision_steps, plan_from_decision
from advsim_ros.core.types import ActorTrack, FloatArray, Plan, Scenario

ACTORS = TopicSpec("/advsim/markers/actors", names.MARKER_ARRAY, qos.STREAM)
HUMAN = TopicSpec("/advsim/markers/human", names.MARKER_ARRAY, qos.STREAM)
PLAN = TopicSpec("/advsim/markers/plan", names.MARKER_ARRAY, qos.STREAM)
DETECTIONS = TopicSpec("/advsim/markers/detections", names.MARKER_ARRAY, qos.STREAM)
PREDICTIONS = TopicSpec("/advsim/markers/predictions", names.MARKER_ARRAY, qos.STREAM)
MARKER_TOPICS: tuple[TopicSpec, ...] = (ACTORS, HUMAN, PLAN, DETECTIONS, PREDICTIONS)

# visualization_msgs/Marker constants (ROS 2 Jazzy)
CUBE, LINE_STRIP, TEXT_VIEW_FACING = 1, 4, 9
ADD, DELETEALL = 0, 3

Rgba = tuple[float, float, float, float]
PERTURBED_COLOR: Rgba = (0.90, 0.10, 0.10, 0.85)
ACTOR_COLOR: Rgba = (0.12, 0.47, 0.71, 0.55)
EGO_COLOR: Rgba = (0.17, 0.63, 0.17, 0.75)
PLAN_COLOR: Rgba = (1.00, 0.50, 0.05, 0.95)
COLLISION_COLOR: Rgba = (1.00, 0.00, 0.00, 1.00)
DETECTION_COLOR: Rgba = (1.00, 0.85, 0.10, 0.50)
PREDICTION_COLOR: Rgba = (0.60, 0.30, 0.80, 0.90)
TEXT_COLOR: Rgba = (1.0, 1.0, 1.0, 1.0)
LINE_WIDTH = 0.25  # LINE_STRIP width [m]
TEXT_HEIGHT = 1.0  # label height [m]
LINE_HEIGHT = 0.2  # height of drawn paths above the ground plane of the world frame [m]


@dataclass(frozen=True, eq=False)
class StackOutputs:
    """What the stack answered at the decision frame (world frame): its plan, and its detections and predictions."""

    plan: Plan | None  # the decision frame's plan, None when the stack gave none
    detections: tuple[ActorTrack, ...] = ()  # one state per detected box, empty when it gave none
    predictions: tuple[ActorTrack, ...] = ()  # future states per predicted actor, empty when it gave none


def _color(rgba: Rgba) -> Msg:
    return message("std_msgs/msg/ColorRGBA", r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3])


def _point(x: float, y: float, z: float) -> Msg:
    return message(names.POINT, x=float(x), y=float(y), z=float(z))


def _pose(x: float, y: float, z: float, yaw: float) -> Msg:
    orientation = message(names.QUATERNION, x=0.0, y=0.0, z=math.sin(yaw / 2.0), w=math.cos(yaw / 2.0))
    return message(names.POSE, position=_point(x, y, z), orientation=orientation)


def _marker(
    stamp: int,
    frame_id: str,
    namespace: str,
    marker_id: int,
    kind: int,
    *,
    action: int = ADD,
    pose: Msg = None,
    scale: tuple[float, float, float] = (1.0, 1.0, 1.0),
    color: Rgba = TEXT_COLOR,
    points: Sequence[Msg] = (),
    text: str = "",
) -> Msg:
    """One visualization_msgs/Marker with every field set (rosbags messages have no defaults)."""
    return message(
        "visualization_msgs/msg/Marker",
        header=header_msg(stamp, frame_id),
        ns=namespace,
        id=marker_id,
        type=kind,
        action=action,
        pose=pose if pose is not None else _pose(0.0, 0.0, 0.0, 0.0),
        scale=message(names.VECTOR3, x=scale[0], y=scale[1], z=scale[2]),
        color=_color(color),
        lifetime=message("builtin_interfaces/msg/Duration", sec=0, nanosec=0),
        frame_locked=False,
        points=list(points),
        colors=[],
        texture_resource="",
        texture=message(
            "sensor_msgs/msg/CompressedImage", header=header_msg(stamp, frame_id), format="", data=np.empty(0, np.uint8)
        ),
        uv_coordinates=[],
        text=text,
        mesh_resource="",
        mesh_file=message("visualization_msgs/msg/MeshFile", filename="", data=np.empty(0, np.uint8)),
        mesh_use_embedded_materials=False,
    )


class _ArrayBuilder:
    """The markers of one MarkerArray, numbered per namespace, behind a DELETEALL."""

    def __init__(self, stamp: int, frame_id: str) -> None:
        self.stamp, self.frame_id = stamp, frame_id
        self.markers: list[Msg] = [_marker(stamp, frame_id, "", 0, CUBE, action=DELETEALL)]
        self._next: dict[str, int] = {}

    def add(self, namespace: str, kind: int, **fields: Msg) -> None:
        marker_id = self._next.get(namespace, 0)
        self._next[namespace] = marker_id + 1
        self.markers.append(_marker(self.stamp, self.frame_id, namespace, marker_id, kind, **fields))

    def box(self, namespace: str, center: Sequence[float], yaw: float, size: FloatArray, color: Rgba) -> None:
        x, y, z = (float(v) for v in center)
        scale = (float(size[0]), float(size[1]), float(size[2]))
        self.add(namespace, CUBE, pose=_pose(x, y, z, yaw), scale=scale, color=color)

    def label(self, namespace: str, center: Sequence[float], height: float, text: str) -> None:
        pose = _pose(float(center[0]), float(center[1]), float(center[2]) + height / 2.0 + TEXT_HEIGHT, 0.0)
        self.add(namespace, TEXT_VIEW_FACING, pose=pose, scale=(0.0, 0.0, TEXT_HEIGHT), color=TEXT_COLOR, text=text)

    def line(self, namespace: str, xyz: FloatArray, color: Rgba) -> None:
        if xyz.shape[0] < 2:
            return
        points = [_point(x, y, z) for x, y, z in xyz.tolist()]
        self.add(namespace, LINE_STRIP, scale=(LINE_WIDTH, 0.0, 0.0), color=color, points=points)

    def encoded(self, topic: TopicSpec) -> tuple[str, str, int, bytes]:
        array = message(names.MARKER_ARRAY, markers=self.markers)
        return (topic.name, topic.msgtype, self.stamp, codec.encode(array))


def first_collision_ns(scenario: Scenario, plan: Plan, decision_index: int, config: MetricsConfig) -> int | None:
    """Log time [ns] of the first plan stamp at which the SDV's box on its plan overlaps an actor; None if never.

    The scorer's collision test (core.metrics.collision_steps) on the plan with the SDV's pose at the
    decision time in front, against the scenario's actors (the perturbed ones as perturbed).
    """
    decision_ns = int(scenario.frame_stamps_ns[decision_index])
    full = plan_from_decision(plan, scenario.ego.poses[decision_index], decision_ns)
    futures: ActorFutures = actor_futures_at(scenario.actors, full.stamps_ns, config.actor_extrapolation)
    colliding = collision_steps(full, futures, scenario.ego_geometry, config)
    return int(full.stamps_ns[int(np.argmax(colliding))]) if np.any(colliding) else None


def plan_pose_at(plan: Plan, stamp: int) -> tuple[float, float, float] | None:
    """The plan's (x, y, yaw) at a log time [ns], linear in time; None outside the plan's stamps."""
    stamps = plan.stamps_ns
    if stamp < int(stamps[0]) or stamp > int(stamps[-1]):
        return None
    x = float(np.interp(stamp, stamps, plan.xy[:, 0]))
    y = float(np.interp(stamp, stamps, plan.xy[:, 1]))
    yaw = float(np.interp(stamp, stamps, np.unwrap(plan.yaws)))
    return x, y, yaw


def _ego_box_center(scenario: Scenario, x: float, y: float, z: float, yaw: float) -> tuple[float, float, float]:
    """Centre of the SDV's box for the ego frame at (x, y, z, yaw): its forward offset ahead, standing on the ground."""
    ego = scenario.ego_geometry
    return (
        x + ego.forward_offset * math.cos(yaw),
        y + ego.forward_offset * math.sin(yaw),
        z + float(ego.size[2]) / 2.0,
    )


def scenario_markers(
    scenario: Scenario,
    perturbed_ids: Sequence[str],
    outputs: StackOutputs,
    decision_index: int,
    frame_id: str,
    metrics: MetricsConfig | None = None,
) -> list[tuple[str, str, int, bytes]]:
    """MarkerArrays of every frame of ``scenario`` (an attacked window) as (topic, type, stamp [ns], CDR) tuples.

    ``decision_index`` is the frame (index into the scenario) the stack planned from; ``metrics``
    sets the collision test that colours the SDV's planned box (default: the scorer's defaults).
    """
    config = metrics or MetricsConfig()
    moved = set(perturbed_ids)
    plan = outputs.plan
    collision_ns = first_collision_ns(scenario, plan, decision_index, config) if plan is not None else None
    decision_ns = int(scenario.frame_stamps_ns[decision_index])
    ego_z = scenario.ego.poses[:, 2, 3]
    human = np.column_stack([scenario.ego.xy, ego_z + LINE_HEIGHT])
    extra: list[tuple[str, str, int, bytes]] = []
    for index, stamp in enumerate(scenario.frame_stamps_ns.tolist()):
        actors = _ArrayBuilder(stamp, frame_id)
        for actor in scenario.actors:
            at = np.nonzero(actor.stamps_ns == stamp)[0]
            if not at.size:
                continue
            i = int(at[0])
            perturbed = actor.actor_id in moved
            namespace = "perturbed" if perturbed else "actors"
            actors.box(
                namespace,
                actor.centers[i],
                float(actor.yaws[i]),
                actor.size,
                PERTURBED_COLOR if perturbed else ACTOR_COLOR,
            )
            text = f"{actor.actor_id} {actor.actor_class.value}" + (" (perturbed)" if perturbed else "")
            actors.label(f"{namespace}_labels", actor.centers[i], actor.height, text)
            if perturbed:
                actors.line("perturbed_paths", actor.centers, PERTURBED_COLOR)
        ego_yaw = float(scenario.ego.yaws[index])
        ego_x, ego_y = (float(v) for v in scenario.ego.xy[index])
        ego_center = _ego_box_center(scenario, ego_x, ego_y, float(ego_z[index]), ego_yaw)
        actors.box("sdv_logged", ego_center, ego_yaw, scenario.ego_geometry.size, EGO_COLOR)
        actors.label("sdv_labels", ego_center, float(scenario.ego_geometry.size[2]), "SDV (logged)")
        extra.append(actors.encoded(ACTORS))

        trajectory = _ArrayBuilder(stamp, frame_id)
        trajectory.line("human_trajectory", human, EGO_COLOR)
        extra.append(trajectory.encoded(HUMAN))

        if plan is not None and stamp >= decision_ns:
            planned = _ArrayBuilder(stamp, frame_id)
            z = float(ego_z[decision_index]) + LINE_HEIGHT
            planned.line("plan", np.column_stack([plan.xy, np.full(plan.xy.shape[0], z)]), PLAN_COLOR)
            pose = plan_pose_at(plan_from_decision(plan, scenario.ego.poses[decision_index], decision_ns), stamp)
            if pose is not None:
                colliding = collision_ns is not None and stamp >= collision_ns
                center = _ego_box_center(scenario, pose[0], pose[1], float(ego_z[decision_index]), pose[2])
                planned.box(
                    "sdv_planned",
                    center,
                    pose[2],
                    scenario.ego_geometry.size,
                    COLLISION_COLOR if colliding else PLAN_COLOR,
                )
                text = "SDV on its plan" + (" - COLLISION" if colliding else "")
                planned.label("sdv_planned_labels", center, float(scenario.ego_geometry.size[2]), text)
            extra.append(planned.encoded(PLAN))
    extra.extend(_stack_perception(outputs, decision_ns, frame_id))
    return extra


def _stack_perception(outputs: StackOutputs, decision_ns: int, frame_id: str) -> list[tuple[str, str, int, bytes]]:
    """The stack's detections and predictions of the decision frame, when it gave them."""
    found = []
    if outputs.detections:
        detections = _ArrayBuilder(decision_ns, frame_id)
        for track in outputs.detections:
            detections.box("detections", track.centers[0], float(track.yaws[0]), track.size, DETECTION_COLOR)
            detections.label(
                "detection_labels", track.centers[0], track.height, f"{track.actor_id} {track.actor_class.value}"
            )
        found.append(detections.encoded(DETECTIONS))
    if outputs.predictions:
        predictions = _ArrayBuilder(decision_ns, frame_id)
        for track in outputs.predictions:
            predictions.line("predictions", track.centers + np.array([0.0, 0.0, LINE_HEIGHT]), PREDICTION_COLOR)
        found.append(predictions.encoded(PREDICTIONS))
    return found
