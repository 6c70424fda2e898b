"""Animated bird's-eye view of an attack, original (left) vs adversarial (right), over the whole window (GIF).

Every frame of the window (1 s of history, then the 5 s the plan covers) is the figure of
viz/bev.py moved to that frame's stamp; the first collision frame is held for a moment so that
the instant is not missed. The static parts are drawn once and each frame restores them and draws
only what moves (blitting; a text that shows again is pasted, not rasterised again), and Pillow
writes the GIF with one palette for every frame.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from advsim_ros.core.types import ScenarioError
from advsim_ros.viz.attack_view import AttackView
from advsim_ros.viz.bev import BevLook, TextStamps, bev_figure


@dataclass(frozen=True)
class AnimationConfig:
    """How the GIF is drawn: small and quick by default (about 1-2 MB, a few seconds)."""

    fps: float = 10.0  # GIF frames per second: the log's 10 Hz plays in real time [1/s]
    frame_stride: int = 1  # draw every n-th frame of the window [1]
    hold_collision: int = 8  # extra copies of the first collision frame (a pause of 0.8 s at 10 fps) [1]
    look: BevLook = field(default_factory=BevLook)  # size (720 x 360 px), LiDAR points per panel, framing

    def __post_init__(self) -> None:
        if not (0.0 < self.fps <= 50.0):
            raise ScenarioError(f"AnimationConfig.fps: must be in (0, 50], got {self.fps}")
        if self.frame_stride < 1 or self.hold_collision < 0:
            raise ScenarioError("AnimationConfig: frame_stride >= 1 and hold_collision >= 0")


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
    """Write the animated BEV of an attack to ``path`` (GIF), atomically; return the path."""
    import matplotlib.pyplot as plt
    from PIL import Image

    config = config or AnimationConfig()
    drawn = bev_figure(view, config.look)
    figure = drawn.figure
    try:
        decision_ns = view.decision_ns
        stamps = view.adversarial.frame_stamps_ns
        canvas = figure.canvas
        canvas.draw()  # the static background, once
        background = canvas.copy_from_bbox(figure.bbox)
        texts = TextStamps(figure)
        images = []
        for index in _frames(view, config):
            stamp = int(stamps[index])
            drawn.heading(stamp, decision_ns)
            canvas.restore_region(background)
            moving = [update(stamp, False) for update in drawn.updates]
            for text in drawn.texts([title for _, title in moving]):
                texts.draw(text)  # on the bare background, before anything moving can overlap them
            for artists, _ in moving:
                for artist in artists:
                    figure.draw_artist(artist)
            rgba = np.asarray(canvas.buffer_rgba())
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
