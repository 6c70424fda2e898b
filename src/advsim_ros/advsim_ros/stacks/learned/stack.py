"""The learned stack: the imitation-learning planner run on the BEV raster of the last second of LiDAR."""

from __future__ import annotations

import dataclasses
import io
import os
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from advsim_ros.core.types import FloatArray, Plan, RoadMap
from advsim_ros.stacks.interface import (
    StackError,
    StackFrame,
    StackOutput,
    headings_along,
    plan_stamps,
    transform_points,
    yaw_of,
)
from advsim_ros.stacks.learned.config import LearnedStackConfig
from advsim_ros.stacks.learned.model import BevPlanner
from advsim_ros.stacks.learned.raster import (
    Float32Array,
    SweepHistory,
    motion_features,
    motion_prior,
    rasterize,
    reduce_sweep,
)

WEIGHTS_FORMAT = 1  # bumped when the saved file's layout changes


@dataclass(frozen=True, eq=False)
class PlannerInputs:
    """What the network sees for one sweep."""

    image: Float32Array  # (C, rows, columns) raster
    features: Float32Array  # (F,) motion features
    prior: Float32Array  # (T, 2) motion prior in the ego frame [m]


class InputBuilder:
    """Keeps the reduced sweeps of the last second and builds the network's inputs, sweep by sweep."""

    def __init__(self, config: LearnedStackConfig) -> None:
        self._config = config
        self._history = SweepHistory(config.raster)

    def reset(self) -> None:
        self._history.reset()

    def add(self, frame: StackFrame) -> PlannerInputs:
        config = self._config
        xyz_ego = transform_points(np.asarray(frame.xyz, dtype=np.float32), frame.ego_T_sensor)
        self._history.add(reduce_sweep(frame.stamp_ns, xyz_ego, frame.world_T_ego, config.ground, config.raster))
        sweeps = self._history.newest_first
        return PlannerInputs(
            image=rasterize(sweeps, frame.world_T_ego, config.raster),
            features=motion_features(sweeps, frame.world_T_ego, frame.motion, config.raster.history),
            prior=motion_prior(frame.motion, config.num_steps, config.step_s),
        )


def save_weights(model: BevPlanner, config: LearnedStackConfig, path: Path, metadata: dict[str, object]) -> None:
    """Write the weights (float32 state dict plus the config they fit) atomically."""
    payload = {
        "format": WEIGHTS_FORMAT,
        "raster": dataclasses.asdict(config.raster),
        "model": dataclasses.asdict(config.model),
        "num_steps": config.num_steps,
        "state_dict": {name: tensor.detach().clone() for name, tensor in model.state_dict().items()},
        "metadata": metadata,
    }
    write_payload(payload, path)


def write_payload(payload: dict[str, object], path: Path) -> None:
    """torch.save into memory first (the archive is then named the same whatever the file's name, so the
    same weights give the same bytes), then to a temporary file beside `path`, renamed into place."""
    buffer = io.BytesIO()
    torch.save(payload, buffer)
    path.parent.mkdir(parents=True, exist_ok=True)
    handle, temporary = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(handle, "wb") as stream:
            stream.write(buffer.getvalue())
        os.chmod(temporary, 0o644)  # mkstemp makes it private; weights are shared files
        os.replace(temporary, path)
    finally:
        if os.path.exists(temporary):
            os.unlink(temporary)


def load_model(config: LearnedStackConfig, path: Path | None = None) -> tuple[BevPlanner, dict[str, object]]:
    """The planner with its trained weights; StackError when the file is missing or was made for other inputs."""
    path = path or config.weights_path
    if not path.is_file():
        raise StackError(f"learned stack weights not found: {path} (train them with `advsim train-il --out {path}`)")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except (RuntimeError, OSError, ValueError) as error:
        raise StackError(f"learned stack weights {path} cannot be read: {error}") from error
    if not isinstance(payload, dict) or payload.get("format") != WEIGHTS_FORMAT:
        raise StackError(f"learned stack weights {path}: not a weights file of format {WEIGHTS_FORMAT}")
    for section in ("raster", "model"):
        expected = dataclasses.asdict(getattr(config, section))
        saved = {key: tuple(value) if isinstance(value, list) else value for key, value in payload[section].items()}
        expected = {key: tuple(value) if isinstance(value, list) else value for key, value in expected.items()}
        if saved != expected:
            raise StackError(
                f"learned stack weights {path} were trained with {section} {saved}, the config asks for {expected}"
            )
    if payload["num_steps"] != config.num_steps:
        raise StackError(f"learned stack weights {path} plan {payload['num_steps']} steps, config {config.num_steps}")
    model = BevPlanner(config.raster, config.model, config.num_steps)
    model.load_state_dict(payload["state_dict"])
    model.eval()
    metadata: dict[str, object] = payload.get("metadata", {})  # what train_il recorded (JSON-like values)
    return model, metadata


def ego_plan_to_world(waypoints: FloatArray, world_T_ego: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Ego-frame waypoints (T, 2) as world positions (T, 2) and headings (T,)."""
    world = waypoints @ world_T_ego[:2, :2].T + world_T_ego[:2, 3]
    return world, headings_along(world, world_T_ego[:2, 3], yaw_of(world_T_ego))


class LearnedStack:
    """Stateful learned stack; one step() per sweep. Publishes plans only (no detections)."""

    name = "learned"
    perceives = False  # a plan from the raster, no objects

    def __init__(self, config: LearnedStackConfig | None = None, weights: Path | None = None) -> None:
        self.config = config or LearnedStackConfig()
        self._model, self.metadata = load_model(self.config, weights)
        torch.set_num_threads(self.config.planner.threads)  # a small network: more threads only contend
        self._inputs = InputBuilder(self.config)

    def reset(self) -> None:
        self._inputs.reset()

    def set_road_map(self, road_map: RoadMap | None) -> None:
        """The raster carries the road; the network takes no map."""

    def step(self, frame: StackFrame) -> StackOutput:
        start = time.perf_counter()
        inputs = self._inputs.add(frame)
        mark = time.perf_counter()
        with torch.inference_mode():
            waypoints = self._model(
                torch.from_numpy(inputs.image[None]),
                torch.from_numpy(inputs.features[None]),
                torch.from_numpy(inputs.prior[None]),
            )[0].numpy()
        inference = time.perf_counter() - mark
        xy, yaws = ego_plan_to_world(waypoints.astype(np.float64), frame.world_T_ego)
        stamps = plan_stamps(frame.stamp_ns, self.config.horizon_s, self.config.step_s)
        return StackOutput(
            plan=Plan(stamps_ns=stamps, xy=xy, yaws=yaws),
            plan_z=float(frame.world_T_ego[2, 3]),
            timings_s={"raster": mark - start, "inference": inference, "total": time.perf_counter() - start},
        )
