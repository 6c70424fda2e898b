"""The on-disk form of a built re-simulation model: its cache key and its arrays.

The key (``scenario_digest``) hashes everything the model depends on, so a changed log,
configuration or kind of machine (``core.numerics``) builds anew instead of reading a stale
file; ``model_arrays`` and ``model_parts`` turn the model's parts into the named arrays of
one .npz (core.lidar.cache) and back.
"""

from __future__ import annotations

import numpy as np

from advsim_ros.core.digest import Digest
from advsim_ros.core.lidar.assets import ActorAsset
from advsim_ros.core.lidar.background import BackgroundModel
from advsim_ros.core.lidar.config import ResimConfig
from advsim_ros.core.lidar.sensor import BeamRows
from advsim_ros.core.lidar.surfels import SurfelCloud
from advsim_ros.core.numerics import numerics_fingerprint
from advsim_ros.core.types import ActorClass, Scenario, SensorModel

MODEL_VERSION = "resim-model-6"  # bump when the built model's content changes meaning


def scenario_digest(scenario: Scenario, config: ResimConfig) -> str:
    """A hash of everything the built model depends on: sweeps, poses, tracks, settings, the machine's numerics."""
    digest = Digest(MODEL_VERSION)
    digest.text(config.model_key())
    digest.text(numerics_fingerprint())  # another CPU or library version builds other bits: its own file
    digest.array(scenario.frame_stamps_ns)
    for sweep in scenario.sweeps:
        digest.array(np.array([sweep.stamp_ns]))
        digest.array(sweep.sensor_pose)
        digest.text(str(sweep.points.dtype))
        digest.array(
            sweep.points.view(np.uint8).reshape(-1) if sweep.points.flags.c_contiguous else sweep.points.copy()
        )
    for actor in scenario.actors:
        digest.text(f"{actor.actor_id}|{actor.actor_class.value}")
        for array in (actor.size, actor.stamps_ns, actor.centers, actor.yaws):
            digest.array(array)
    return digest.hexdigest()


def model_arrays(
    beam_rows: BeamRows, background: BackgroundModel, assets: dict[str, ActorAsset]
) -> dict[str, np.ndarray]:
    """The model as named arrays, as the cache stores them."""
    arrays = background.to_arrays()
    sensor = beam_rows.sensor
    arrays["sensor/beam_elevations"] = sensor.beam_elevations
    arrays["sensor/limits"] = np.array([sensor.azimuth_resolution, sensor.min_range, sensor.max_range])
    arrays["sensor/source"] = np.array(beam_rows.source)
    arrays["sensor/ring_to_row"] = beam_rows.ring_to_row
    arrays["sensor/beam_heights"] = beam_rows.beam_heights
    arrays["sensor/scan_start"] = np.array(beam_rows.scan_start)
    arrays["assets/ids"] = np.array(list(assets), dtype=str)
    for key, asset in assets.items():
        arrays.update(asset.surfels.to_arrays(f"asset/{key}/"))
        arrays[f"asset/{key}/class"] = np.array(asset.actor_class.value)
        if asset.pass_probability is not None:
            arrays[f"asset/{key}/pass"] = asset.pass_probability
        arrays[f"asset/{key}/numbers"] = np.concatenate(
            [asset.size, [asset.template_intensity, asset.drop_probability, asset.num_points]]
        )
    return arrays


def model_parts(arrays: dict[str, np.ndarray]) -> tuple[BeamRows, BackgroundModel, dict[str, ActorAsset]]:
    """The sensor model, background and assets stored by ``model_arrays``."""
    resolution, min_range, max_range = (float(value) for value in arrays["sensor/limits"])
    sensor = SensorModel(
        beam_elevations=arrays["sensor/beam_elevations"],
        azimuth_resolution=resolution,
        min_range=min_range,
        max_range=max_range,
    )
    beam_rows = BeamRows(
        sensor=sensor,
        source=str(arrays["sensor/source"]),
        ring_to_row=arrays["sensor/ring_to_row"],
        beam_heights=arrays["sensor/beam_heights"],
        scan_start=float(arrays["sensor/scan_start"]),
    )
    assets: dict[str, ActorAsset] = {}
    for key in (str(value) for value in arrays["assets/ids"]):
        numbers = arrays[f"asset/{key}/numbers"]
        assets[key] = ActorAsset(
            actor_id=key,
            actor_class=ActorClass(str(arrays[f"asset/{key}/class"])),
            size=numbers[:3],
            surfels=SurfelCloud.from_arrays(arrays, f"asset/{key}/"),
            template_intensity=float(numbers[3]),
            drop_probability=float(numbers[4]),
            num_points=int(numbers[5]),
            pass_probability=arrays.get(f"asset/{key}/pass"),
        )
    return beam_rows, BackgroundModel.from_arrays(arrays), assets
