"""Reading and checking a search's settings does not import the algorithm's heavy dependencies."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from advsim_ros.core.search.registry import ALGORITHM_NAMES, config_type, make_search


@pytest.mark.parametrize("name", ALGORITHM_NAMES)
def test_the_config_is_the_one_the_algorithm_takes(name: str) -> None:
    search = make_search(name, 2, np.random.default_rng(0), config_type(name)())
    assert type(search.config) is config_type(name)


def test_bo_settings_are_read_without_importing_torch(
    imported_after: Callable[[str, tuple[str, ...]], list[str]],
) -> None:
    # `advsim attack` checks the search's settings before the graph starts: torch and BoTorch took seconds there
    code = (
        "from advsim_ros.core.search.registry import config_from_params\n"
        "config_from_params('bo', {'initial_points': 5}).notes()\n"
    )
    assert imported_after(code, ("torch", "botorch", "gpytorch")) == []
