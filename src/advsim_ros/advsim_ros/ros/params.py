"""ROS parameters <-> the core's frozen dataclass configs.

A node declares one ROS parameter per field of its config (nested under a prefix such as
``bag.``), with the dataclass default, so `--params-file params/<node>.yaml` and `-p key:=value`
set them as usual; the values are then validated by the same `config_from_mapping` the
ROS-free code uses, so a bad value is reported with the key that holds it.
"""

from __future__ import annotations

import array
import dataclasses
import typing
from typing import TypeVar

from rcl_interfaces.msg import ParameterDescriptor, ParameterType
from rclpy.node import Node

from advsim_ros.core.params import config_from_mapping

ConfigT = TypeVar("ConfigT")

# ROS parameter types (rcl_interfaces' ParameterType constants) by the config field's Python type
_SCALAR_TYPES: dict[object, int] = {
    bool: ParameterType.PARAMETER_BOOL,
    int: ParameterType.PARAMETER_INTEGER,
    float: ParameterType.PARAMETER_DOUBLE,
    str: ParameterType.PARAMETER_STRING,
}
_ARRAY_TYPES: dict[object, int] = {
    bool: ParameterType.PARAMETER_BOOL_ARRAY,
    int: ParameterType.PARAMETER_INTEGER_ARRAY,
    float: ParameterType.PARAMETER_DOUBLE_ARRAY,
    str: ParameterType.PARAMETER_STRING_ARRAY,
}


def _parameter_type(annotation: object, name: str) -> int:
    if annotation in _SCALAR_TYPES:
        return _SCALAR_TYPES[annotation]
    if typing.get_origin(annotation) is tuple:
        arguments = [arg for arg in typing.get_args(annotation) if arg is not Ellipsis]
        if arguments and arguments[0] in _ARRAY_TYPES:
            return _ARRAY_TYPES[arguments[0]]
    raise TypeError(f"config field {name}: type {annotation} has no ROS parameter type")


def declare_parameters(node: Node, config_type: type[object], prefix: str = "") -> dict[str, object]:
    """Declare every field of `config_type` as parameter `<prefix><field>`; return their values by field name."""
    if not dataclasses.is_dataclass(config_type):
        raise TypeError(f"{config_type} is not a dataclass")
    hints = typing.get_type_hints(config_type)
    values: dict[str, object] = {}
    for field in dataclasses.fields(config_type):
        if not field.init:
            continue
        name = f"{prefix}{field.name}"
        kind = _parameter_type(hints[field.name], name)
        if field.default is not dataclasses.MISSING:
            default = field.default
        elif field.default_factory is not dataclasses.MISSING:
            default = field.default_factory()
        else:
            raise TypeError(f"config field {name} has no default")
        if isinstance(default, tuple):
            default = list(default)
        descriptor = ParameterDescriptor(name=name, type=kind, dynamic_typing=not default and isinstance(default, list))
        if kind == ParameterType.PARAMETER_DOUBLE and isinstance(default, int):
            default = float(default)
        value = node.declare_parameter(name, default, descriptor).value
        # array parameters come back as array.array or list; the configs take tuples of builtins
        values[field.name] = list(value) if isinstance(value, (list, tuple, array.array)) else value
    return values


def declare_config(node: Node, config_type: type[ConfigT], prefix: str = "") -> ConfigT:
    """Declare every field of `config_type` as parameter `<prefix><field>` and build the config from them."""
    values = declare_parameters(node, config_type, prefix)
    return config_from_mapping(config_type, values, f"/{node.get_name()} {prefix or ''}".rstrip())
