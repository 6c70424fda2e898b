"""A node parameter given to an attack (--param, a campaign's parameters) adds to what the attack's options set."""

from __future__ import annotations

from pathlib import Path

from advsim_ros.attack.options import AttackOptions, StackSpec, default_params_dir
from advsim_ros.attack.params import node_files, node_parameters
from advsim_ros.attack.run import _base_overrides


def _search_parameters(options: AttackOptions, tmp_path: Path) -> dict[str, object]:
    overrides = _base_overrides(options, tmp_path / "journal.jsonl")
    return node_parameters(node_files(default_params_dir(), "search"), "search", overrides)


def test_a_nested_search_parameter_keeps_the_query_budget_of_the_options(tmp_path: Path) -> None:
    # campaign `parameters: {search: {bo: {initial_points: 8}}}` with `algorithms: {bo: 20}`
    options = AttackOptions(
        bag=tmp_path / "bag", out_dir=tmp_path / "out", stack=StackSpec.parse("reference"), algorithm="bo",
        queries=20, parameter_overrides={"search": {"bo": {"initial_points": 8}}},
    )  # fmt: skip
    bo = _search_parameters(options, tmp_path)["bo"]
    assert isinstance(bo, dict)
    assert (bo["max_queries"], bo["initial_points"]) == (20, 8)
    assert bo["beta"] == 3.0  # the rest of params/search.yaml's bo section stays


def test_the_user_s_own_query_budget_still_wins(tmp_path: Path) -> None:
    options = AttackOptions(
        bag=tmp_path / "bag", out_dir=tmp_path / "out", stack=StackSpec.parse("reference"), algorithm="bo",
        queries=20, parameter_overrides={"search": {"bo": {"max_queries": 30}}},
    )  # fmt: skip
    bo = _search_parameters(options, tmp_path)["bo"]
    assert isinstance(bo, dict)
    assert bo["max_queries"] == 30
