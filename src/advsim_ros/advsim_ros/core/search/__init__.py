"""Black-box search over the perturbation box [-1, 1]^D behind one ask/tell interface."""

from advsim_ros.core.search.base import BestPoint, SearchAlgorithm, SearchConfig, SearchError, run_search
from advsim_ros.core.search.registry import (
    ALGORITHM_NAMES,
    SearchSettings,
    config_from_params,
    config_type,
    default_config,
    load_search_settings,
    make_search,
)

__all__ = [
    "ALGORITHM_NAMES",
    "BestPoint",
    "SearchAlgorithm",
    "SearchConfig",
    "SearchError",
    "SearchSettings",
    "config_from_params",
    "config_type",
    "default_config",
    "load_search_settings",
    "make_search",
    "run_search",
]
