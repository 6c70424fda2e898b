"""Parameters files in the ROS shape, loaded into frozen dataclass configs.

A parameters file looks like ``/<node_name>:\\n  ros__parameters:\\n    key: value`` (nested
mappings allowed, as ROS 2 reads them into dotted names). This module only reads YAML and
checks types; each config's own ``__post_init__`` checks the values.
"""

from __future__ import annotations

import dataclasses
import types
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Any, TypeVar

import yaml

from advsim_ros.core.types import ScenarioError


class ParamsError(ScenarioError):
    """A parameters file or mapping that does not fit its config; the message names the key."""


ConfigT = TypeVar("ConfigT")


def load_node_params(path: Path, node_name: str) -> dict[str, Any]:
    """The ``ros__parameters`` mapping of ``/<node_name>`` (or ``<node_name>``) in a YAML file."""
    try:
        document = yaml.safe_load(path.read_text(encoding="utf-8"))
    except OSError as error:
        raise ParamsError(f"{path}: cannot read parameters file ({error})") from error
    except yaml.YAMLError as error:
        raise ParamsError(f"{path}: not valid YAML ({yaml_problem(error)})") from error
    if not isinstance(document, dict):
        raise ParamsError(f"{path}: expected a mapping of node names at the top level")
    node = document.get(f"/{node_name}", document.get(node_name))
    if node is None:
        raise ParamsError(f"{path}: no entry for node /{node_name} (has {sorted(map(str, document))})")
    if not isinstance(node, dict) or not isinstance(node.get("ros__parameters"), dict):
        raise ParamsError(f"{path}: /{node_name} must hold a 'ros__parameters' mapping")
    parameters: dict[str, Any] = node["ros__parameters"]
    return parameters


def yaml_problem(error: yaml.YAMLError) -> str:
    """A YAML error in one line: the problem and where (PyYAML's own message spans several, with a caret)."""
    problem, mark = getattr(error, "problem", None), getattr(error, "problem_mark", None)
    if problem and mark is not None:
        return f"{problem} at line {mark.line + 1}, column {mark.column + 1}"
    return " ".join(str(error).split())


def _coerce(value: Any, annotation: Any, key: str) -> Any:
    """value converted to the field type `annotation`, or ParamsError naming `key`."""
    origin = typing.get_origin(annotation)
    if origin in (typing.Union, types.UnionType):
        options = typing.get_args(annotation)
        if value is None and type(None) in options:
            return None
        present = [option for option in options if option is not type(None)]
        if len(present) == 1:  # Optional[X]: X's own message says what is wrong
            return _coerce(value, present[0], key)
        for option in options:
            if option is type(None):
                continue
            try:
                return _coerce(value, option, key)
            except ParamsError:
                continue
        raise ParamsError(f"{key}: {value!r} does not fit {annotation}")
    if origin is tuple:
        arguments = typing.get_args(annotation)
        if not isinstance(value, list | tuple):
            raise ParamsError(f"{key}: expected a list, got {value!r}")
        if arguments and arguments[-1] is not Ellipsis and len(arguments) != len(value):
            raise ParamsError(f"{key}: expected {len(arguments)} entries, got {len(value)}")
        item_type = arguments[0] if arguments else Any
        return tuple(_coerce(item, item_type, f"{key}[{index}]") for index, item in enumerate(value))
    if annotation is Any:
        return value
    if origin is dict:  # dict[str, V]: a mapping with string keys
        key_type, value_type = typing.get_args(annotation)
        if not isinstance(value, Mapping):
            raise ParamsError(f"{key}: expected a mapping, got {value!r}")
        return {
            _coerce(item_key, key_type, key): _coerce(item, value_type, f"{key}.{item_key}")
            for item_key, item in value.items()
        }
    if dataclasses.is_dataclass(annotation):  # a nested section
        return config_from_mapping(typing.cast(type[Any], annotation), value, key)
    if annotation is bool:
        if not isinstance(value, bool):
            raise ParamsError(f"{key}: expected true or false, got {value!r}")
        return value
    if annotation is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ParamsError(f"{key}: expected an integer, got {value!r}")
        return value
    if annotation is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ParamsError(f"{key}: expected a number, got {value!r}")
        return float(value)
    if annotation is str:
        if not isinstance(value, str):
            raise ParamsError(f"{key}: expected a string, got {value!r}")
        return value
    raise ParamsError(f"{key}: unsupported parameter type {annotation}")


def config_from_mapping(config_type: type[ConfigT], mapping: Mapping[str, Any], context: str) -> ConfigT:
    """A frozen dataclass config from a mapping; unknown keys and wrong types name the key.

    Keys left out keep the dataclass defaults. `context` prefixes every message (for
    example ``params/search.yaml /search bo``).
    """
    if not dataclasses.is_dataclass(config_type):
        raise TypeError(f"{config_type} is not a dataclass")
    if not isinstance(mapping, Mapping):
        raise ParamsError(f"{context}: expected a mapping of parameters, got {mapping!r}")
    hints = typing.get_type_hints(config_type)
    known = {field.name for field in dataclasses.fields(config_type) if field.init}
    unknown = sorted(str(key) for key in mapping if key not in known)
    if unknown:
        raise ParamsError(f"{context}: unknown parameter(s) {unknown} (known: {sorted(known)})")
    arguments = {key: _coerce(value, hints[key], f"{context}.{key}") for key, value in mapping.items()}
    try:
        return config_type(**arguments)
    except ScenarioError as error:
        raise ParamsError(f"{context}: {error}") from error
