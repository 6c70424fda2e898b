"""The animated BEV: every frame of the window, small, and the collision instant visible."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from advsim_ros.viz.animation import AnimationConfig, write_bev_animation
from advsim_ros.viz.attack_view import load_attack_view


def _red(image: Image.Image) -> int:
    """Pixels of pure red (the collision star and title)."""
    rgb = np.asarray(image.convert("RGB")).astype(int)
    return int(np.sum((rgb[..., 0] > 200) & (rgb[..., 1] < 40) & (rgb[..., 2] < 40)))


def test_the_gif_shows_the_window_frame_by_frame_and_marks_the_collision(attack_out: Path, tmp_path: Path) -> None:
    view = load_attack_view(attack_out / "adversarial", attack_out / "summary.json")
    assert view.original is not None
    assert view.original_plan is not None
    assert view.adversarial_collision_ns is not None
    assert view.original_collision_ns is None
    path = write_bev_animation(view, tmp_path / "bev.gif")
    assert path.stat().st_size < 3_000_000
    with Image.open(path) as gif:
        frames = []
        durations = []
        for index in range(gif.n_frames):
            gif.seek(index)
            frames.append(gif.convert("RGB"))
            durations.append(gif.info["duration"])
    # 60 frames of 0.1 s; the held collision frame merges into one longer frame
    assert sum(durations) == pytest.approx((60 + AnimationConfig().hold_collision) * 100, abs=len(frames))
    assert len(frames) >= 55
    assert frames[0].size == (720, 360)
    stamps = view.adversarial.frame_stamps_ns
    collision_frame = int(np.searchsorted(stamps, view.adversarial_collision_ns))
    before = _red(frames[collision_frame - 2])
    after = _red(frames[-1])
    assert after > before + 50  # the star and the red title appear at the collision
    assert not np.array_equal(np.asarray(frames[0]), np.asarray(frames[30]))  # things move


def test_bad_settings_are_refused() -> None:
    with pytest.raises(ValueError, match="fps"):
        AnimationConfig(fps=0.0)
    summary = {"scenario": {"bag": "/nowhere", "window_start_frame": 0, "history_frames": 10, "future_frames": 50}}
    with pytest.raises(ValueError, match="bag not found"):
        load_attack_view(Path("/nowhere/adversarial"), json.loads(json.dumps(summary)))
