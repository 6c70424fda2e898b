"""params/lidar_resim.yaml and ResimConfig validation."""

from __future__ import annotations

from pathlib import Path

import pytest

from advsim_ros import graph
from advsim_ros.core.lidar.config import ResimConfig, load_resim_config
from advsim_ros.core.params import ParamsError
from advsim_ros.core.types import ScenarioError

PARAMS = Path(__file__).resolve().parents[3] / "params" / "lidar_resim.yaml"


def test_the_parameters_file_holds_the_defaults() -> None:
    assert load_resim_config(PARAMS, node=graph.LIDAR_RESIM.name) == ResimConfig()


def test_an_unknown_key_in_the_parameters_file_is_named(tmp_path: Path) -> None:
    path = tmp_path / "lidar_resim.yaml"
    path.write_text("/lidar_resim:\n  ros__parameters:\n    resim:\n      box_margn: 0.1\n")
    with pytest.raises(ParamsError, match="box_margn"):
        load_resim_config(path, node=graph.LIDAR_RESIM.name)


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("background_voxel", 0.0, "background_voxel"),
        ("removal_margin", -0.1, "removal_margin"),
        ("max_drop_probability", 1.5, "max_drop_probability"),
        ("asset_min_points", 0, "asset_min_points"),
        ("mirror_classes", ("truck",), "mirror_classes"),
        ("asset_max_half_size", 0.01, "asset_max_half_size"),
    ],
)
def test_bad_settings_are_refused_naming_the_setting(field: str, value: object, message: str) -> None:
    with pytest.raises(ScenarioError, match=message):
        ResimConfig(**{field: value})  # type: ignore[arg-type]


def test_runtime_settings_do_not_change_the_cached_model_key() -> None:
    assert ResimConfig(snap_to_ground=False, sweep_cache_size=4).model_key() == ResimConfig().model_key()
    assert ResimConfig(background_voxel=0.1).model_key() != ResimConfig().model_key()
