"""A node parameter given to an attack (--param, a campaign's parameters) adds to what the attack's options set;
a BO budget its initial design fills is named random search before anything starts."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from advsim_ros.attack.options import AttackOptions, StackSpec, default_params_dir
from advsim_ros.attack.params import node_files, node_parameters
from advsim_ros.attack.run import _base_overrides, search_notes


def _options(tmp_path: Path, search_overrides: dict[str, object], queries: int = 20) -> AttackOptions:
    """A BO attack's options with ``search_overrides`` for the search node."""
    return AttackOptions(
        bag=tmp_path / "bag", out_dir=tmp_path / "out", stack=StackSpec.parse("reference"), algorithm="bo",
        queries=queries, parameter_overrides={"search": search_overrides},
    )  # fmt: skip


def _bo_parameters(tmp_path: Path, search_overrides: dict[str, object]) -> dict[str, object]:
    """The search node's bo section for a 20-query BO attack given ``search_overrides`` for the search node."""
    overrides = _base_overrides(_options(tmp_path, search_overrides), tmp_path / "journal.jsonl")
    bo = node_parameters(node_files(default_params_dir(), "search"), "search", overrides)["bo"]
    assert isinstance(bo, dict)
    return bo


def test_a_nested_search_parameter_keeps_the_query_budget_of_the_options(tmp_path: Path) -> None:
    # campaign `parameters: {search: {bo: {initial_points: 8}}}` with `algorithms: {bo: 20}`
    bo = _bo_parameters(tmp_path, {"bo": {"initial_points": 8}})
    assert (bo["max_queries"], bo["initial_points"]) == (20, 8)
    assert bo["beta"] == 3.0  # the rest of params/search.yaml's bo section stays


def test_the_user_s_own_query_budget_still_wins(tmp_path: Path) -> None:
    bo = _bo_parameters(tmp_path, {"bo": {"max_queries": 30}})
    assert bo["max_queries"] == 30


def test_a_bo_budget_its_initial_design_fills_is_called_random_search(tmp_path: Path) -> None:
    def notes(queries: int, search_overrides: dict[str, object]) -> tuple[str, ...]:
        return search_notes(_options(tmp_path, search_overrides, queries))

    (note,) = notes(20, {})  # params/search.yaml's initial design is 20 uniform queries
    assert "random search" in note
    assert "search.bo.initial_points" in note
    assert notes(20, {"bo": {"initial_points": 8}}) == ()  # 8 uniform, then 12 GP-UCB queries
    assert notes(75, {}) == ()  # the paper's 20 of 75


def test_advsim_attack_says_so_before_it_starts(tmp_path: Path) -> None:
    result = subprocess.run(
        [sys.executable, "-m", "advsim_ros.cli", "attack", str(tmp_path / "no_bag"), "--algo", "bo", "--queries", "20",
         "-o", str(tmp_path / "out")],
        capture_output=True, text=True, timeout=120, check=False,
    )  # fmt: skip
    note, error = result.stderr.strip().splitlines()
    assert note.startswith("advsim attack: note: --algo bo --queries 20: the initial design of 20 uniform queries")
    assert "not a rosbag2 folder" in error
    assert result.returncode == 1
