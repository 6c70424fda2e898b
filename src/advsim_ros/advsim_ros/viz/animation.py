"""Animated bird's-eye view of an attack, original (left) vs adversarial (right), over the whole window (GIF).

Each frame of the window (1 s of history, then the 5 s the plan covers) shows the actors' boxes
(perturbed in red, with their paths dashed), the SDV's logged box (green) and its human
trajectory, the stack's plan of the decision frame and the SDV's box where the plan puts it at
that time (orange; red with a star from the first collision on), and the LiDAR the stack saw:
each history frame's sweep, then the decision frame's sweep held (the stack sees only 1 s). The
collision frame is held for a moment so that the instant is not missed. matplotlib draws the
frames (blitting the static background; a text that shows again is pasted, not rasterised again)
and Pillow writes the GIF.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from advsim_ros.core.geometry import box_corners
from advsim_ros.core.metrics import plan_from_decision
from advsim_ros.core.types import FloatArray, Plan, Scenario, ScenarioError
from advsim_ros.viz.attack_view import AttackView, number
from advsim_ros.viz.markers import plan_pose_at

NS_PER_S = 1e9


@dataclass(frozen=True)
class AnimationConfig:
    """How the GIF is drawn: small and quick by default (about 1-2 MB, a few seconds)."""

    fps: float = 10.0  # GIF frames per second: the log's 10 Hz plays in real time [1/s]
    frame_stride: int = 1  # draw every n-th frame of the window [1]
    hold_collision: int = 8  # extra copies of the first collision frame (a pause of 0.8 s at 10 fps) [1]
    max_points: int = 4000  # LiDAR points drawn per panel and frame (evenly subsampled) [1]
    width: float = 10.0  # figure width [in]
    height: float = 5.0  # figure height [in]
    dpi: int = 72  # [dots/in]: 10 x 5 in -> 720 x 360 px
    margin: float = 12.0  # view around the SDV's paths and the perturbed actors [m]
    reach: float = 30.0  # perturbed actors' positions farther than this from the SDV's paths are not framed [m]

    def __post_init__(self) -> None:
        if not (0.0 < self.fps <= 50.0):
            raise ScenarioError(f"AnimationConfig.fps: must be in (0, 50], got {self.fps}")
        if self.frame_stride < 1 or self.hold_collision < 0 or self.max_points < 0:
            raise ScenarioError("AnimationConfig: frame_stride >= 1, hold_collision >= 0 and max_points >= 0")
        if self.width <= 0 or self.height <= 0 or self.dpi <= 0 or self.margin < 0 or self.reach < 0:
            raise ScenarioError("AnimationConfig: width, height and dpi must be positive, margin >= 0")


@dataclass(frozen=True, eq=False)
class _Panel:
    title: str
    scenario: Scenario
    plan: Plan | None
    collision_ns: int | None
    score: dict[str, Any] | None


def _box(x: float, y: float, yaw: float, length: float, width: float) -> FloatArray:
    corners: FloatArray = np.asarray(box_corners(np.array([x, y, yaw, length, width])), dtype=np.float64)
    return corners


def _sdv_box(scenario: Scenario, x: float, y: float, yaw: float) -> FloatArray:
    box = scenario.ego_geometry.boxes(np.array([x, y]), np.array(yaw))
    return _box(*box.tolist())


def _lidar_world(scenario: Scenario, stamp: int, decision_ns: int, max_points: int) -> FloatArray:
    """Points (x, y) of the sweep the stack saw at this time: the frame's own, after the decision the decision's."""
    wanted = min(stamp, decision_ns)
    sweeps = [sweep for sweep in scenario.sweeps if sweep.stamp_ns <= wanted]
    if not sweeps or max_points == 0:
        return np.empty((0, 2))
    sweep = sweeps[-1]
    picked = sweep.points[:: max(1, sweep.num_points // max_points)]  # subsample before converting
    xyz = np.stack([picked[name].astype(np.float64) for name in ("x", "y", "z")], axis=-1)
    world: FloatArray = (xyz @ sweep.sensor_pose[:3, :3].T + sweep.sensor_pose[:3, 3])[:, :2]
    return world


def _extent(view: AttackView, margin: float, reach: float) -> tuple[float, float, float, float]:
    """x and y limits holding the SDV's logged path and plans, and the perturbed actors near them [m]."""
    scenario = view.adversarial
    sdv = [scenario.ego.xy] + [plan.xy for plan in (view.adversarial_plan, view.original_plan) if plan is not None]
    around = np.vstack(sdv)
    points = [around]
    for actor in scenario.actors:
        if actor.actor_id in view.perturbed_ids:
            xy = actor.centers[:, :2]
            near = np.min(np.linalg.norm(xy[:, None, :] - around[None, :, :], axis=-1), axis=1) <= reach
            points.append(xy[near])
    stacked = np.vstack(points)
    low, high = stacked.min(axis=0) - margin, stacked.max(axis=0) + margin
    return float(low[0]), float(high[0]), float(low[1]), float(high[1])


def _fit(x: tuple[float, float], y: tuple[float, float], ratio: float) -> tuple[tuple[float, float], ...]:
    """x and y limits widened around their centre so that height / width equals ``ratio``."""
    width, height = x[1] - x[0], y[1] - y[0]
    if height < ratio * width:
        height = ratio * width
    else:
        width = height / ratio
    cx, cy = (x[0] + x[1]) / 2.0, (y[0] + y[1]) / 2.0
    return (cx - width / 2.0, cx + width / 2.0), (cy - height / 2.0, cy + height / 2.0)


def _frames(view: AttackView, config: AnimationConfig) -> list[int]:
    """Window frame indices in play order: every stride-th frame, the first collision frame held."""
    stamps = view.adversarial.frame_stamps_ns
    order = list(range(0, stamps.shape[0], config.frame_stride))
    collision = view.adversarial_collision_ns
    if collision is not None:
        first = int(np.searchsorted(stamps, collision))  # the first frame at or after the collision
        if first < stamps.shape[0]:
            if first not in order:
                order = sorted({*order, first})
            position = order.index(first)
            order[position + 1 : position + 1] = [first] * config.hold_collision
    return order


def write_bev_animation(view: AttackView, path: Path, config: AnimationConfig | None = None) -> Path:
    """Write the animated BEV of an attack to ``path`` (GIF), atomically; return the path.

    The static parts (axes, paths, legend) are drawn once; each frame restores them and draws only
    what moves (blitting), and Pillow writes the frames with one shared palette.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Polygon
    from PIL import Image

    config = config or AnimationConfig()
    summary = view.summary
    panels = []
    if view.original is not None:
        panels.append(
            _Panel(
                "original (logged)",
                view.original,
                view.original_plan,
                view.original_collision_ns,
                summary.get("original"),
            )
        )
    panels.append(
        _Panel(
            "adversarial",
            view.adversarial,
            view.adversarial_plan,
            view.adversarial_collision_ns,
            summary.get("adversarial"),
        )
    )
    x0, x1, y0, y1 = _extent(view, config.margin, config.reach)
    # panels side by side, or one above the other for a long, flat scene (a straight road along x)
    stacked = len(panels) > 1 and (x1 - x0) > 2.2 * (y1 - y0)
    figure, axes_array = plt.subplots(
        len(panels) if stacked else 1,
        1 if stacked else len(panels),
        figsize=(config.width, config.height),
        dpi=config.dpi,
        squeeze=False,  # not shared: equal aspect with adjustable limits needs independent axes (same limits set)
    )
    try:
        axes = list(axes_array[:, 0] if stacked else axes_array[0])
        decision_ns = view.decision_ns
        stamps = view.adversarial.frame_stamps_ns
        updaters = [
            _draw_panel(axis, panel, view, decision_ns, config, Polygon)
            for axis, panel in zip(axes, panels, strict=True)
        ]
        for axis in axes:
            axis.tick_params(labelsize=7)
            axis.set_ylabel("y [m]", fontsize=8)
        axes[-1].set_xlabel("x [m]", fontsize=8)
        axes[-1].legend(loc="upper right", fontsize=6, framealpha=0.8)
        scenario_id = summary.get("scenario", {}).get("scenario_id", view.adversarial.scenario_id)
        figure.suptitle(f"{scenario_id}   red = perturbed", fontsize=9, y=0.985)
        # the moving part of the heading: the time (left) and the phase of the window (right)
        clock = figure.text(0.02, 0.915, "", fontsize=8, animated=True)
        phase = figure.text(0.98, 0.915, "", fontsize=8, ha="right", animated=True)
        figure.tight_layout(rect=(0.0, 0.0, 1.0, 0.9))
        for axis in axes:  # equal scale: widen the limits to the panel's shape (the panel keeps its size)
            box = axis.get_position()
            panel_ratio = (box.height * config.height) / (box.width * config.width)
            (left, right), (bottom, top) = _fit((x0, x1), (y0, y1), panel_ratio)
            axis.set_xlim(left, right)
            axis.set_ylim(bottom, top)
        canvas = figure.canvas
        canvas.draw()  # the static background, once
        background = canvas.copy_from_bbox(figure.bbox)  # type: ignore[attr-defined]
        texts = _TextStamps(figure)
        images = []
        for index in _frames(view, config):
            stamp = int(stamps[index])
            clock.set_text(f"t = {(stamp - decision_ns) / NS_PER_S:+.1f} s from the decision")
            phase.set_text("history: the stack sees LiDAR" if stamp <= decision_ns else "the stack's plan, open loop")
            canvas.restore_region(background)  # type: ignore[attr-defined]
            moving = [updater(stamp) for updater in updaters]
            for text in (clock, phase, *(title for _, title in moving)):
                texts.draw(text)  # on the bare background, before anything moving can overlap them
            for artists, _ in moving:
                for artist in artists:
                    figure.draw_artist(artist)
            rgba = np.asarray(canvas.buffer_rgba())  # type: ignore[attr-defined]
            images.append(Image.fromarray(rgba[..., :3].copy()))
    finally:
        plt.close(figure)
    # one palette for every frame, from frames across the window (colours that appear late, the
    # collision's red, must be in it)
    picks = sorted({*np.linspace(0, len(images) - 1, 6).round().astype(int).tolist()})
    strip = Image.new("RGB", (images[0].width, images[0].height * len(picks)))
    for row, pick in enumerate(picks):
        strip.paste(images[pick], (0, row * images[0].height))
    palette = strip.quantize(colors=128, method=Image.Quantize.MEDIANCUT)
    frames = [image.quantize(palette=palette, dither=Image.Dither.NONE) for image in images]
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(f".{path.stem}.tmp{path.suffix}")
    try:
        frames[0].save(
            temporary, format="GIF", save_all=True, append_images=frames[1:], duration=round(1000 / config.fps), loop=0
        )
        os.replace(temporary, path)
    finally:
        temporary.unlink(missing_ok=True)
    return path


def _draw_panel(
    axis: Any, panel: _Panel, view: AttackView, decision_ns: int, config: AnimationConfig, polygon: Any
) -> Any:
    """Draw the static parts of a panel; return the function that moves its dynamic parts to a stamp
    (it returns them and the panel's title)."""
    scenario = panel.scenario
    moved = set(view.perturbed_ids)
    lidar = axis.scatter(np.empty(0), np.empty(0), s=0.3, c="0.6", linewidths=0, zorder=1, animated=True)
    axis.plot(*scenario.ego.xy.T, color="tab:green", lw=1.5, zorder=2, label="human trajectory")
    full_plan = None
    if panel.plan is not None:
        full_plan = plan_from_decision(panel.plan, scenario.ego.poses[view.decision_index], decision_ns)
        axis.plot(*panel.plan.xy.T, color="tab:orange", lw=1.5, zorder=3, label="stack plan")
    boxes: list[tuple[Any, Sequence[int], Any]] = []
    for actor in scenario.actors:
        perturbed = actor.actor_id in moved
        color = "tab:red" if perturbed else "tab:blue"
        if perturbed:
            axis.plot(*actor.centers[:, :2].T, "--", color=color, lw=1, zorder=2)
        patch = polygon(
            np.zeros((4, 2)), closed=True, color=color, alpha=0.7 if perturbed else 0.45, zorder=4, animated=True
        )
        patch.set_visible(False)
        axis.add_patch(patch)
        boxes.append((patch, actor.stamps_ns.tolist(), actor))
    ego_patch = polygon(
        np.zeros((4, 2)), closed=True, color="tab:green", alpha=0.5, zorder=5, label="SDV (logged)", animated=True
    )
    axis.add_patch(ego_patch)
    planned_patch = polygon(
        np.zeros((4, 2)),
        closed=True,
        fill=False,
        edgecolor="tab:orange",
        lw=2,
        zorder=6,
        label="SDV on its plan",
        animated=True,
    )
    planned_patch.set_visible(False)
    axis.add_patch(planned_patch)
    (star,) = axis.plot([], [], marker="*", color="red", markersize=16, zorder=7, linestyle="none", animated=True)
    score = panel.score or {}
    base_title = (
        f"{panel.title}: L_adv {number(score.get('adversarial_loss'))}, "
        f"collision@5s {number(score.get('collision_5s'))}, L2@5s {number(score.get('l2_human_5s'))} m"
    )
    title = axis.set_title(base_title, fontsize=8)
    title.set_animated(True)
    index_of = {int(stamp): i for i, stamp in enumerate(scenario.frame_stamps_ns.tolist())}
    collision_pose = (
        plan_pose_at(full_plan, panel.collision_ns)
        if full_plan is not None and panel.collision_ns is not None
        else None
    )

    def update(stamp: int) -> tuple[list[Any], Any]:
        lidar.set_offsets(_lidar_world(scenario, stamp, decision_ns, config.max_points))
        for patch, actor_stamps, actor in boxes:
            try:
                i = actor_stamps.index(stamp)
            except ValueError:
                patch.set_visible(False)
                continue
            x, y = actor.centers[i, :2]
            patch.set_xy(_box(float(x), float(y), float(actor.yaws[i]), actor.length, actor.width))
            patch.set_visible(True)
        frame = index_of[stamp]
        ego_x, ego_y = (float(v) for v in scenario.ego.xy[frame])
        ego_patch.set_xy(_sdv_box(scenario, ego_x, ego_y, float(scenario.ego.yaws[frame])))
        colliding = panel.collision_ns is not None and stamp >= panel.collision_ns
        pose = plan_pose_at(full_plan, stamp) if full_plan is not None and stamp >= decision_ns else None
        planned_patch.set_visible(pose is not None)
        if pose is not None:
            planned_patch.set_xy(_sdv_box(scenario, pose[0], pose[1], pose[2]))
            planned_patch.set_edgecolor("red" if colliding else "tab:orange")
        if colliding and collision_pose is not None and panel.collision_ns is not None:
            seconds = (panel.collision_ns - decision_ns) / NS_PER_S
            star.set_data([collision_pose[0]], [collision_pose[1]])
            title.set_text(f"{base_title}\nCOLLISION of the SDV on its plan at +{seconds:.1f} s")
            title.set_color("red")
        else:
            star.set_data([], [])
            title.set_text(base_title)
            title.set_color("black")
        return [lidar, *(patch for patch, _, _ in boxes), ego_patch, planned_patch, star], title

    return update


class _TextStamps:
    """Draws animated texts, each look once: rasterising glyphs was most of a frame's cost (a title
    changes twice in a window), so a text seen before is pasted from the pixels it drew then."""

    def __init__(self, figure: Any) -> None:
        self.figure = figure
        self.drawn: dict[tuple[int, str, str], Any] = {}

    def draw(self, text: Any) -> None:
        key = (id(text), text.get_text(), str(text.get_color()))
        region = self.drawn.get(key)
        canvas = self.figure.canvas
        if region is not None:
            canvas.restore_region(region)
            return
        self.figure.draw_artist(text)
        box = text.get_window_extent(canvas.get_renderer()).padded(2)
        self.drawn[key] = canvas.copy_from_bbox(box)
