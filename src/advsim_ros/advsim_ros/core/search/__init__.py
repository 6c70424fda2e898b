"""Black-box search over the perturbation box [-1, 1]^D behind one ask/tell interface."""

from advsim_ros.core.renamed import RENAMED_ALGORITHMS, canonical_algorithm
from advsim_ros.core.search.base import BestPoint, SearchAlgorithm, SearchConfig, SearchError, run_search
from advsim_ros.core.search.registry import (
    ALGORITHM_NAMES,
    SearchSettings,
    accept_algorithm,
    config_from_params,
    config_type,
    default_config,
    load_search_settings,
    make_search,
)

__all__ = [
    "ALGORITHM_NAMES",
    "RENAMED_ALGORITHMS",
    "BestPoint",
    "SearchAlgorithm",
    "SearchConfig",
    "SearchError",
    "SearchSettings",
    "accept_algorithm",
    "canonical_algorithm",
    "config_from_params",
    "config_type",
    "default_config",
    "load_search_settings",
    "make_search",
    "run_search",
]
