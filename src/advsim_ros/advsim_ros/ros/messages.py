"""Generic ROS message <-> plain Python conversion (rosidl_runtime_py is not available as a wheel).

Used for summaries, logs and tests: a message becomes nested dicts/lists of builtins that JSON
can hold, and such a dict becomes a message again, field by field, through rosidl introspection.
"""

from __future__ import annotations

import array
import dataclasses
import importlib
from collections.abc import Mapping
from typing import Any, TypeAlias

import numpy as np
from rosidl_parser.definition import AbstractNestedType, NamespacedType

from advsim_ros.contract.codec import Msg

# What message_to_dict makes of a message: builtins JSON can hold
Builtin: TypeAlias = bool | int | float | str | list["Builtin"] | dict[str, "Builtin"] | None


def message_class(type_name: str) -> type[Msg]:
    """The message class for 'pkg/msg/Name' or 'pkg/Name'."""
    parts = type_name.split("/")
    if len(parts) == 2:
        parts = [parts[0], "msg", parts[1]]
    if len(parts) != 3 or not all(parts):
        raise ValueError(f"not a message type name: {type_name!r} (expected pkg/msg/Name)")
    package, kind, name = parts
    try:
        module = importlib.import_module(f"{package}.{kind}")
        message_type: type[Msg] = getattr(module, name)
        return message_type
    except (ImportError, AttributeError) as error:
        raise ValueError(f"unknown message type {type_name!r}: {error}") from error


def _field_names(message: Msg) -> list[str]:
    """Field names of an rclpy message or of a rosbags message dataclass (constants left out)."""
    if hasattr(message, "get_fields_and_field_types"):
        return list(message.get_fields_and_field_types())
    # ROS field names are lower case; upper-case names are constants, dunder names rosbags metadata
    return [f.name for f in dataclasses.fields(message) if not f.name.startswith("__") and not f.name.isupper()]


def _is_message(value: object) -> bool:
    return hasattr(value, "get_fields_and_field_types") or (
        dataclasses.is_dataclass(value) and hasattr(value, "__msgtype__")
    )


def message_to_dict(message: Msg) -> dict[str, Builtin]:
    """A message (rclpy or rosbags) as nested dicts and lists of builtins, in field order."""
    return {name: _value_to_builtin(getattr(message, name)) for name in _field_names(message)}


def _value_to_builtin(value: Msg) -> Builtin:  # a field's value: message, array or scalar
    if _is_message(value):
        return message_to_dict(value)
    if isinstance(value, (list, tuple, array.array, np.ndarray)):
        return [_value_to_builtin(item) for item in value]
    scalar: Builtin  # numpy's item() and a message's scalar fields are untyped
    if isinstance(value, np.generic):
        scalar = value.item()
        return scalar
    if isinstance(value, bytes):
        return list(value)
    scalar = value
    return scalar


def dict_to_message(message_type: type[Msg], values: Mapping[str, Builtin]) -> Msg:
    """Build a message of `message_type` from a dict as produced by message_to_dict (missing keys keep defaults)."""
    message = message_type()
    fields = message_type.get_fields_and_field_types()
    unknown = set(values) - set(fields)
    if unknown:
        raise ValueError(f"{message_type.__name__} has no fields {sorted(unknown)}")
    for slot_type, name in zip(message_type.SLOT_TYPES, fields, strict=True):
        if name in values:
            setattr(message, name, _builtin_to_value(slot_type, values[name]))
    return message


# slot_type: rosidl_parser's description of the field (an untyped package); value: the field's as message_to_dict
# wrote it, read back by that description (a dict for a message, a list for an array)
def _builtin_to_value(slot_type: Any, value: Any) -> Msg:
    if isinstance(slot_type, NamespacedType):
        return dict_to_message(message_class("/".join([*slot_type.namespaces, slot_type.name])), value)
    if isinstance(slot_type, AbstractNestedType):
        item_type = slot_type.value_type
        if isinstance(item_type, NamespacedType):
            return [_builtin_to_value(item_type, item) for item in value]
        return list(value)
    return value
