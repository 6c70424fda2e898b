"""Bird's-eye view of an attack: the original scenario and the adversarial one side by side."""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from advsim_ros.core.episode import WindowConfig
from advsim_ros.core.geometry import box_corners
from advsim_ros.core.types import ActorTrack, FloatArray, Plan, Scenario


def _number(value: Any) -> str:
    return "n/a" if value is None else f"{value:.3g}"


def draw_bev(
    path: Path,
    source: Scenario,
    adversarial: Scenario,
    plans: tuple[Plan | None, Plan | None],
    window: WindowConfig,
    summary: dict[str, Any],
    driven: tuple[FloatArray | None, FloatArray | None] = (None, None),
    reacted: tuple[Sequence[ActorTrack], Sequence[ActorTrack]] = ((), ()),
) -> None:
    """Bird's-eye view, original (left) vs adversarial (right): actors, human trajectory, the stack's plan,
    in closed loop what the ego drove ((K, 2) positions) and where reactive actors drove instead of their tracks."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    frames = window.frame_indices(source.num_frames)
    decision = frames.start + window.decision_index
    decision_stamp = int(source.frame_stamps_ns[decision])
    future = source.ego.xy[decision : frames.stop]
    ego_pose = source.ego.poses[decision]
    moved_ids = set(summary["perturbed_actors"])
    figure, axes = plt.subplots(1, 2, figsize=(14, 6.5), sharex=True, sharey=True)
    panels = (
        ("original (logged)", source, summary.get("original"), plans[0], driven[0], reacted[0]),
        ("adversarial", adversarial, summary.get("adversarial"), plans[1], driven[1], reacted[1]),
    )
    for axis, (title, scenario, score, plan, drove, reactions) in zip(axes, panels, strict=True):
        if scenario is adversarial and adversarial.sweeps:
            sweep = adversarial.sweeps[-1]
            xyz = sweep.xyz[:: max(1, sweep.num_points // 20000)]
            world = xyz @ sweep.sensor_pose[:3, :3].T + sweep.sensor_pose[:3, 3]
            axis.scatter(world[:, 0], world[:, 1], s=0.2, c="0.75", linewidths=0)
        for actor in scenario.actors:
            inside = (actor.stamps_ns >= source.frame_stamps_ns[frames.start]) & (
                actor.stamps_ns <= source.frame_stamps_ns[frames.stop - 1]
            )
            if not np.any(inside):
                continue
            moved = actor.actor_id in moved_ids
            color = "tab:red" if moved else "tab:blue"
            axis.plot(actor.centers[inside, 0], actor.centers[inside, 1], "--", color=color, lw=1)
            at = np.nonzero(actor.stamps_ns == decision_stamp)[0]
            if at.size:
                i = int(at[0])
                box = np.array([*actor.centers[i, :2], actor.yaws[i], actor.length, actor.width])
                corners = box_corners(box)
                axis.fill(corners[:, 0], corners[:, 1], color=color, alpha=0.5 if moved else 0.3)
        ego_box = source.ego_geometry.boxes(ego_pose[:2, 3], np.array(math.atan2(ego_pose[1, 0], ego_pose[0, 0])))
        corners = box_corners(ego_box)
        axis.fill(corners[:, 0], corners[:, 1], color="tab:green", alpha=0.6, label="SDV")
        axis.plot(future[:, 0], future[:, 1], color="tab:green", lw=2, label="human trajectory")
        if plan is not None:
            axis.plot(plan.xy[:, 0], plan.xy[:, 1], color="black", lw=2, label="stack plan")
        if drove is not None:
            axis.plot(drove[:, 0], drove[:, 1], color="tab:orange", lw=2, label="driven (closed loop)")
        for index, track in enumerate(reactions):
            label = "reacted actors (closed loop)" if index == 0 else None
            axis.plot(track.centers[:, 0], track.centers[:, 1], color="tab:purple", lw=2, label=label)
            axis.plot(*track.centers[-1, :2], "o", color="tab:purple", ms=4)  # where it ended up
        text = (
            "no score"
            if score is None
            else f"L_adv {_number(score.get('adversarial_loss'))}   "
            f"collision@5s {_number(score.get('collision_5s'))}   L2@5s {_number(score.get('l2_human_5s'))} m"
        )
        if score is not None and score.get("loop") == "closed":
            text = f"driven: {text}   plan (open loop) collision@5s {_number(score.get('open_loop_collision_5s'))}"
        axis.set_title(f"{title}\n{text}", fontsize=10)
        axis.set_aspect("equal")
        axis.set_xlabel("x [m]")
        centre = ego_pose[:2, 3]
        axis.set_xlim(centre[0] - 45, centre[0] + 45)
        axis.set_ylim(centre[1] - 30, centre[1] + 30)
    axes[0].set_ylabel("y [m]")
    axes[1].legend(loc="upper right", fontsize=8)
    figure.suptitle(f"{summary['scenario']['scenario_id']} window @ frame {window.window_start_frame}: red = perturbed")
    figure.tight_layout()
    temporary = path.with_name(f".{path.name}.tmp.png")
    figure.savefig(temporary, dpi=110)
    plt.close(figure)
    os.replace(temporary, path)
