"""SimBA is `simba`; its old name `rs` is still accepted (one deprecation warning on stderr naming `simba`)
on the command line, in --param search.rs.*, and as the section of a params folder of before the rename."""

from __future__ import annotations

import logging
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from advsim_ros.attack.options import AttackOptions, StackSpec, default_params_dir
from advsim_ros.attack.params import node_files, node_parameters
from advsim_ros.attack.run import _base_overrides


def _advsim_attack(tmp_path: Path, algorithm: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "advsim_ros.cli", "attack", str(tmp_path / "no_bag"), "--algo", algorithm,
         "--queries", "5", "-o", str(tmp_path / "out")],
        capture_output=True, text=True, timeout=120, check=False,
    )  # fmt: skip


def test_advsim_attack_takes_simba_and_rs_with_one_deprecation_line_for_rs(tmp_path: Path) -> None:
    (error,) = _advsim_attack(tmp_path, "simba").stderr.strip().splitlines()
    assert "not a rosbag2 folder" in error  # got past --algo: the missing bag is what stops it
    old = _advsim_attack(tmp_path, "rs")
    warning, error = old.stderr.strip().splitlines()
    assert warning == "advsim attack: warning: search algorithm 'rs' is deprecated: use 'simba' (the same algorithm)"
    assert "not a rosbag2 folder" in error
    assert old.returncode == 1


def test_the_options_take_rs_as_simba_and_its_parameters_too(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    with caplog.at_level(logging.WARNING):
        options = AttackOptions(
            bag=tmp_path / "bag", out_dir=tmp_path / "out", stack=StackSpec.parse("reference"), algorithm="rs",
            queries=9, parameter_overrides={"search": {"rs": {"step": 0.5}}},
        )  # fmt: skip
    assert options.algorithm == "simba"
    assert options.parameter_overrides["search"] == {"simba": {"step": 0.5}}
    assert len(caplog.records) == 2
    assert all("'simba'" in record.getMessage() for record in caplog.records)
    overrides = _base_overrides(options, tmp_path / "journal.jsonl")
    simba = node_parameters(node_files(default_params_dir(), "search"), "search", overrides)["simba"]
    assert (simba["max_queries"], simba["step"]) == (9, 0.5)


def test_a_params_folder_with_an_rs_section_gives_it_to_simba(tmp_path: Path) -> None:
    params = tmp_path / "params"
    shutil.copytree(default_params_dir(), params)
    search = params / "search.yaml"
    search.write_text(search.read_text(encoding="utf-8").replace("    simba:\n", "    rs:\n"), encoding="utf-8")
    search.write_text(search.read_text(encoding="utf-8").replace("step: 0.25", "step: 0.75"), encoding="utf-8")
    options = AttackOptions(
        bag=tmp_path / "bag", out_dir=tmp_path / "out", stack=StackSpec.parse("reference"), algorithm="simba",
        queries=7, params_dir=params,
    )  # fmt: skip
    overrides = _base_overrides(options, tmp_path / "journal.jsonl")
    simba = node_parameters(node_files(params, "search"), "search", overrides)["simba"]
    assert (simba["max_queries"], simba["step"]) == (7, 0.75)
