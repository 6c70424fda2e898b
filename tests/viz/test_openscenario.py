"""`advsim export openscenario`: the XML validates against the ASAM XSD and gives back the bag's tracks."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from advsim_ros.core.geometry import wrap_angle
from advsim_ros.export.openscenario import (
    EGO,
    ExportError,
    export_openscenario,
    perturbed_entities,
    read_trajectories,
    validate,
)
from advsim_ros.io.bag import read_scenario_bag


@pytest.fixture(scope="module")
def exported(attack_out: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("xosc") / "scenario.xosc"
    export_openscenario(attack_out / "adversarial", path)
    return path


def test_the_exported_trajectories_read_back_are_the_bags_tracks_within_1_cm_and_1_ms(
    exported: Path, attack_out: Path
) -> None:
    validate(exported)  # the written file, read again, validates against the XSD
    scenario = read_scenario_bag(attack_out / "adversarial", load_sweeps=False)
    start = int(scenario.frame_stamps_ns[0])
    read = read_trajectories(exported)
    assert set(read) == {EGO, *(actor.actor_id for actor in scenario.actors if actor.stamps_ns.shape[0] >= 2)}
    perturbed = perturbed_entities(exported)
    assert perturbed == {scenario.actors[0].actor_id}
    for actor in scenario.actors:
        if actor.actor_id not in read:
            continue
        got = read[actor.actor_id]
        assert np.max(np.abs(got.times - (actor.stamps_ns - start) / 1e9)) <= 1e-3
        centre = got.xyzh[:, :3] + np.array([0.0, 0.0, actor.height / 2.0])  # reference point on the ground
        assert np.max(np.linalg.norm(centre - actor.centers, axis=1)) <= 0.01
        assert np.max(np.abs(wrap_angle(got.xyzh[:, 3] - actor.yaws))) <= 1e-6
    ego = read[EGO]
    assert np.max(np.abs(ego.times - (scenario.frame_stamps_ns - start) / 1e9)) <= 1e-3
    assert np.max(np.linalg.norm(ego.xyzh[:, :2] - scenario.ego.xy, axis=1)) <= 0.01


def test_validation_rejects_xml_the_schema_does_not_allow(exported: Path, tmp_path: Path) -> None:
    text = exported.read_text()
    broken = tmp_path / "broken.xosc"
    broken.write_text(text.replace("<Polyline>", "<Polyline><Bogus/>", 1))
    with pytest.raises(ExportError, match="does not validate"):
        validate(broken)


def test_the_command_writes_once_and_refuses_to_overwrite_with_one_line(attack_out: Path, tmp_path: Path) -> None:
    output = tmp_path / "out.xosc"
    command = [sys.executable, "-m", "advsim_ros.cli", "export", "openscenario", str(attack_out / "adversarial"),
               "-o", str(output)]  # fmt: skip
    first = subprocess.run(command, capture_output=True, text=True, timeout=120, check=False)
    assert first.returncode == 0, first.stderr
    assert "validated against OpenSCENARIO" in first.stdout
    again = subprocess.run(command, capture_output=True, text=True, timeout=120, check=False)
    assert again.returncode == 1
    assert again.stderr.strip().count("\n") == 0
    assert "exists" in again.stderr
    missing = subprocess.run([*command[:5], str(tmp_path / "nothing"), "-o", str(tmp_path / "x.xosc")],
                             capture_output=True, text=True, timeout=120, check=False)  # fmt: skip
    assert missing.returncode == 1
    assert "bag not found" in missing.stderr
    assert not (tmp_path / "x.xosc").exists()
