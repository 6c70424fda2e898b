"""bev.png: the bird's-eye view at the decision instant, drawn by the same code as the animation."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
from PIL import Image

from advsim_ros.viz.attack_view import load_attack_view
from advsim_ros.viz.bev import STILL, write_bev_still


def _pure_red(rgb: np.ndarray) -> int:
    return int(np.sum((rgb[..., 0] > 200) & (rgb[..., 1] < 40) & (rgb[..., 2] < 40)))


def test_the_still_marks_the_collision_on_the_adversarial_side_and_draws_a_closed_loop_drive(
    attack_out: Path, tmp_path: Path
) -> None:
    view = load_attack_view(attack_out / "adversarial", attack_out / "summary.json")
    assert view.adversarial_collision_ns is not None
    assert view.original_collision_ns is None
    path = write_bev_still(view, tmp_path / "bev.png")
    with Image.open(path) as image:
        assert image.size == (round(STILL.width * STILL.dpi), round(STILL.height * STILL.dpi))
        rgb = np.asarray(image.convert("RGB")).astype(int)
    half = rgb.shape[1] // 2
    # both panels draw the perturbed actor's path in red; only the adversarial one the star and the red title
    assert _pure_red(rgb[:, half:]) > _pure_red(rgb[:, :half]) + 50
    assert not list(tmp_path.glob(".*"))  # written atomically: no temporary left

    # closed loop: what the ego drove is drawn (black) where the plan alone drew nothing
    drive = view.adversarial.ego.xy[view.decision_index :] + np.array([0.0, 3.0])
    driven = write_bev_still(dataclasses.replace(view, adversarial_driven=drive), tmp_path / "driven.png")
    with Image.open(driven) as image:
        black = np.all(np.asarray(image.convert("RGB")).astype(int) < 30, axis=-1)
    assert np.sum(black) > np.sum(np.all(rgb < 30, axis=-1)) + 100
