"""A node parameter given to an attack (--param, a campaign's parameters) adds to what the attack's options set."""

from __future__ import annotations

from pathlib import Path

from advsim_ros.attack.options import AttackOptions, StackSpec, default_params_dir
from advsim_ros.attack.params import node_files, node_parameters
from advsim_ros.attack.run import _base_overrides


def _bo_parameters(tmp_path: Path, search_overrides: dict[str, object]) -> dict[str, object]:
    """The search node's bo section for a 20-query BO attack given ``search_overrides`` for the search node."""
    options = AttackOptions(
        bag=tmp_path / "bag", out_dir=tmp_path / "out", stack=StackSpec.parse("reference"), algorithm="bo",
        queries=20, parameter_overrides={"search": search_overrides},
    )  # fmt: skip
    overrides = _base_overrides(options, tmp_path / "journal.jsonl")
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
