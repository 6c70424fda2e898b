"""Search algorithms by name, their configs, and the search parameters file.

Names: "bo" (GP-UCB), "ga" (GenAttack-style GA), "simba" (SimBA), "nes" (NES),
"bandit" (Bandit-TD), "random" (uniform sampling, the baseline). Modules are imported on
first use, so that choosing "ga" never pays for importing torch and BoTorch.

SimBA was once named "rs": a name a user gives (`--algo`, a campaign's `algorithms`, a
parameters file) is still accepted under its old name with one deprecation warning
(``accept_algorithm``); what was recorded under it (attack and campaign journals) reads as the
new name silently (``core.renamed.canonical_algorithm``).
"""

from __future__ import annotations

import importlib
import logging
from collections.abc import Mapping
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np

from advsim_ros.core.params import ParamsError, config_from_mapping, load_node_params
from advsim_ros.core.renamed import RENAMED_ALGORITHMS
from advsim_ros.core.search.base import SearchAlgorithm, SearchConfig, SearchError
from advsim_ros.core.search.driver import DriverConfig

ALGORITHM_NAMES = ("bo", "ga", "simba", "nes", "bandit", "random")
_log = logging.getLogger(__name__)

# name -> (module.algorithm class, module.config class); a config lives apart from a heavy algorithm
# (bo: torch, BoTorch) so that reading and checking settings does not import it
_ENTRIES: dict[str, tuple[str, str]] = {
    "bo": ("advsim_ros.core.search.bo.BayesianOptimization", "advsim_ros.core.search.bo_config.BoConfig"),
    "ga": ("advsim_ros.core.search.ga.GeneticAlgorithm", "advsim_ros.core.search.ga.GaConfig"),
    "simba": ("advsim_ros.core.search.simba.Simba", "advsim_ros.core.search.simba.SimbaConfig"),
    "nes": ("advsim_ros.core.search.nes.Nes", "advsim_ros.core.search.nes.NesConfig"),
    "bandit": ("advsim_ros.core.search.bandit_td.BanditTd", "advsim_ros.core.search.bandit_td.BanditConfig"),
    "random": (
        "advsim_ros.core.search.random_search.RandomSearch",
        "advsim_ros.core.search.random_search.RandomSearchConfig",
    ),
}


def accept_algorithm(name: str) -> str:
    """The registry name of an algorithm a user named: an old name logs one deprecation warning naming the new one."""
    renamed = RENAMED_ALGORITHMS.get(name)
    if renamed is None:
        return name
    _log.warning("search algorithm %r is deprecated: use %r (the same algorithm)", name, renamed)
    return renamed


def _imported(dotted: str) -> Any:
    module_name, _, attribute = dotted.rpartition(".")
    return getattr(importlib.import_module(module_name), attribute)


def _checked(name: str) -> tuple[str, str]:
    name = accept_algorithm(name)
    if name not in _ENTRIES:
        raise SearchError(f"unknown search algorithm {name!r} (known: {', '.join(ALGORITHM_NAMES)})")
    return _ENTRIES[name]


def _entry(name: str) -> tuple[type[SearchAlgorithm[Any]], type[SearchConfig]]:
    algorithm_path, config_path = _checked(name)
    algorithm: type[SearchAlgorithm[Any]] = _imported(algorithm_path)
    config: type[SearchConfig] = _imported(config_path)
    return algorithm, config


def config_type(name: str) -> type[SearchConfig]:
    """The frozen config dataclass of algorithm `name` (without importing the algorithm's module)."""
    config: type[SearchConfig] = _imported(_checked(name)[1])
    return config


def default_config(name: str) -> SearchConfig:
    """Algorithm `name`'s config with every default (the paper's settings)."""
    return config_type(name)()


def make_search(
    name: str,
    dimension: int,
    rng: np.random.Generator,
    config: SearchConfig | None = None,
) -> SearchAlgorithm[Any]:
    """A fresh search of algorithm `name` over [-1, 1]^dimension; the defaults when config is None."""
    algorithm, expected = _entry(name)
    settings = expected() if config is None else config
    if not isinstance(settings, expected):
        raise SearchError(f"search {name!r} needs a {expected.__name__}, got {type(settings).__name__}")
    return algorithm(settings, dimension, rng)


def config_from_params(name: str, mapping: Mapping[str, Any], context: str = "") -> SearchConfig:
    """Algorithm `name`'s config from a parameters mapping (unknown keys and bad values name the key)."""
    return config_from_mapping(config_type(name), mapping, context or f"search {name}")


@dataclass(frozen=True)
class SearchSettings:
    """What the search node runs: the algorithm, its config and the seed."""

    algorithm: str  # registry name
    config: SearchConfig  # the algorithm's hyper-parameters and budget
    seed: int  # seeds the search's numpy Generator [1]


def load_search_settings(path: Path, algorithm: str | None = None, *, node: str) -> SearchSettings:
    """Read the parameters of node ``node`` (advsim_ros.graph names it) in params/search.yaml; `algorithm`
    overrides the file's choice."""
    context = f"{path} /{node}"
    parameters = renamed_sections(load_node_params(path, node), context)
    name = parameters.get("algorithm") if algorithm is None else algorithm
    name = accept_algorithm(name) if isinstance(name, str) else name
    if not isinstance(name, str) or name not in ALGORITHM_NAMES:
        raise ParamsError(f"{context}.algorithm: {name!r} is not one of {', '.join(ALGORITHM_NAMES)}")
    seed = parameters.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ParamsError(f"{context}.seed: expected a non-negative integer, got {seed!r}")
    node_keys = {f.name for f in fields(DriverConfig)}
    unknown = sorted(set(parameters) - {*node_keys, *ALGORITHM_NAMES})
    if unknown:
        raise ParamsError(f"{context}: unknown parameter(s) {unknown}")
    section = parameters.get(name, {})
    return SearchSettings(name, config_from_params(name, section, f"{context}.{name}"), seed)


def renamed_sections(parameters: Mapping[str, Any], context: str) -> dict[str, Any]:
    """The search node's parameters with an algorithm's section under an old name moved to its new name.

    Each old section found logs one deprecation warning; values under the new name win over the old
    section's."""
    moved = dict(parameters)
    for old, new in RENAMED_ALGORITHMS.items():
        if old in moved:
            _log.warning("%s: the section %r is deprecated: name it %r (the same algorithm)", context, old, new)
            section, newer = moved.pop(old), moved.get(new)
            moved[new] = (
                {**section, **newer}
                if isinstance(section, Mapping) and isinstance(newer, Mapping)
                else (section if newer is None else newer)
            )
    return moved
