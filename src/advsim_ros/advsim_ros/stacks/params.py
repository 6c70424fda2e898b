"""Stack parameters: frozen dataclass configs made of sections, read from params/stack_*.yaml.

A stack's config is a frozen dataclass whose every field is a section (``ground``,
``detector``, ...), itself a frozen dataclass of plain values. In the YAML each section is
a nested mapping under ``ros__parameters``; ROS sees the same keys as dotted names
(``ground.cell_size``), which is how the nodes declare them (advsim_ros.ros.params,
one section at a time). Values go through core.params, so a wrong type or an unknown key
raises ParamsError naming the key, and each section's ``__post_init__`` checks the values.
"""

from __future__ import annotations

import dataclasses
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Any, TypeVar

from advsim_ros.core.params import ParamsError, config_from_mapping, load_node_params

ConfigT = TypeVar("ConfigT")

_REPO_PARAMS_DIR = Path(__file__).resolve().parents[4] / "params"  # the repository's params/ (editable install)


def default_params_file(filename: str) -> Path:
    """params/<filename> of this checkout, else of the installed package's share folder (colcon install)."""
    candidate = _REPO_PARAMS_DIR / filename
    if candidate.is_file():
        return candidate
    try:
        from ament_index_python.packages import PackageNotFoundError, get_package_share_directory
    except ImportError:
        return candidate
    try:
        return Path(get_package_share_directory("advsim_ros")) / "params" / filename
    except PackageNotFoundError:
        return candidate


def section_types(config_type: type[object]) -> dict[str, type[object]]:
    """Section name -> section dataclass of a sectioned config."""
    if not dataclasses.is_dataclass(config_type):
        raise TypeError(f"{config_type} is not a dataclass")
    hints = typing.get_type_hints(config_type)
    sections: dict[str, type[object]] = {}
    for field in dataclasses.fields(config_type):
        annotation = hints[field.name]
        if not (isinstance(annotation, type) and dataclasses.is_dataclass(annotation)):
            raise TypeError(f"{config_type.__name__}.{field.name} is not a section dataclass")
        sections[field.name] = annotation
    return sections


# mapping: the YAML's sections as parsed (untyped like any YAML; core.params checks every value)
def config_from_sections(config_type: type[ConfigT], mapping: Mapping[str, Any], context: str) -> ConfigT:
    """A sectioned config from nested mappings; sections left out keep their defaults."""
    if not isinstance(mapping, Mapping):
        raise ParamsError(f"{context}: expected a mapping of sections, got {mapping!r}")
    sections = section_types(config_type)
    unknown = sorted(str(key) for key in mapping if key not in sections)
    if unknown:
        raise ParamsError(f"{context}: unknown section(s) {unknown} (known: {sorted(sections)})")
    built = {
        name: config_from_mapping(section_type, mapping[name], f"{context}.{name}")
        for name, section_type in sections.items()
        if name in mapping
    }
    return config_type(**built)


def load_stack_config(config_type: type[ConfigT], path: Path, node_name: str) -> ConfigT:
    """The config of node `node_name` from a params YAML in the ROS shape."""
    return config_from_sections(config_type, load_node_params(path, node_name), f"{path} /{node_name}")
