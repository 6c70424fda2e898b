"""Imitation learning of the BEV planner on the project's own data (`advsim train-il`).

Samples: every frame of a log with a full second of history and a full plan horizon
after it; the input is what the stack would see at that frame, the target the human
(logged) ego positions over the horizon in the ego frame of that frame. Data: synthetic
street logs generated from fixed seeds (io.synthetic) and the early part of a KITTI
tracking sequence (its later frames are held out for evaluation). Everything is seeded
and torch runs deterministic kernels (not oneDNN's) on a fixed number of threads, so the same config
and data give the same weights.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch
from torch import nn

from advsim_ros.core.curation import CurationConfig
from advsim_ros.core.types import Scenario
from advsim_ros.stacks.interface import StackError
from advsim_ros.stacks.learned.config import LearnedStackConfig
from advsim_ros.stacks.learned.dataset import hardest_windows
from advsim_ros.stacks.learned.model import BevPlanner
from advsim_ros.stacks.learned.samples import TrainingData, samples_from_scenario
from advsim_ros.stacks.learned.stack import save_weights


def family_logs(
    config: LearnedStackConfig, seeds: Sequence[int], families: Sequence[str] | None = None
) -> list[Scenario]:
    """The synthetic logs of ``families`` (default ``training.finetune_families``) for each seed.

    Street logs are ``training.synthetic_duration`` long, as standard training reads them; the other families
    have the length campaigns give them (SyntheticConfig's), so that training reads the very logs the
    campaigns of scripts/table2.sh attack.
    """
    from advsim_ros.io.synthetic import SyntheticConfig, generate_synthetic_log, synthetic_name

    logs = []
    for family in config.training.finetune_families if families is None else families:
        synthetic = SyntheticConfig(family=family)
        if family == "street":
            synthetic = replace(synthetic, duration=config.training.synthetic_duration)
        for seed in seeds:
            name = synthetic_name(family, seed)
            logs.append(generate_synthetic_log(np.random.default_rng(seed), synthetic, name).scenario)
    return logs


def training_scenarios(
    config: LearnedStackConfig, kitti_root: Path | None
) -> list[tuple[Scenario, Callable[[int], bool] | None]]:
    """The logs trained on: synthetic logs of ``training.families`` from the training seeds, and KITTI up to the
    last training decision."""
    training = config.training
    scenarios: list[tuple[Scenario, Callable[[int], bool] | None]] = [
        (scenario, None) for scenario in family_logs(config, training.synthetic_seeds, training.families)
    ]
    if kitti_root is not None:
        from advsim_ros.io.kitti import load_kitti_tracking

        last = training.kitti_last_decision
        scenarios.append((load_kitti_tracking(kitti_root, training.kitti_sequence), lambda index: index <= last))
    return scenarios


def validation_data(config: LearnedStackConfig, log: Callable[[str], None] | None = None) -> TrainingData | None:
    """Every sample of the validation logs (``training.finetune_families`` of ``training.validation_seeds``)."""
    parts = []
    for scenario in family_logs(config, config.training.validation_seeds):
        part = samples_from_scenario(scenario, config)
        if log is not None:
            log(f"{scenario.scenario_id}: {part.count} validation samples")
        parts.append(part)
    return TrainingData.concatenate(parts) if parts else None


@dataclass(frozen=True)
class TrainingReport:
    """What a training run did."""

    samples: int  # training samples (before mirroring)
    sources: dict[str, int]  # samples per log
    epochs: int  # passes run
    final_loss: float  # mean smooth-L1 loss of the last pass [m]
    seconds: float  # wall time of data building and training [s]
    parameters: int  # trainable parameters
    weights: str  # where the weights were written
    losses: tuple[float, ...] = field(default=())  # mean loss per pass [m]
    scheme: str = "standard"
    validation_losses: tuple[float, ...] = field(default=())  # fine-tuning: before it, then after each pass [m]
    best_epoch: int | None = None  # fine-tuning: the pass whose weights were kept (lowest validation loss)
    hard_windows: dict[str, float] = field(default_factory=dict)  # curriculum: window -> curation rate


class Fit(NamedTuple):
    """What train_planner returns."""

    model: BevPlanner
    losses: list[float]  # mean training loss of every pass run [m]
    validation_losses: list[float]  # with validation: before training, then after every pass [m]
    best_epoch: int  # the pass whose weights were kept (1-based): with validation the best one, else the last


def _mirror(
    images: torch.Tensor, features: torch.Tensor, priors: torch.Tensor, targets: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Left-right mirrored copies (y -> -y): the raster's rows flip, every y and the yaw rate change sign."""
    sign = torch.ones(features.shape[1])
    sign[1] = -1.0  # yaw rate
    sign[4::2] = -1.0  # past y positions (features are speed, yaw rate, accel, then x, y pairs)
    flip_y = torch.tensor([1.0, -1.0])
    return torch.flip(images, dims=[2]), features * sign, priors * flip_y, targets * flip_y


def validation_loss(model: BevPlanner, data: TrainingData, batch_size: int) -> float:
    """Mean smooth-L1 loss of the model on the samples, unmirrored [m] (no gradients, no random draws)."""
    loss_function = nn.SmoothL1Loss(reduction="sum")
    total = 0.0
    was_training = model.training
    model.eval()
    # training's kernels (no oneDNN, _reproducible_torch): a loss measured here equals the one training measured
    with torch.no_grad(), torch.backends.mkldnn.flags(enabled=False):
        for start in range(0, data.count, batch_size):
            batch = slice(start, start + batch_size)
            planned = model(torch.from_numpy(data.images[batch]).float(), torch.from_numpy(data.features[batch]),
                            torch.from_numpy(data.priors[batch]))  # fmt: skip
            total += float(loss_function(planned, torch.from_numpy(data.targets[batch])))
    model.train(was_training)
    return total / max(data.targets.size, 1)


@contextmanager
def _reproducible_torch(threads: int) -> Iterator[None]:
    """Torch on a fixed number of threads with deterministic kernels, restored afterwards.

    oneDNN's convolutions are left out: on 2 threads they are not deterministic (a short training on
    fixed inputs gave other weights in 1 process of 10); torch's own ones are.
    """
    previous_threads = torch.get_num_threads()
    torch.set_num_threads(threads)
    torch.use_deterministic_algorithms(True)
    try:
        with torch.backends.mkldnn.flags(enabled=False):
            yield
    finally:
        torch.set_num_threads(previous_threads)
        torch.use_deterministic_algorithms(False)


def train_planner(
    data: TrainingData,
    config: LearnedStackConfig,
    log: Callable[[str], None] | None = None,
    initial: BevPlanner | None = None,
    validation: TrainingData | None = None,
) -> Fit:
    """Fit the planner to the samples, from ``initial``'s weights when given (deterministic for given inputs).

    With ``validation``, its loss is measured before the first pass (for reference) and after every
    pass; training stops once ``training.finetune_patience`` passes in a row did not lower it below
    the best pass's, and the best pass's weights are kept (the earliest among equals). Measuring
    draws nothing random, so the passes run are the same with or without it.
    """
    training = config.training
    if config.training.mirror and not np.isclose(config.raster.y_range[0], -config.raster.y_range[1]):
        raise StackError("training mirror: needs a raster y_range symmetric about 0")
    if validation is not None and validation.count == 0:
        raise StackError("training validation: the validation logs gave no samples (shorter than 6 s?)")
    torch.manual_seed(training.seed)
    with _reproducible_torch(training.threads):
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
        validation_losses: list[float] = []
        best_epoch, best_state = 0, None
        if validation is not None:
            validation_losses.append(validation_loss(model, validation, training.batch_size))
            if log is not None:
                log(f"before training: validation loss {validation_losses[0]:.4f}")
        model.train()
        for epoch in range(1, training.epochs + 1):
            order = rng.permutation(data.count)
            total, batches = 0.0, 0
            for start in range(0, data.count, training.batch_size):
                pick = torch.from_numpy(order[start : start + training.batch_size])
                batch = (images[pick].float(), features[pick], priors[pick], targets[pick])
                if training.mirror:
                    mirrored = _mirror(*batch)
                    batch = tuple(  # type: ignore[assignment]  # the same four tensors, each doubled
                        torch.cat([a, b]) for a, b in zip(batch, mirrored, strict=True)
                    )
                optimiser.zero_grad()
                loss = loss_function(model(batch[0], batch[1], batch[2]), batch[3])
                loss.backward()
                optimiser.step()
                total += float(loss.detach())
                batches += 1
            losses.append(total / max(batches, 1))
            message = f"epoch {epoch}/{training.epochs}: loss {losses[-1]:.4f}"
            if validation is None:
                best_epoch = epoch
            else:
                validation_losses.append(validation_loss(model, validation, training.batch_size))
                message += f", validation loss {validation_losses[-1]:.4f}"
                if best_state is None or validation_losses[-1] < validation_losses[best_epoch]:
                    best_epoch, best_state = epoch, _copy_state(model)
            if log is not None:
                log(message)
            if validation is not None and epoch - best_epoch >= training.finetune_patience:
                if log is not None:
                    log(f"early stop: no better validation loss for {training.finetune_patience} passes")
                break
        if best_state is not None:
            model.load_state_dict(best_state)
            if log is not None:
                log(f"kept the weights of pass {best_epoch} (validation loss {validation_losses[best_epoch]:.4f})")
        model.eval()
        return Fit(model, losses, validation_losses, best_epoch)


def _copy_state(model: BevPlanner) -> dict[str, torch.Tensor]:
    return {name: tensor.detach().clone() for name, tensor in model.state_dict().items()}


SCHEMES = ("standard", "curriculum", "robust")


def fine_tune(
    config: LearnedStackConfig,
    parts: Sequence[TrainingData],
    extra: Sequence[TrainingData],
    log: Callable[[str], None] | None = None,
    extra_validation: Sequence[TrainingData] = (),
) -> tuple[LearnedStackConfig, TrainingData, Fit]:
    """Fine-tune the configured weights on the logs' samples plus ``extra``, each repeated ``finetune_repeat`` times.

    The shared path of curriculum and robust training: ``finetune_epochs`` passes at most, at
    ``finetune_learning_rate``, early stopping on the validation logs (``validation_data``) plus
    ``extra_validation`` (robust training: found scenarios of the validation split, so that the
    pass kept is the one that imitates best on held-out adversarial scenes too).
    Returns the config the passes ran with, the samples and the fit.
    """
    from advsim_ros.stacks.learned.stack import load_model

    training = config.training
    initial, _ = load_model(config)
    tuned = replace(config, training=replace(training, epochs=training.finetune_epochs,
                                             learning_rate=training.finetune_learning_rate))  # fmt: skip
    data = TrainingData.concatenate([*parts, *list(extra) * training.finetune_repeat])
    validation = validation_data(config, log)
    if extra_validation:
        validation = TrainingData.concatenate([*([validation] if validation is not None else []), *extra_validation])
        if log is not None:
            log(f"validation: {validation.count} samples, {sum(p.count for p in extra_validation)} of them found")
    return tuned, data, train_planner(data, tuned, log, initial, validation)


def train_il(
    config: LearnedStackConfig,
    kitti_root: Path | None,
    out: Path,
    log: Callable[[str], None] | None = None,
    scheme: str = "standard",
    adversarial: Sequence[TrainingData] = (),
    curation: CurationConfig | None = None,
    adversarial_validation: Sequence[TrainingData] = (),
) -> TrainingReport:
    """Build the data, train, write the weights to `out` atomically; the report says what happened.

    ``standard`` trains from scratch on the logs. ``curriculum`` and ``robust`` (AdvSim's baselines,
    Sec. 4.4) fine-tune the configured weights (``planner.weights``, default the packaged standard
    ones) on the same logs mixed with extra samples, each repeated ``training.finetune_repeat``
    times so that a few scenarios weigh against hundreds of logged frames (``fine_tune``): for
    ``curriculum`` the hardest ``training.curriculum_fraction`` of the logs' train-split windows by
    curation rate (``dataset.hardest_windows``, with ``curation``, default CurationConfig()), for
    ``robust`` the adversarial samples (``adversarial``: train-split shards of `advsim export
    training`); ``adversarial_validation`` (validation-split shards) joins the validation logs in
    early stopping.
    """
    if scheme not in SCHEMES:
        raise StackError(f"training scheme: expected one of {', '.join(SCHEMES)}, got {scheme!r}")
    if scheme == "robust" and not adversarial:
        raise StackError("robust training needs adversarial samples (`advsim export training`, split 'train')")
    if scheme != "robust" and (adversarial or adversarial_validation):
        raise StackError(f"{scheme} training takes no adversarial samples (they are for --scheme robust)")
    start = time.perf_counter()
    scenarios = training_scenarios(config, kitti_root)
    parts = []
    for scenario, keep in scenarios:
        part = samples_from_scenario(scenario, config, keep)
        if log is not None:
            log(f"{scenario.scenario_id}: {part.count} samples")
        parts.append(part)
    hard: dict[str, float] = {}
    if scheme == "standard":
        data = TrainingData.concatenate(parts)
        fit = train_planner(data, config, log)
    else:
        extra = list(adversarial)
        if scheme == "curriculum":
            training = config.training
            unread = [family for family in training.finetune_families if family not in training.families]
            candidates = [scenario for scenario, _ in scenarios] + family_logs(config, training.synthetic_seeds, unread)
            windows = hardest_windows(candidates, config, curation or CurationConfig())
            hard = {window.name: window.window.collision_rate for window in windows}
            if log is not None:
                log("hardest train windows (curation rate): " + ", ".join(f"{k} {v:.3f}" for k, v in hard.items()))
            extra = [window.samples(config) for window in windows]
        config, data, fit = fine_tune(config, parts, extra, log, adversarial_validation)
    losses = fit.losses
    sources: dict[str, int] = {}
    for source in data.sources:
        scenario_id = source.rsplit("@", 1)[0]
        sources[scenario_id] = sources.get(scenario_id, 0) + 1
    fine_tuned = scheme != "standard"
    metadata: dict[str, object] = {
        "samples": data.count,
        "sources": sources,
        "epochs": len(losses),
        "seed": config.training.seed,
        "final_loss": losses[-1],
        "kitti_last_decision": config.training.kitti_last_decision if kitti_root is not None else None,
        "scheme": scheme,
        "adversarial_samples": sum(part.count for part in adversarial),
        "adversarial_validation_samples": sum(part.count for part in adversarial_validation),
    }
    if fine_tuned:
        metadata |= {"hard_windows": hard, "validation_seeds": list(config.training.validation_seeds),
                     "validation_losses": fit.validation_losses, "best_epoch": fit.best_epoch}  # fmt: skip
    save_weights(fit.model, config, out, metadata)
    return TrainingReport(
        samples=data.count,
        sources=sources,
        epochs=len(losses),
        final_loss=losses[-1],
        seconds=time.perf_counter() - start,
        parameters=sum(parameter.numel() for parameter in fit.model.parameters()),
        weights=str(out),
        losses=tuple(losses),
        scheme=scheme,
        validation_losses=tuple(fit.validation_losses),
        best_epoch=fit.best_epoch if fine_tuned else None,
        hard_windows=hard,
    )
