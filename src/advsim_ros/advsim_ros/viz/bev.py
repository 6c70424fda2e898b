"""The bird's-eye view of an attack, original (left) vs adversarial (right): one drawer for bev.png and bev.gif.

A panel shows the actors' boxes (perturbed in red, with their paths dashed), the SDV's logged box
(green) and its human trajectory, the stack's plan of the decision frame and the SDV's box where
the plan puts it at that time (orange; red with a star from the first collision on), in closed
loop what the ego drove (black) and where reactive actors drove instead of their tracks (purple),
and the LiDAR the stack saw: each history frame's sweep, then the decision frame's sweep held.
`bev_figure` draws what stays once and returns, per panel, the function that moves the rest to a
stamp; the animation (viz/animation.py) blits it frame by frame, the still (`write_bev_still`,
OUTDIR/bev.png) is that figure at the decision instant with the first collision marked.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeAlias

import numpy as np

from advsim_ros.core.attack_summary import Score
from advsim_ros.core.geometry import box_corners
from advsim_ros.core.metrics import plan_from_decision
from advsim_ros.core.types import ActorTrack, FloatArray, Plan, Scenario, ScenarioError
from advsim_ros.viz.attack_view import AttackView, number
from advsim_ros.viz.markers import plan_pose_at

NS_PER_S = 1e9
# a matplotlib figure, axis, text or patch: matplotlib is imported lazily (a heavy import), its objects untyped here
Artist: TypeAlias = Any
# (stamp, whether to show the first collision already) -> (artists that moved, the panel's title)
PanelUpdate = Callable[[int, bool], tuple[list[Artist], Artist]]


@dataclass(frozen=True)
class BevLook:
    """Size and content of a bird's-eye-view figure."""

    width: float = 10.0  # figure width [in]
    height: float = 5.0  # figure height [in]
    dpi: int = 72  # [dots/in]: 10 x 5 in -> 720 x 360 px
    max_points: int = 4000  # LiDAR points drawn per panel (evenly subsampled) [1]
    margin: float = 12.0  # view around the SDV's paths and the perturbed actors [m]
    reach: float = 30.0  # perturbed actors' positions farther than this from the SDV's paths are not framed [m]

    def __post_init__(self) -> None:
        if self.width <= 0 or self.height <= 0 or self.dpi <= 0 or self.margin < 0 or self.reach < 0:
            raise ScenarioError("bird's-eye view: width, height and dpi must be positive, margin and reach >= 0")
        if self.max_points < 0:
            raise ScenarioError("bird's-eye view: max_points >= 0")


STILL = BevLook(dpi=150, max_points=20000)  # bev.png: the animation's figure at 1500 x 750 px


@dataclass(frozen=True, eq=False)
class _Panel:
    title: str
    scenario: Scenario
    plan: Plan | None
    collision_ns: int | None
    score: Score | None
    driven: FloatArray | None  # closed loop: what the ego drove (K, 2) [m]
    reacted: Sequence[ActorTrack]  # closed loop: reactive actors' drives


@dataclass(frozen=True, eq=False)
class BevFigure:
    """A drawn bird's-eye view: the matplotlib figure, one update per panel, the heading's moving texts."""

    figure: Artist
    updates: list[PanelUpdate]
    clock: Artist  # "t = ... s from the decision" (left)
    phase: Artist  # history or plan (right)

    def texts(self, titles: Sequence[Artist]) -> tuple[Artist, ...]:
        return (self.clock, self.phase, *titles)

    def heading(self, stamp: int, decision_ns: int) -> None:
        self.clock.set_text(f"t = {(stamp - decision_ns) / NS_PER_S:+.1f} s from the decision")
        self.phase.set_text("history: the stack sees LiDAR" if stamp <= decision_ns else "the stack's plan, open loop")


def _panels(view: AttackView) -> list[_Panel]:
    summary = view.summary
    panels = []
    if view.original is not None:
        panels.append(
            _Panel("original (logged)", view.original, view.original_plan, view.original_collision_ns,
                   summary.get("original"), view.original_driven, view.original_reacted)
        )  # fmt: skip
    panels.append(
        _Panel("adversarial", view.adversarial, view.adversarial_plan, view.adversarial_collision_ns,
               summary.get("adversarial"), view.adversarial_driven, view.adversarial_reacted)
    )  # fmt: skip
    return panels


def bev_figure(view: AttackView, look: BevLook) -> BevFigure:
    """The figure of an attack's panels, its static parts drawn; the caller closes it (pyplot.close)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = _panels(view)
    x0, x1, y0, y1 = _extent(view, look.margin, look.reach)
    # panels side by side, or one above the other for a long, flat scene (a straight road along x)
    stacked = len(panels) > 1 and (x1 - x0) > 2.2 * (y1 - y0)
    figure, axes_array = plt.subplots(
        len(panels) if stacked else 1,
        1 if stacked else len(panels),
        figsize=(look.width, look.height),
        dpi=look.dpi,
        squeeze=False,  # not shared: equal aspect with adjustable limits needs independent axes (same limits set)
    )
    axes = list(axes_array[:, 0] if stacked else axes_array[0])
    updates = [_draw_panel(axis, panel, view, look) for axis, panel in zip(axes, panels, strict=True)]
    for axis in axes:
        axis.tick_params(labelsize=7)
        axis.set_ylabel("y [m]", fontsize=8)
    axes[-1].set_xlabel("x [m]", fontsize=8)
    axes[-1].legend(loc="upper right", fontsize=6, framealpha=0.8)
    scenario = view.summary.get("scenario", {})
    scenario_id = scenario.get("scenario_id", view.adversarial.scenario_id)
    start = scenario.get("window_start_frame")
    window = "" if start is None else f" window @ frame {start}"
    figure.suptitle(f"{scenario_id}{window}   red = perturbed", fontsize=9, y=0.985)
    # the moving part of the heading: the time (left) and the phase of the window (right)
    clock = figure.text(0.02, 0.915, "", fontsize=8, animated=True)
    phase = figure.text(0.98, 0.915, "", fontsize=8, ha="right", animated=True)
    figure.tight_layout(rect=(0.0, 0.0, 1.0, 0.9))
    for axis in axes:  # equal scale: widen the limits to the panel's shape (the panel keeps its size)
        box = axis.get_position()
        panel_ratio = (box.height * look.height) / (box.width * look.width)
        (left, right), (bottom, top) = _fit((x0, x1), (y0, y1), panel_ratio)
        axis.set_xlim(left, right)
        axis.set_ylim(bottom, top)
    return BevFigure(figure, updates, clock, phase)


def write_bev_still(view: AttackView, path: Path, look: BevLook = STILL) -> Path:
    """OUTDIR/bev.png: the panels at the decision instant, the first collision on the plan marked; atomically."""
    import matplotlib.pyplot as plt

    drawn = bev_figure(view, look)
    try:
        moved = [update(view.decision_ns, True) for update in drawn.updates]
        drawn.heading(view.decision_ns, view.decision_ns)
        for artist in [*drawn.texts([title for _, title in moved]), *(a for artists, _ in moved for a in artists)]:
            artist.set_animated(False)  # a still draws everything at once
        path = Path(path)
        temporary = path.with_name(f".{path.name}.tmp.png")
        drawn.figure.savefig(temporary)
        os.replace(temporary, path)
    finally:
        plt.close(drawn.figure)
    return path


class TextStamps:
    """Draws animated texts, each look once: rasterising glyphs was most of a frame's cost (a title
    changes twice in a window), so a text seen before is pasted from the pixels it drew then."""

    def __init__(self, figure: Artist) -> None:
        self.figure = figure
        self.drawn: dict[tuple[int, str, str], Artist] = {}

    def draw(self, text: Artist) -> None:
        key = (id(text), text.get_text(), str(text.get_color()))
        region = self.drawn.get(key)
        canvas = self.figure.canvas
        if region is not None:
            canvas.restore_region(region)
            return
        self.figure.draw_artist(text)
        box = text.get_window_extent(canvas.get_renderer()).padded(2)
        self.drawn[key] = canvas.copy_from_bbox(box)


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
    """x and y limits holding the SDV's logged path, plans and drives, and the perturbed actors near them [m]."""
    scenario = view.adversarial
    plans = [plan.xy for plan in (view.adversarial_plan, view.original_plan) if plan is not None]
    drives = [xy for xy in (view.adversarial_driven, view.original_driven) if xy is not None and len(xy)]
    around = np.vstack([scenario.ego.xy, *plans, *drives])
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


def _title(panel: _Panel) -> str:
    score = panel.score or {}
    text = (
        f"L_adv {number(score.get('adversarial_loss'))}, collision@5s {number(score.get('collision_5s'))}, "
        f"L2@5s {number(score.get('l2_human_5s'))} m"
    )
    if score.get("loop") == "closed":
        text = f"driven: {text}; plan (open loop) collision@5s {number(score.get('open_loop_collision_5s'))}"
    return f"{panel.title}: {text}"


def _draw_panel(axis: Artist, panel: _Panel, view: AttackView, look: BevLook) -> PanelUpdate:
    """Draw the static parts of a panel; return the function that moves its dynamic parts to a stamp."""
    from matplotlib.patches import Polygon

    scenario, decision_ns = panel.scenario, view.decision_ns
    moved = set(view.perturbed_ids)
    lidar = axis.scatter(np.empty(0), np.empty(0), s=0.3, c="0.6", linewidths=0, zorder=1, animated=True)
    axis.plot(*scenario.ego.xy.T, color="tab:green", lw=1.5, zorder=2, label="human trajectory")
    full_plan = None
    if panel.plan is not None:
        full_plan = plan_from_decision(panel.plan, scenario.ego.poses[view.decision_index], decision_ns)
        axis.plot(*panel.plan.xy.T, color="tab:orange", lw=1.5, zorder=3, label="stack plan")
    if panel.driven is not None and len(panel.driven):
        axis.plot(*panel.driven.T, color="black", lw=1.5, zorder=3, label="driven (closed loop)")
    for index, track in enumerate(panel.reacted):
        label = "reacted actors (closed loop)" if index == 0 else None
        axis.plot(*track.centers[:, :2].T, color="tab:purple", lw=1.5, zorder=3, label=label)
        axis.plot(*track.centers[-1, :2], "o", color="tab:purple", ms=3, zorder=3)  # where it ended up
    boxes: list[tuple[Artist, list[int], Artist]] = []
    for actor in scenario.actors:
        perturbed = actor.actor_id in moved
        color = "tab:red" if perturbed else "tab:blue"
        if perturbed:
            axis.plot(*actor.centers[:, :2].T, "--", color=color, lw=1, zorder=2)
        patch = Polygon(np.zeros((4, 2)), closed=True, color=color, alpha=0.7 if perturbed else 0.45, zorder=4,
                        animated=True)  # fmt: skip
        patch.set_visible(False)
        axis.add_patch(patch)
        boxes.append((patch, actor.stamps_ns.tolist(), actor))
    ego_patch = Polygon(np.zeros((4, 2)), closed=True, color="tab:green", alpha=0.5, zorder=5, label="SDV (logged)",
                        animated=True)  # fmt: skip
    axis.add_patch(ego_patch)
    planned_patch = Polygon(np.zeros((4, 2)), closed=True, fill=False, edgecolor="tab:orange", lw=2, zorder=6,
                            label="SDV on its plan", animated=True)  # fmt: skip
    axis.add_patch(planned_patch)  # visible: the legend copies its look (animated, so no frame draws it unasked)
    (star,) = axis.plot([], [], marker="*", color="red", markersize=16, zorder=7, linestyle="none", animated=True)
    base_title = _title(panel)
    title = axis.set_title(base_title, fontsize=8)
    title.set_animated(True)
    index_of = {int(stamp): i for i, stamp in enumerate(scenario.frame_stamps_ns.tolist())}
    collision_pose = (
        plan_pose_at(full_plan, panel.collision_ns)
        if full_plan is not None and panel.collision_ns is not None
        else None
    )

    def update(stamp: int, show_collision: bool = False) -> tuple[list[Artist], Artist]:
        lidar.set_offsets(_lidar_world(scenario, stamp, decision_ns, look.max_points))
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
        reached = panel.collision_ns is not None and stamp >= panel.collision_ns  # the box is in the collision
        colliding = reached or (show_collision and panel.collision_ns is not None)
        pose = plan_pose_at(full_plan, stamp) if full_plan is not None and stamp >= decision_ns else None
        planned_patch.set_visible(pose is not None)
        if pose is not None:
            planned_patch.set_xy(_sdv_box(scenario, pose[0], pose[1], pose[2]))
            planned_patch.set_edgecolor("red" if reached else "tab:orange")
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
