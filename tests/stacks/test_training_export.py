"""Found scenarios as training data: shards that read back to what the stack saw, split by source window."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from advsim_ros.core.curation import crop_frames
from advsim_ros.io.bag import bag_layout_json, read_scenario_bag, write_scenario_bag
from advsim_ros.io.synthetic import SyntheticConfig, generate_synthetic_log
from advsim_ros.stacks.interface import StackError
from advsim_ros.stacks.learned.config import LearnedStackConfig
from advsim_ros.stacks.learned.dataset import export_training, load_shard, source_window, window_split
from advsim_ros.stacks.learned.samples import samples_from_scenario

CONFIG = LearnedStackConfig()


@pytest.fixture(scope="module")
def suite(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A regression suite of two 6-s scenarios: one from a training log, one from a held-out family."""
    folder = tmp_path_factory.mktemp("campaign") / "suite"
    scenarios = []
    for name, seed, family in (("from_training_log", 100, "street"), ("held_out", 3, "lead_brake")):
        log_id = f"synthetic_{seed}" if family == "street" else f"synthetic_{family}_{seed}"
        log = generate_synthetic_log(np.random.default_rng(seed), SyntheticConfig(family=family), log_id)
        window = crop_frames(log.scenario, 10, 69)
        window = type(window)(**{**window.__dict__, "scenario_id": f"{log_id}@10/adversarial"})
        write_scenario_bag(window, folder / name, source="test")
        scenarios.append({"name": name, "bag": name, "found_on": "learned", "recorded": {"collision_5s": 1.0}})
    (folder / "index.json").write_text(json.dumps({"suite_version": 1, "scenarios": scenarios}))
    return folder


def test_every_shard_reads_back_to_the_samples_the_stack_computes_from_its_bag(suite: Path, tmp_path: Path) -> None:
    written = export_training(suite, tmp_path / "data", CONFIG)
    index = json.loads((tmp_path / "data" / "index.json").read_text())
    assert [(s["name"], s["split"], s["log"], s["window_start"]) for s in index["shards"]] == [
        ("from_training_log", "train", "synthetic_100", 10),
        ("held_out", "test", "synthetic_lead_brake_3", 10),
    ]
    for shard in written.shards:
        expected = samples_from_scenario(read_scenario_bag(suite / shard["name"]), CONFIG)
        loaded = load_shard(tmp_path / "data" / shard["file"])
        assert loaded.count == expected.count == shard["samples"] > 0
        for name in ("images", "features", "priors", "targets"):
            assert np.array_equal(getattr(loaded, name), getattr(expected, name)), name
        assert loaded.sources == expected.sources
    with np.load(tmp_path / "data" / "held_out.npz") as arrays:  # numpy alone reads a shard
        assert arrays["targets"].shape[1:] == (CONFIG.num_steps, 2)


def test_a_suite_of_bags_in_a_users_layout_exports_as_recorded(recorded_your_way: Any, tmp_path: Path) -> None:
    """A campaign on bags recorded one's own way keeps their layout in the suite and its index says so."""
    suite = tmp_path / "suite"
    log = generate_synthetic_log(np.random.default_rng(5), SyntheticConfig(), "synthetic_5")
    window = crop_frames(log.scenario, 10, 69)
    window = type(window)(**{**window.__dict__, "scenario_id": "synthetic_5@10/adversarial"})
    layout = recorded_your_way.layout
    write_scenario_bag(window, suite / "yours", config=layout, source="test")
    entry = {"name": "yours", "bag": "yours", "found_on": "learned", "bag_params": bag_layout_json(layout)}
    (suite / "index.json").write_text(json.dumps({"suite_version": 1, "scenarios": [entry]}))
    written = export_training(suite, tmp_path / "data", CONFIG)
    expected = samples_from_scenario(read_scenario_bag(suite / "yours", config=layout), CONFIG)
    assert written.shards[0]["samples"] == expected.count > 0
    assert np.array_equal(load_shard(tmp_path / "data" / "yours.npz").targets, expected.targets)


def test_the_command_writes_the_shards_and_refuses_a_folder_that_is_not_a_suite(suite: Path, tmp_path: Path) -> None:
    command = [sys.executable, "-m", "advsim_ros.cli", "export", "training"]
    done = subprocess.run([*command, str(suite), "-o", str(tmp_path / "out")], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert "wrote 2 shards" in done.stdout
    bad = subprocess.run([*command, str(tmp_path), "-o", str(tmp_path / "x")], capture_output=True, text=True)
    assert bad.returncode != 0
    assert bad.stderr.strip().count("\n") == 0
    assert "not a regression suite" in bad.stderr
    with pytest.raises(StackError, match="not a regression suite"):
        export_training(tmp_path, tmp_path / "y", CONFIG)


def test_the_split_never_lets_a_test_window_share_a_frame_with_training() -> None:
    training = CONFIG.training
    kitti = f"kitti_tracking_{training.kitti_sequence}"
    trained_frames = {  # every frame a KITTI training sample reads: its history and its target horizon
        frame
        for decision in range(CONFIG.raster.history - 1, training.kitti_last_decision + 1)
        for frame in range(decision - CONFIG.raster.history + 1, decision + CONFIG.num_steps + 1)
    }
    splits = {start: window_split(kitti, start, 60, CONFIG) for start in range(0, 140)}  # a longer log than 0000
    assert set(splits.values()) == {"train", "test", "excluded"}
    for start, split in splits.items():
        frames = set(range(start, start + 60))
        if split == "test":
            assert frames.isdisjoint(trained_frames), start
        if split == "train":
            assert frames <= trained_frames, start
    assert window_split("synthetic_100", 0, 60, CONFIG) == "train"
    assert window_split("synthetic_104", 0, 60, CONFIG) == "validation"  # validates fine-tuning, never trains
    assert window_split("synthetic_lead_brake_100", 0, 60, CONFIG) == "train"  # a family log of a training seed
    assert window_split("synthetic_left_turn_105", 0, 60, CONFIG) == "validation"
    assert window_split("synthetic_lead_brake_3", 0, 60, CONFIG) == "test"  # any other seed, any family
    assert window_split("synthetic_bogus_100", 0, 60, CONFIG) == "test"  # not a synthetic name: not trusted
    assert window_split("av2_7fab", 0, 60, CONFIG) == "test"
    assert source_window("kitti_tracking_0000@20/adversarial") == ("kitti_tracking_0000", 20)
    assert source_window("synthetic_3") == ("synthetic_3", 0)


def test_robust_training_fine_tunes_on_logs_plus_found_scenarios_reproducibly(suite: Path, tmp_path: Path) -> None:
    import dataclasses

    import torch

    from advsim_ros.stacks.learned.dataset import training_shards
    from advsim_ros.stacks.learned.stack import load_model
    from advsim_ros.stacks.learned.train import train_il

    export_training(suite, tmp_path / "data", CONFIG)
    adversarial = training_shards(tmp_path / "data")
    assert [part.sources[0].split("@")[0] for part in adversarial] == ["synthetic_100"]  # the held-out one stays out
    tiny = {"synthetic_seeds": (5,), "synthetic_duration": 6.2, "finetune_epochs": 1, "finetune_repeat": 2,
            "validation_seeds": (6,), "finetune_families": ("street",)}  # fmt: skip
    small = dataclasses.replace(CONFIG, training=dataclasses.replace(CONFIG.training, **tiny))
    first = train_il(small, None, tmp_path / "robust_a.pt", scheme="robust", adversarial=adversarial)
    second = train_il(small, None, tmp_path / "robust_b.pt", scheme="robust", adversarial=adversarial)
    assert adversarial[0].count == 1  # a found scenario is one decision: 1 s of history, 5 s of future
    assert first.sources == {"synthetic_5": 3, "synthetic_100@10/adversarial": 2}  # the log's samples + 2 repeats
    assert second.samples == first.samples
    robust, metadata = load_model(small, tmp_path / "robust_a.pt")
    again, _ = load_model(small, tmp_path / "robust_b.pt")
    pairs = zip(robust.state_dict().values(), again.state_dict().values(), strict=True)
    assert all(torch.equal(a, b) for a, b in pairs)  # the same weights, bit for bit
    assert metadata["scheme"] == "robust"
    assert metadata["adversarial_samples"] == adversarial[0].count
    assert metadata["best_epoch"] == first.best_epoch == 1  # one pass: the only one to keep
    assert len(metadata["validation_losses"]) == 2  # before fine-tuning, after the pass
    standard, _ = load_model(small)  # the packaged weights it started from
    pairs = zip(robust.state_dict().values(), standard.state_dict().values(), strict=True)
    changed = [not torch.equal(a, b) for a, b in pairs]
    assert any(changed)  # fine-tuned, not retrained from scratch nor left as it was
    with pytest.raises(StackError, match="robust training needs adversarial samples"):
        train_il(small, None, tmp_path / "none.pt", scheme="robust")


def test_robust_training_validates_on_found_scenarios_of_the_validation_split_and_never_trains_on_them(
    suite: Path, tmp_path: Path
) -> None:
    import dataclasses

    from advsim_ros.stacks.commands import train_il_command

    export_training(suite, tmp_path / "data", CONFIG)
    # the same suite read with seed 3 as a validation seed: its held-out scenario becomes validation data
    validating = dataclasses.replace(CONFIG, training=dataclasses.replace(CONFIG.training, validation_seeds=(3,)))
    export_training(suite, tmp_path / "data_validation", validating)
    index = json.loads((tmp_path / "data_validation" / "index.json").read_text())
    assert [shard["split"] for shard in index["shards"]] == ["train", "validation"]
    params = tmp_path / "learned.yaml"
    params.write_text(
        "/learned_stack:\n  ros__parameters:\n    training:\n      synthetic_seeds: [5]\n"
        "      synthetic_duration: 6.2\n      finetune_epochs: 1\n      finetune_repeat: 2\n"
        "      validation_seeds: [6]\n      finetune_families: [street]\n"
    )
    runs = {
        name: train_il_command(tmp_path / f"{name}.pt", None, params, None, lambda _: None, "robust", folders)
        for name, folders in (("plain", [tmp_path / "data"]), ("validated", [tmp_path / "data_validation"]))
    }
    assert runs["validated"]["sources"] == runs["plain"]["sources"]  # validation scenarios are never trained on
    assert runs["validated"]["validation_losses"] != runs["plain"]["validation_losses"]  # ... but measured
    with pytest.raises(StackError, match="only --scheme robust"):
        train_il_command(tmp_path / "c.pt", None, params, None, lambda _: None, "curriculum", [tmp_path / "data"])
