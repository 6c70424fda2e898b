"""Training data from found scenarios (`advsim export training`) and the split that keeps evaluation honest.

A campaign's regression suite holds the adversarial scenario of every failure it found (a
scenario bag each: the sweeps the stack saw, re-simulated, and the human's logged
trajectory). AdvSim's robust training (Wang et al., CVPR 2021, Sec. 4.4) trains on such
scenarios with the human trajectory as target: perturbations never touch it, so it stays a
valid target. Each scenario becomes samples through the learned stack's own input code
(``samples_from_scenario``: the same raster, features and motion prior the stack computes
when it drives), written as one compressed ``.npz`` shard per scenario with an
``index.json`` naming every shard, its split and where it came from. A user's own training
reads the shards with numpy alone; ``load_shard`` reads one back as ``TrainingData``.

The split (``window_split``) is decided by the log window a scenario comes from, never by
the scenario itself: a failure found on a held-out window is test data even if it was found
against a stack that trained on other windows of the same log.

- synthetic logs are split by their seed, whatever their scene family: those of the training
  seeds (``training.synthetic_seeds``) train, those of the validation seeds
  (``training.validation_seeds``, disjoint from them) validate: fine-tuning stops early on their
  loss and never trains on them; every other seed is test. Standard training reads the training
  seeds' logs of ``training.families`` (the packaged weights: street only; Table 2's standard
  stack also the interaction families), and robust training's campaign attacks those seeds only
  (params/campaign_table2_train.yaml), so a test scene (another seed) is never a log any training
  or attack for training saw;
- the KITTI training sequence trains on windows inside the frames training saw (decisions up
  to ``training.kitti_last_decision`` and their horizons), tests on windows wholly after them,
  and windows straddling the boundary are excluded (they would leak training targets);
- everything else (Argoverse 2, users' bags) is test.

Curriculum training (``hardest_windows``) ranks the curation windows (``core.curation``) of the
logs standard training reads by their collision rate and keeps the hardest fraction, of the train
split only: a window of a validation or test log, or one straddling KITTI's boundary, is never
a candidate.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TypedDict

import numpy as np

from advsim_ros.core.atomic import atomic_file, write_json_atomically
from advsim_ros.core.curation import CurationConfig, CurationWindow, crop_scenario, curate_windows
from advsim_ros.core.types import Scenario
from advsim_ros.io.bag import bag_layout_of, read_scenario_bag
from advsim_ros.io.synthetic_families import FAMILY_NAMES
from advsim_ros.stacks.interface import StackError
from advsim_ros.stacks.learned.config import LearnedStackConfig
from advsim_ros.stacks.learned.samples import TrainingData, samples_from_scenario

SPLITS = ("train", "validation", "test", "excluded")
INDEX_NAME = "index.json"
SHARD_ARRAYS = ("images", "features", "priors", "targets")


def source_window(scenario_id: str) -> tuple[str, int]:
    """(log id, first frame of the window) of a scenario id ``LOG@START/KIND`` (a whole log: start 0)."""
    found = re.fullmatch(r"(.+)@(\d+)(/.*)?", scenario_id)
    return (found.group(1), int(found.group(2))) if found else (scenario_id, 0)


def synthetic_seed(log_id: str) -> int | None:
    """The seed of a synthetic log id (``synthetic_SEED`` or ``synthetic_FAMILY_SEED``, io.synthetic.synthetic_name)."""
    found = re.fullmatch(r"synthetic_(?:([a-z_]+)_)?(\d+)", log_id)
    if found is None or (found.group(1) is not None and found.group(1) not in FAMILY_NAMES):
        return None
    return int(found.group(2))


def window_split(log_id: str, first_frame: int, num_frames: int, config: LearnedStackConfig) -> str:
    """Which split a window of a log belongs to: "train", "validation", "test" or "excluded" (module docstring)."""
    training = config.training
    seed = synthetic_seed(log_id)
    if seed is not None and seed in training.synthetic_seeds:
        return "train"
    if seed is not None and seed in training.validation_seeds:
        return "validation"
    if log_id == f"kitti_tracking_{training.kitti_sequence}":
        last_seen = training.kitti_last_decision + config.num_steps  # the last frame a training target reaches
        if first_frame + num_frames - 1 <= last_seen:
            return "train"
        return "test" if first_frame > last_seen else "excluded"
    return "test"


class ShardEntry(TypedDict):
    """One shard of a training export, as its index lists it."""

    name: str  # the regression suite's scenario
    file: str  # <name>.npz beside the index
    split: str  # "train", "validation" or "test"
    samples: int
    log: str  # the log the window is of
    window_start: int  # its first frame in that log
    found_on: str | None  # the stack the suite entry was found on
    recorded: dict[str, float | None] | None  # its recorded figures (adversarial_loss, collision_3s, collision_5s)


@dataclass(frozen=True)
class TrainingExport:
    """What `advsim export training` wrote."""

    out_dir: Path
    shards: tuple[ShardEntry, ...]

    def describe(self) -> str:
        counts = {split: sum(s["samples"] for s in self.shards if s["split"] == split) for split in SPLITS}
        listed = ", ".join(f"{counts[split]} {split}" for split in SPLITS)
        return f"wrote {len(self.shards)} shards to {self.out_dir}: samples {listed} (index: {INDEX_NAME})"


def export_training(
    suite: Path, out_dir: Path, config: LearnedStackConfig, progress: Callable[[str], None] | None = None
) -> TrainingExport:
    """One shard per scenario of a regression suite (OUTDIR/suite of a campaign), and the index."""
    index_path = suite / INDEX_NAME
    try:
        scenarios = json.loads(index_path.read_text(encoding="utf-8"))["scenarios"]
    except (OSError, ValueError, KeyError, TypeError):
        raise StackError(f"{suite}: not a regression suite (expected {INDEX_NAME} of `advsim campaign`)") from None
    out_dir.mkdir(parents=True, exist_ok=True)
    shards: list[ShardEntry] = []
    for entry in scenarios:
        layout = bag_layout_of(entry.get("bag_params"), f"{index_path} {entry['name']} bag_params")
        scenario = read_scenario_bag(suite / entry["bag"], config=layout)  # in the layout the attack wrote it
        log_id, first = source_window(scenario.scenario_id)
        split = window_split(log_id, first, scenario.num_frames, config)
        data = samples_from_scenario(scenario, config)
        shard = f"{entry['name']}.npz"
        with atomic_file(out_dir / shard, "wb") as stream:
            np.savez_compressed(stream, **{name: getattr(data, name) for name in SHARD_ARRAYS},
                                sources=np.array(data.sources))  # fmt: skip
        shards.append({
            "name": entry["name"], "file": shard, "split": split, "samples": data.count, "log": log_id,
            "window_start": first, "found_on": entry.get("found_on"), "recorded": entry.get("recorded"),
        })  # fmt: skip
        if progress is not None:
            progress(f"{entry['name']}: {data.count} samples ({split})")
    write_json_atomically(out_dir / INDEX_NAME, {
        "format": "advsim_ros training shards v1",
        "arrays": {"images": "(N, C, rows, columns) bool BEV occupancy", "features": "(N, F) float32",
                   "priors": "(N, T, 2) float32 motion prior [m]",
                   "targets": "(N, T, 2) float32 human positions in the ego frame [m]",
                   "sources": "(N,) '<scenario id>@<frame>'"},
        "raster": config.raster.__dict__, "num_steps": config.num_steps, "step_s": config.step_s,
        "shards": shards,
    })  # fmt: skip
    return TrainingExport(out_dir, tuple(shards))


def load_shard(path: Path) -> TrainingData:
    """A shard written by export_training, as TrainingData."""
    with np.load(path) as arrays:
        return TrainingData(
            images=arrays["images"], features=arrays["features"], priors=arrays["priors"],
            targets=arrays["targets"], sources=tuple(str(s) for s in arrays["sources"]),
        )  # fmt: skip


def training_shards(folder: Path, split: str = "train") -> list[TrainingData]:
    """The shards of an export that belong to ``split`` (robust training takes "train" only)."""
    try:
        shards = json.loads((folder / INDEX_NAME).read_text(encoding="utf-8"))["shards"]
    except (OSError, ValueError, KeyError, TypeError):
        raise StackError(
            f"{folder}: not a training export (expected {INDEX_NAME} of `advsim export training`)"
        ) from None
    return [load_shard(folder / shard["file"]) for shard in shards if shard["split"] == split]


@dataclass(frozen=True)
class HardWindow:
    """A curation window of a training log picked by curriculum training."""

    scenario: Scenario  # the whole log
    window: CurationWindow

    @property
    def name(self) -> str:
        """``LOG@START``, like the scenario ids of found scenarios."""
        return f"{self.scenario.scenario_id}@{self.window.start_frame}"

    def samples(self, config: LearnedStackConfig) -> TrainingData:
        """The window's samples (its one decision: 1 s of history, 5 s of future), named ``LOG@START/hard``."""
        cropped = crop_scenario(self.scenario, self.window)
        return samples_from_scenario(replace(cropped, scenario_id=f"{self.name}/hard"), config)


def hardest_windows(
    scenarios: Sequence[Scenario], config: LearnedStackConfig, curation: CurationConfig
) -> list[HardWindow]:
    """The hardest ``training.curriculum_fraction`` of the train-split curation windows, hardest first.

    Candidates are the curation windows of ``scenarios`` whose split is "train"; ranked by collision
    rate (equal rates: in the order of the logs and windows), the first ceil(fraction x candidates)
    are kept, less those with rate 0 (no curation signal: nothing makes them hard). StackError when
    no window is a candidate or none of the kept ones has any signal.
    """
    span = curation.history_frames + curation.future_frames
    candidates = []
    for scenario in scenarios:
        if scenario.num_frames < span:
            continue  # shorter than one window: nothing to rank
        log_id, first = source_window(scenario.scenario_id)
        for window in curate_windows(scenario, curation):
            if window_split(log_id, first + window.start_frame, span, config) == "train":
                candidates.append(HardWindow(scenario, window))
    if not candidates:
        raise StackError(
            f"curriculum training: no train-split window of {span} frames in the training logs "
            f"({', '.join(s.scenario_id for s in scenarios) or 'none'})"
        )
    ranked = sorted(range(len(candidates)), key=lambda index: (-candidates[index].window.collision_rate, index))
    count = math.ceil(config.training.curriculum_fraction * len(candidates))
    hardest = [candidates[index] for index in ranked[:count] if candidates[index].window.collision_rate > 0.0]
    if not hardest:
        raise StackError(
            f"curriculum training: none of the {len(candidates)} train-split windows has any curation signal "
            "(no sampled SDV trajectory collides in any): nothing to rank them by"
        )
    return hardest
