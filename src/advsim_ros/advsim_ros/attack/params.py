"""The graph's parameters as each node will see them, read in the orchestrator before anything starts.

Every node gets params/bag.yaml (``/**``), its own params/<node>.yaml and the attack's
overrides file, in that order, as ``--params-file`` arguments; ``node_parameters`` merges the
same files the same way, so the orchestrator can check them, fingerprint them and use the
settings it needs itself (window, re-simulation, drivable area) without a second source.
"""

from __future__ import annotations

import copy
import dataclasses
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, TypeVar

import yaml

from advsim_ros.core.params import ParamsError, config_from_mapping

ConfigT = TypeVar("ConfigT")
SHARED_FILES = ("bag.yaml", "drivable.yaml")  # parameter files every node gets (their entries are under /**)


def merge_parameters(into: dict[str, Any], values: Mapping[str, Any]) -> None:
    """Nested parameters of ``values`` into ``into``, key by key (a nested mapping adds to, not replaces, its own)."""
    for key, value in values.items():
        if isinstance(value, Mapping) and isinstance(into.get(key), dict):
            merge_parameters(into[key], value)
        else:
            into[key] = copy.deepcopy(value)


def _load(path: Path) -> dict[str, Any]:
    try:
        document = yaml.safe_load(path.read_text(encoding="utf-8")) or {}
    except (OSError, yaml.YAMLError) as error:
        raise ParamsError(f"{path}: cannot read parameters ({error})") from None
    if not isinstance(document, dict):
        raise ParamsError(f"{path}: expected a mapping of node names at the top level")
    return document


def node_files(params_dir: Path, node: str) -> tuple[Path, ...]:
    """The project's parameter files a node gets (the attack's overrides come after them)."""
    files = [params_dir / name for name in SHARED_FILES] + [params_dir / f"{node}.yaml"]
    return tuple(f for f in files if f.exists())


def node_parameters(files: Sequence[Path], node: str, overrides: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The ros__parameters a node named ``node`` gets from these files, then ``overrides`` (a document of the
    same shape): ``/**`` entries first, then ``/<node>``, later ones winning."""
    merged: dict[str, Any] = {}
    documents = [_load(path) for path in files] + ([dict(overrides)] if overrides is not None else [])
    for document in documents:
        for key in ("/**", "**", f"/{node}", node):
            entry = document.get(key)
            if isinstance(entry, Mapping) and isinstance(entry.get("ros__parameters"), Mapping):
                merge_parameters(merged, entry["ros__parameters"])
    return merged


def section(parameters: Mapping[str, Any], key: str, config_type: type[ConfigT], context: str) -> ConfigT:
    """A config from one section of a node's parameters (``key`` "" for the top level's own fields)."""
    values = parameters.get(key, {}) if key else parameters
    if not isinstance(values, Mapping):
        raise ParamsError(f"{context} {key}: expected a mapping")
    if not key:
        known = {f.name for f in dataclasses.fields(config_type)}  # type: ignore[arg-type]
        values = {k: v for k, v in values.items() if k in known}
    return config_from_mapping(config_type, values, f"{context} {key}".strip())
