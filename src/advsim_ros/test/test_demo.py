"""`advsim demo` as a first-time user runs it: a staged scene, the reference stack, a found collision."""

from __future__ import annotations

import json
import subprocess
from collections.abc import Callable
from pathlib import Path

import pytest


@pytest.mark.slow
def test_the_demo_finds_a_collision_of_the_reference_stack_and_prints_the_comparison(
    advsim: Callable[..., subprocess.CompletedProcess[str]], tmp_path: Path
) -> None:
    out = tmp_path / "demo"
    demo = advsim("demo", "-o", str(out))
    assert demo.returncode == 0, demo.stderr
    summary = json.loads((out / "attack" / "summary.json").read_text())
    assert summary["original"]["collision_5s"] == 0.0
    assert summary["adversarial"]["collision_5s"] == 1.0  # the reference stack's plan collides
    assert summary["perturbed_actors"] == ["lead"]  # the staged interaction is the one attacked
    assert summary["best"]["reproduction"]["reproduced"]
    rows = {line[:36].strip(): line[36:].split() for line in demo.stdout.splitlines() if "  " in line}
    assert rows["collision up to 5 s"] == ["0", "1"]
    assert f"{(out / 'attack' / 'report.html').resolve()}" in demo.stdout
