"""Open-loop evaluation of the reference stacks on unperturbed logs: the sanity table and detection AP.

Windows follow AdvSim's protocol: the stack sees one second of LiDAR (10 sweeps, starting
from a reset, as each query of an attack does) and its plan from the last sweep (the
decision frame) is scored against the human (logged) trajectory and the logged actors
over the next 5 s with core.metrics (collision up to 3 s / 5 s, L2 to human at 3 s / 5 s,
largest lateral acceleration, largest jerk), the same metrics the scorer reports.
Detection AP is Car BEV AP against KITTI's labels, pooled over the sweeps.
"""

from __future__ import annotations

import json
import os
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from advsim_ros.core.futures import actor_futures_at
from advsim_ros.core.geometry import bev_iou
from advsim_ros.core.metrics import (
    DetectionTally,
    MetricsConfig,
    QueryMetrics,
    aggregate_metrics,
    average_precision,
    match_detections,
    plan_from_decision,
    query_metrics,
)
from advsim_ros.core.types import Scenario
from advsim_ros.stacks.interface import AutonomyStack, StackError, yaw_of
from advsim_ros.stacks.replay import scenario_frames, window_frames

HISTORY_FRAMES = 10  # 1 s of LiDAR at 10 Hz before the decision
FUTURE_FRAMES = 50  # 5 s plan horizon at 10 Hz


@dataclass(frozen=True)
class WindowResult:
    """One window's plan, scored."""

    scenario_id: str
    decision_frame: int
    metrics: QueryMetrics
    seconds_per_sweep: tuple[float, ...]  # wall time of each step() in the window [s]


def evaluate_windows(
    stack: AutonomyStack,
    scenario: Scenario,
    metrics_config: MetricsConfig,
    stride: int = 10,
    keep: Callable[[int], bool] | None = None,
) -> list[WindowResult]:
    """Every window (1 s history, 5 s future; decisions `stride` frames apart, and keep(decision) if given)."""
    results: list[WindowResult] = []
    for start, decision in window_frames(scenario, HISTORY_FRAMES, FUTURE_FRAMES, stride):
        if keep is not None and not keep(decision):
            continue
        times: list[float] = []
        steps = []
        stack.reset()
        stack.set_road_map(scenario.road_map)
        for index, frame in scenario_frames(scenario, range(start, decision + 1)):
            began = time.perf_counter()
            steps.append((index, stack.step(frame)))
            times.append(time.perf_counter() - began)
        if not steps or steps[-1][0] != decision:
            raise StackError(f"{scenario.scenario_id}: no sweep at decision frame {decision}")
        plan = plan_from_decision(
            steps[-1][1].plan, scenario.ego.poses[decision], int(scenario.frame_stamps_ns[decision])
        )
        actors = actor_futures_at(scenario.actors, plan.stamps_ns, metrics_config.actor_extrapolation)
        metrics = query_metrics(plan, scenario.ego, actors, scenario.ego_geometry, metrics_config)
        results.append(WindowResult(scenario.scenario_id, decision, metrics, tuple(times)))
    return results


@dataclass(frozen=True)
class SanityRow:
    """One row of the sanity table: a stack on a set of windows."""

    stack: str
    data: str  # which windows
    windows: int
    collision_3s: float  # share of windows whose plan collides within 3 s [1]
    collision_5s: float  # ... within 5 s [1]
    l2_3s: float  # mean plan-to-human distance at 3 s [m]
    l2_5s: float  # ... at 5 s [m]
    lateral_acceleration: float  # mean of the per-plan largest |lateral acceleration| [m/s^2]
    jerk: float  # mean of the per-plan largest |jerk| [m/s^3]
    median_ms: float  # median wall time of one step() [ms]


def sanity_row(stack_name: str, data: str, results: Sequence[WindowResult]) -> SanityRow:
    if not results:
        raise StackError(f"no windows to evaluate for {stack_name} on {data}")
    total = aggregate_metrics([result.metrics for result in results])
    times = np.concatenate([np.asarray(result.seconds_per_sweep) for result in results])
    return SanityRow(
        stack=stack_name,
        data=data,
        windows=total.count,
        collision_3s=float(total.collision_rate[0]),
        collision_5s=float(total.collision_rate[1]),
        l2_3s=float(total.l2_human[0]),
        l2_5s=float(total.l2_human[1]),
        lateral_acceleration=float(total.lateral_acceleration),
        jerk=float(total.jerk),
        median_ms=float(1000.0 * np.median(times)),
    )


def kitti_car_boxes(scenario: Scenario, car_ids: set[str], frame: int) -> np.ndarray:
    """(G, 5) world-frame BEV boxes of the labelled cars at a frame."""
    stamp = int(scenario.frame_stamps_ns[frame])
    boxes = []
    for actor in scenario.actors:
        if actor.actor_id not in car_ids:
            continue
        hits = np.flatnonzero(actor.stamps_ns == stamp)
        if hits.size:
            index = int(hits[0])
            boxes.append([*actor.centers[index, :2], actor.yaws[index], actor.length, actor.width])
    return np.array(boxes, dtype=np.float64).reshape(-1, 5)


def in_camera_view(world_xy: np.ndarray, world_T_ego: np.ndarray, half_angle: float) -> np.ndarray:
    """Whether world points are in front of the ego within +-half_angle of its heading (KITTI labels only there)."""
    local = (world_xy - world_T_ego[:2, 3]) @ world_T_ego[:2, :2]
    inside: np.ndarray = (local[:, 0] > 0.0) & (np.abs(np.arctan2(local[:, 1], local[:, 0])) <= half_angle)
    return inside


@dataclass(frozen=True)
class DetectionReport:
    """Car BEV AP of a detector over a log's sweeps."""

    sweeps: int
    ground_truth: int  # labelled cars in view, pooled
    ap: dict[str, float]  # "0.5", "0.7" -> AP at that BEV IoU


def car_detection_ap(
    stack: AutonomyStack,
    scenario: Scenario,
    car_ids: set[str],
    ignored_ids: set[str],
    iou_thresholds: Sequence[float] = (0.5, 0.7),
    camera_half_angle: float = np.deg2rad(45.0),
) -> DetectionReport:
    """Car BEV AP of the stack's vehicle detections against the labels, over every sweep of the log.

    KITTI labels objects in the camera's view only, so detections and labels are compared
    there (in front of the ego, within +-45 deg). Vans, trucks and trams are neither hits
    nor false alarms for Car (KITTI's convention): detections overlapping them at the IoU
    threshold are set aside.
    """
    stack.reset()
    stack.set_road_map(scenario.road_map)
    per_threshold: dict[float, list[DetectionTally]] = {threshold: [] for threshold in iou_thresholds}
    sweeps = 0
    ground_truth = 0
    for index, frame in scenario_frames(scenario):
        output = stack.step(frame)
        if output.detections is None:
            raise StackError(f"stack {stack.name} publishes no detections")
        sweeps += 1
        detections = output.detections
        vehicle = np.array([str(c) == "vehicle" for c in detections.actor_classes], dtype=bool)
        boxes = detections.boxes()[:, 0][vehicle]
        scores = detections.confidences[vehicle]
        pose = frame.world_T_ego
        seen = in_camera_view(boxes[:, :2], pose, camera_half_angle)
        boxes, scores = boxes[seen], scores[seen]
        cars = kitti_car_boxes(scenario, car_ids, index)
        cars = cars[in_camera_view(cars[:, :2], pose, camera_half_angle)]
        others = kitti_car_boxes(scenario, ignored_ids, index)
        ground_truth += cars.shape[0]
        van_iou = bev_iou(boxes[:, None, :], others[None, :, :]).max(axis=1) if others.size else np.zeros(len(boxes))
        car_iou = bev_iou(boxes[:, None, :], cars[None, :, :]).max(axis=1) if cars.size else np.zeros(len(boxes))
        for threshold in iou_thresholds:
            # A detection of a van is neither right nor wrong for Car.
            keep = ~((van_iou >= threshold) & (car_iou < threshold))
            config = MetricsConfig(iou_threshold=threshold)
            per_threshold[threshold].append(
                match_detections(boxes[keep], scores[keep], cars, pose[:2, 3], yaw_of(pose), config)
            )
    return DetectionReport(
        sweeps=sweeps,
        ground_truth=ground_truth,
        ap={f"{threshold:g}": average_precision(tallies) for threshold, tallies in per_threshold.items()},
    )


@dataclass(frozen=True)
class SanityReport:
    """Everything `advsim stack sanity` measured."""

    rows: list[SanityRow]
    detection: DetectionReport | None
    notes: list[str] = field(default_factory=list)

    def to_json(self) -> str:
        return json.dumps(asdict(self), indent=2)

    def markdown(self) -> str:
        lines = [
            "| stack | windows | # | collision 3 s | collision 5 s | L2 3 s [m] | L2 5 s [m] | lat. acc. [m/s²] "
            "| jerk [m/s³] | step median [ms] |",
            "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
        ]
        for row in self.rows:
            lines.append(
                f"| {row.stack} | {row.data} | {row.windows} | {100 * row.collision_3s:.1f} % | "
                f"{100 * row.collision_5s:.1f} % | {row.l2_3s:.2f} | {row.l2_5s:.2f} | "
                f"{row.lateral_acceleration:.2f} | {row.jerk:.2f} | {row.median_ms:.0f} |"
            )
        if self.detection is not None:
            ap = ", ".join(f"IoU {key}: {100 * value:.1f}" for key, value in self.detection.ap.items())
            lines += [
                "",
                f"Car BEV AP of the modular detector ({self.detection.sweeps} sweeps, "
                f"{self.detection.ground_truth} labelled cars in view): {ap}",
            ]
        return "\n".join(lines + [""] + [f"- {note}" for note in self.notes])


def write_report(report: SanityReport, path: Path) -> None:
    """The report as JSON (and Markdown beside it), written atomically."""
    path.parent.mkdir(parents=True, exist_ok=True)
    for target, text in ((path, report.to_json()), (path.with_suffix(".md"), report.markdown())):
        handle, temporary = tempfile.mkstemp(prefix=f".{target.name}.", dir=target.parent)
        try:
            with os.fdopen(handle, "w", encoding="utf-8") as stream:
                stream.write(text + "\n")
            os.chmod(temporary, 0o644)  # mkstemp makes it private
            os.replace(temporary, target)
        finally:
            if os.path.exists(temporary):
                os.unlink(temporary)
