"""Imitation learning of the BEV planner on the project's own data (`advsim train-il`).

Samples: every frame of a log with a full second of history and a full plan horizon
after it; the input is what the stack would see at that frame, the target the human
(logged) ego positions over the horizon in the ego frame of that frame. Data: synthetic
street logs generated from fixed seeds (io.synthetic) and the early part of a KITTI
tracking sequence (its later frames are held out for evaluation). Everything is seeded
and torch runs deterministic kernels on a fixed number of threads, so the same config
and data give the same weights.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from advsim_ros.core.types import FloatArray, Scenario
from advsim_ros.stacks.interface import StackError
from advsim_ros.stacks.learned.config import LearnedStackConfig
from advsim_ros.stacks.learned.model import BevPlanner
from advsim_ros.stacks.learned.stack import InputBuilder, save_weights
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


def training_scenarios(
    config: LearnedStackConfig, kitti_root: Path | None
) -> list[tuple[Scenario, Callable[[int], bool] | None]]:
    """The logs trained on: synthetic logs from the configured seeds, and KITTI up to the last training decision."""
    from advsim_ros.io.synthetic import SyntheticConfig, generate_synthetic_log

    training = config.training
    scenarios: list[tuple[Scenario, Callable[[int], bool] | None]] = []
    for seed in training.synthetic_seeds:
        log = generate_synthetic_log(
            np.random.default_rng(seed), SyntheticConfig(duration=training.synthetic_duration), f"synthetic_{seed}"
        )
        scenarios.append((log.scenario, None))
    if kitti_root is not None:
        from advsim_ros.io.kitti import load_kitti_tracking

        last = training.kitti_last_decision
        scenarios.append((load_kitti_tracking(kitti_root, training.kitti_sequence), lambda index: index <= last))
    return scenarios


@dataclass(frozen=True)
class TrainingReport:
    """What a training run did."""

    samples: int  # training samples (before mirroring)
    sources: dict[str, int]  # samples per log
    epochs: int
    final_loss: float  # mean smooth-L1 loss of the last epoch [m]
    seconds: float  # wall time of data building and training [s]
    parameters: int  # trainable parameters
    weights: str  # where the weights were written
    losses: tuple[float, ...] = field(default=())  # mean loss per epoch [m]


def _mirror(
    images: torch.Tensor, features: torch.Tensor, priors: torch.Tensor, targets: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Left-right mirrored copies (y -> -y): the raster's rows flip, every y and the yaw rate change sign."""
    sign = torch.ones(features.shape[1])
    sign[1] = -1.0  # yaw rate
    sign[4::2] = -1.0  # past y positions (features are speed, yaw rate, accel, then x, y pairs)
    flip_y = torch.tensor([1.0, -1.0])
    return torch.flip(images, dims=[2]), features * sign, priors * flip_y, targets * flip_y


def train_planner(
    data: TrainingData,
    config: LearnedStackConfig,
    log: Callable[[str], None] | None = None,
    initial: BevPlanner | None = None,
) -> tuple[BevPlanner, list[float]]:
    """Fit the planner to the samples, from ``initial``'s weights when given (deterministic for given inputs)."""
    training = config.training
    if config.training.mirror and not np.isclose(config.raster.y_range[0], -config.raster.y_range[1]):
        raise StackError("training mirror: needs a raster y_range symmetric about 0")
    torch.manual_seed(training.seed)
    torch.use_deterministic_algorithms(True)
    previous_threads = torch.get_num_threads()
    torch.set_num_threads(training.threads)
    try:
        model = BevPlanner(config.raster, config.model, config.num_steps)
        if initial is not None:  # fine-tuning: start from the given weights, not from a fresh draw
            model.load_state_dict(initial.state_dict())
        optimiser = torch.optim.Adam(model.parameters(), lr=training.learning_rate, weight_decay=training.weight_decay)
        loss_function = nn.SmoothL1Loss()
        rng = np.random.default_rng(training.seed)
        images = torch.from_numpy(data.images)
        features = torch.from_numpy(data.features)
        priors = torch.from_numpy(data.priors)
        targets = torch.from_numpy(data.targets)
        losses: list[float] = []
        model.train()
        for epoch in range(training.epochs):
            order = rng.permutation(data.count)
            total, batches = 0.0, 0
            for start in range(0, data.count, training.batch_size):
                pick = torch.from_numpy(order[start : start + training.batch_size])
                batch = (images[pick].float(), features[pick], priors[pick], targets[pick])
                if training.mirror:
                    mirrored = _mirror(*batch)
                    batch = tuple(torch.cat([a, b]) for a, b in zip(batch, mirrored, strict=True))  # type: ignore[assignment]
                optimiser.zero_grad()
                loss = loss_function(model(batch[0], batch[1], batch[2]), batch[3])
                loss.backward()
                optimiser.step()
                total += float(loss.detach())
                batches += 1
            losses.append(total / max(batches, 1))
            if log is not None:
                log(f"epoch {epoch + 1}/{training.epochs}: loss {losses[-1]:.4f}")
        model.eval()
        return model, losses
    finally:
        torch.set_num_threads(previous_threads)
        torch.use_deterministic_algorithms(False)


SCHEMES = ("standard", "robust")


def train_il(
    config: LearnedStackConfig,
    kitti_root: Path | None,
    out: Path,
    log: Callable[[str], None] | None = None,
    scheme: str = "standard",
    adversarial: Sequence[TrainingData] = (),
) -> TrainingReport:
    """Build the data, train, write the weights to `out` atomically; the report says what happened.

    ``standard`` trains from scratch on the logs. ``robust`` (AdvSim's robust training) fine-tunes
    the configured weights (``planner.weights``, default the packaged ones) for
    ``training.finetune_epochs`` at ``training.finetune_learning_rate`` on the same logs mixed with
    the adversarial samples (``adversarial``: training-split shards of `advsim export training`),
    each adversarial sample repeated ``training.adversarial_repeat`` times so that a few found
    scenarios weigh against hundreds of logged frames.
    """
    if scheme not in SCHEMES:
        raise StackError(f"training scheme: expected one of {', '.join(SCHEMES)}, got {scheme!r}")
    if scheme == "robust" and not adversarial:
        raise StackError("robust training needs adversarial samples (`advsim export training`, split 'train')")
    start = time.perf_counter()
    parts = []
    for scenario, keep in training_scenarios(config, kitti_root):
        part = samples_from_scenario(scenario, config, keep)
        if log is not None:
            log(f"{scenario.scenario_id}: {part.count} samples")
        parts.append(part)
    initial = None
    if scheme == "robust":
        from advsim_ros.stacks.learned.stack import load_model

        initial, _ = load_model(config)
        parts.extend(list(adversarial) * config.training.adversarial_repeat)
        training = config.training
        config = replace(config, training=replace(training, epochs=training.finetune_epochs,
                                                  learning_rate=training.finetune_learning_rate))  # fmt: skip
    data = TrainingData.concatenate(parts)
    model, losses = train_planner(data, config, log, initial)
    sources: dict[str, int] = {}
    for source in data.sources:
        scenario_id = source.rsplit("@", 1)[0]
        sources[scenario_id] = sources.get(scenario_id, 0) + 1
    metadata: dict[str, Any] = {
        "samples": data.count,
        "sources": sources,
        "epochs": config.training.epochs,
        "seed": config.training.seed,
        "final_loss": losses[-1],
        "kitti_last_decision": config.training.kitti_last_decision if kitti_root is not None else None,
        "scheme": scheme,
        "adversarial_samples": sum(part.count for part in adversarial),
    }
    save_weights(model, config, out, metadata)
    return TrainingReport(
        samples=data.count,
        sources=sources,
        epochs=config.training.epochs,
        final_loss=losses[-1],
        seconds=time.perf_counter() - start,
        parameters=sum(parameter.numel() for parameter in model.parameters()),
        weights=str(out),
        losses=tuple(losses),
    )
