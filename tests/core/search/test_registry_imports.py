"""Reading and checking a search's settings does not import the algorithm's heavy dependencies."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from advsim_ros.core.search.registry import ALGORITHM_NAMES, config_type, make_search


@pytest.mark.parametrize("name", ALGORITHM_NAMES)
def test_the_config_is_the_one_the_algorithm_takes(name: str) -> None:
    search = make_search(name, 2, np.random.default_rng(0), config_type(name)())
    assert type(search.config) is config_type(name)


def test_bo_settings_are_read_without_importing_torch() -> None:
    # `advsim attack` checks the search's settings before the graph starts: torch and BoTorch took seconds there
    code = (
        "import sys\n"
        "from advsim_ros.core.search.registry import config_from_params\n"
        "config_from_params('bo', {'initial_points': 5}).notes()\n"
        "print(sorted(name for name in ('torch', 'botorch', 'gpytorch') if name in sys.modules))\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert done.stdout.strip() == "[]"
