"""The registry, the search parameters file and the test functions the comparison uses."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest

from advsim_ros import graph
from advsim_ros.core.params import ParamsError
from advsim_ros.core.search import (
    ALGORITHM_NAMES,
    accept_algorithm,
    canonical_algorithm,
    config_from_params,
    default_config,
    load_search_settings,
    make_search,
)
from advsim_ros.core.search.simba import Simba, SimbaConfig
from advsim_ros.core.search.synthetic import TEST_FUNCTION_NAMES, make_test_function

REPO = Path(__file__).resolve().parents[3]
SEARCH_PARAMS = REPO / "params" / "search.yaml"


@pytest.mark.parametrize("name", ALGORITHM_NAMES)
def test_the_search_parameters_file_holds_the_paper_defaults_of_every_algorithm(name: str) -> None:
    settings = load_search_settings(SEARCH_PARAMS, algorithm=name, node=graph.SEARCH.name)
    assert settings.algorithm == name
    assert settings.config == default_config(name)
    assert settings.seed == 0


def test_the_search_parameters_file_chooses_bayesian_optimisation_with_75_queries() -> None:
    settings = load_search_settings(SEARCH_PARAMS, node=graph.SEARCH.name)
    assert settings.algorithm == "bo"
    assert settings.config.max_queries == 75


def test_search_parameters_name_the_bad_key(tmp_path: Path) -> None:
    with pytest.raises(ParamsError, match=r"search ga: unknown parameter\(s\) \['populaton'\]"):
        config_from_params("ga", {"populaton": 16})
    with pytest.raises(ParamsError, match=r"search bo.beta: expected a number"):
        config_from_params("bo", {"beta": "three"})
    with pytest.raises(ParamsError, match=r"search nes: NesConfig.samples: must be an even number"):
        config_from_params("nes", {"samples": 7})
    broken = tmp_path / "search.yaml"
    broken.write_text("/search:\n  ros__parameters:\n    algorithm: cmaes\n", encoding="utf-8")
    with pytest.raises(ParamsError, match=r"algorithm: 'cmaes' is not one of bo, ga, simba, nes, bandit, random"):
        load_search_settings(broken, node=graph.SEARCH.name)
    broken.write_text("/scorer:\n  ros__parameters: {}\n", encoding="utf-8")
    with pytest.raises(ParamsError, match="no entry for node /search"):
        load_search_settings(broken, node=graph.SEARCH.name)


def test_simba_is_named_simba_and_its_old_name_rs_still_works_with_one_warning(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    assert "simba" in ALGORITHM_NAMES
    assert "rs" not in ALGORITHM_NAMES
    assert isinstance(make_search("simba", 4, np.random.default_rng(0)), Simba)
    with caplog.at_level(logging.WARNING):
        assert isinstance(make_search("rs", 4, np.random.default_rng(0)), Simba)
        assert accept_algorithm("rs") == "simba"
    assert [record.getMessage() for record in caplog.records] == [
        "search algorithm 'rs' is deprecated: use 'simba' (the same algorithm)"
    ] * 2
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        assert canonical_algorithm("rs") == "simba"  # what was recorded under it: silently
        assert accept_algorithm("simba") == canonical_algorithm("simba") == "simba"
        assert accept_algorithm("bo") == "bo"
    assert not caplog.records
    old = tmp_path / "search.yaml"  # a parameters file of before the rename
    old.write_text("/search:\n  ros__parameters:\n    algorithm: rs\n    rs: {step: 0.5}\n", encoding="utf-8")
    with caplog.at_level(logging.WARNING):
        settings = load_search_settings(old, node=graph.SEARCH.name)
    assert settings.algorithm == "simba"
    assert settings.config == SimbaConfig(step=0.5)
    assert len(caplog.records) == 2  # the section and the algorithm, one line each


@pytest.mark.parametrize("name", ["ackley", "rastrigin"])
def test_shifted_rotated_functions_peak_at_zero_inside_the_box(name: str) -> None:
    rng = np.random.default_rng(3)
    function = make_test_function(name, 12, rng)
    samples = function(np.random.default_rng(4).uniform(-1.0, 1.0, size=(2000, 12)))
    assert np.all(samples < function.upper_bound)
    # The optimum is the shift c: rebuild it from the same seed to evaluate there.
    centre = np.random.default_rng(3).uniform(-0.5, 0.5, size=12)
    assert function(centre[None])[0] == pytest.approx(0.0, abs=1e-9)


def test_the_collision_function_has_a_small_target_with_signal_outside() -> None:
    function = make_test_function("collision", 24, np.random.default_rng(0))
    values = function(np.random.default_rng(1).uniform(-1.0, 1.0, size=(20000, 24)))
    hit_rate = float(np.mean(values > 0.0))
    assert 0.0 < hit_rate < 0.01  # reachable but rare for uniform sampling
    assert np.all(values <= function.upper_bound)
    misses = values[values <= 0.0]
    assert misses.min() < -3.0  # the negative gap varies: there is a signal before contact


@pytest.mark.parametrize("name", TEST_FUNCTION_NAMES)
def test_test_functions_are_reproducible_from_the_seed(name: str) -> None:
    points = np.random.default_rng(9).uniform(-1.0, 1.0, size=(5, 12))
    first = make_test_function(name, 12, np.random.default_rng(7))(points)
    second = make_test_function(name, 12, np.random.default_rng(7))(points)
    np.testing.assert_array_equal(first, second)
