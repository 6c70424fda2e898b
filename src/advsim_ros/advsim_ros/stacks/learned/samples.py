"""Training samples of the BEV planner: what the stack would see at a frame, and where the human drove after it.

Every frame of a log with a full second of history and a full plan horizon after it is a sample;
its input is built by the stack's own InputBuilder (the same raster, features and motion prior the
stack computes when it runs), its target the logged ego positions over the horizon in the ego frame
of that frame. Training (stacks.learned.train) and the exported training shards (stacks.learned.dataset)
both make their samples here.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from advsim_ros.core.types import FloatArray, Scenario
from advsim_ros.stacks.interface import StackError
from advsim_ros.stacks.learned.config import LearnedStackConfig
from advsim_ros.stacks.learned.stack import InputBuilder
from advsim_ros.stacks.replay import scenario_frames


@dataclass(frozen=True, eq=False)
class TrainingData:
    """Stacked samples."""

    images: np.ndarray  # (N, C, rows, columns) bool occupancy
    features: np.ndarray  # (N, F) float32
    priors: np.ndarray  # (N, T, 2) float32 motion prior [m]
    targets: np.ndarray  # (N, T, 2) float32 human positions in the ego frame [m]
    sources: tuple[str, ...]  # (N,) "<scenario id>@<frame>"

    @property
    def count(self) -> int:
        return int(self.images.shape[0])

    @staticmethod
    def concatenate(parts: Sequence[TrainingData]) -> TrainingData:
        if not parts:
            raise StackError("no training samples: every log was shorter than 1 s of history plus the horizon")
        return TrainingData(
            images=np.concatenate([part.images for part in parts]),
            features=np.concatenate([part.features for part in parts]),
            priors=np.concatenate([part.priors for part in parts]),
            targets=np.concatenate([part.targets for part in parts]),
            sources=tuple(source for part in parts for source in part.sources),
        )


def human_future(scenario: Scenario, index: int, num_steps: int) -> FloatArray:
    """(num_steps, 2) logged ego positions after frame `index`, in the ego frame of that frame [m]."""
    ego_T_world = np.linalg.inv(scenario.ego.poses[index])
    future = scenario.ego.poses[index + 1 : index + 1 + num_steps, :2, 3]
    result: FloatArray = future @ ego_T_world[:2, :2].T + ego_T_world[:2, 3]
    return result


def samples_from_scenario(
    scenario: Scenario, config: LearnedStackConfig, keep: Callable[[int], bool] | None = None
) -> TrainingData:
    """A sample at every frame with a full history and horizon (and, if given, keep(frame) true)."""
    builder = InputBuilder(config)
    history, steps = config.raster.history, config.num_steps
    images, features, priors, targets, sources = [], [], [], [], []
    for index, frame in scenario_frames(scenario):
        inputs = builder.add(frame)
        if index < history - 1 or index + steps >= scenario.num_frames or (keep is not None and not keep(index)):
            continue
        images.append(inputs.image.astype(bool))
        features.append(inputs.features)
        priors.append(inputs.prior)
        targets.append(human_future(scenario, index, steps).astype(np.float32))
        sources.append(f"{scenario.scenario_id}@{index}")
    if not images:
        rows, columns = config.raster.shape
        return TrainingData(
            np.zeros((0, config.raster.num_channels, rows, columns), bool),
            np.zeros((0, 3 + 2 * history), np.float32),
            np.zeros((0, steps, 2), np.float32),
            np.zeros((0, steps, 2), np.float32),
            (),
        )
    return TrainingData(np.stack(images), np.stack(features), np.stack(priors), np.stack(targets), tuple(sources))
