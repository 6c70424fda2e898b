"""Curriculum training: the hardest train-split windows by curation rate, fine-tuned on with early stopping."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
import torch

from advsim_ros.core.curation import CurationConfig, curate_windows
from advsim_ros.core.types import Scenario
from advsim_ros.io.synthetic import SyntheticConfig, SyntheticLog, generate_synthetic_log, synthetic_name
from advsim_ros.stacks.interface import StackError
from advsim_ros.stacks.learned.config import LearnedStackConfig, ModelConfig, TrainingConfig
from advsim_ros.stacks.learned.dataset import hardest_windows, window_split
from advsim_ros.stacks.learned.samples import samples_from_scenario
from advsim_ros.stacks.learned.stack import load_model
from advsim_ros.stacks.learned.train import (
    train_il,
    train_planner,
    training_scenarios,
    validation_data,
    validation_loss,
)

CONFIG = LearnedStackConfig()  # synthetic seeds 100-103 train, 104-105 validate, everything else tests
CURATION = CurationConfig()


def _log(seed: int, family: str = "street", duration: float = 8.0) -> Scenario:
    config = SyntheticConfig(family=family, duration=duration)
    return generate_synthetic_log(np.random.default_rng(seed), config, synthetic_name(family, seed)).scenario


@pytest.fixture(scope="module")
def logs() -> dict[str, Scenario]:
    """8-s streets (two curation windows each) of two training seeds, a validation seed and a test seed."""
    return {scenario.scenario_id: scenario for scenario in (_log(100), _log(101), _log(104), _log(3))}


def test_curriculum_takes_the_hardest_windows_of_the_train_split_only(logs: dict[str, Scenario]) -> None:
    half = dataclasses.replace(CONFIG, training=dataclasses.replace(CONFIG.training, curriculum_fraction=0.5))
    rates = {f"{name}@{w.start_frame}": w.collision_rate for name, log in logs.items()
             for w in curate_windows(log, CURATION)}  # fmt: skip
    splits = {name: window_split(name.split("@")[0], int(name.split("@")[1]), 60, CONFIG) for name in rates}
    assert sorted(set(splits.values())) == ["test", "train", "validation"]
    train = [name for name in rates if splits[name] == "train"]  # in log order, then window order
    expected = sorted(train, key=lambda name: -rates[name])[:2]  # half of the 4 train windows, hardest first
    picked = hardest_windows(list(logs.values()), half, CURATION)
    assert [window.name for window in picked] == expected
    assert [window.window.collision_rate for window in picked] == [rates[name] for name in expected]
    # windows of the validation and test logs are harder than a picked one, yet never taken
    assert max(rate for name, rate in rates.items() if splits[name] != "train") > min(rates[n] for n in expected)
    everything = dataclasses.replace(CONFIG, training=dataclasses.replace(CONFIG.training, curriculum_fraction=1.0))
    assert sorted(w.name for w in hardest_windows(list(logs.values()), everything, CURATION)) == sorted(
        name for name in train if rates[name] > 0
    )
    sample = picked[0].samples(CONFIG)  # the window's one decision: 1 s of history, 5 s of future
    assert sample.count == 1
    assert sample.sources == (f"{expected[0]}/hard@{CURATION.history_frames - 1}",)


def test_curriculum_refuses_logs_without_train_windows_or_without_any_curation_signal(
    logs: dict[str, Scenario],
) -> None:
    with pytest.raises(StackError, match="no train-split window of 60 frames"):
        hardest_windows([logs["synthetic_104"], logs["synthetic_3"]], CONFIG, CURATION)  # validation and test only
    with pytest.raises(StackError, match="no train-split window"):
        hardest_windows([_log(100, duration=5.0)], CONFIG, CURATION)  # shorter than one window
    quiet = _log(3, "lead_brake")  # nothing but the lead vehicle (ignored by curation) meets the sampled plans
    quiet = dataclasses.replace(quiet, scenario_id="synthetic_100")  # as if it were a training log
    assert all(window.collision_rate == 0.0 for window in curate_windows(quiet, CURATION))
    with pytest.raises(StackError, match="none of the 2 train-split windows has any curation signal"):
        hardest_windows([quiet], CONFIG, CURATION)


def test_curriculum_never_takes_a_kitti_window_beyond_the_training_frames(kitti_root: Path) -> None:
    from advsim_ros.io.kitti import load_kitti_tracking

    kitti = load_kitti_tracking(kitti_root, CONFIG.training.kitti_sequence)
    everything = dataclasses.replace(CONFIG, training=dataclasses.replace(CONFIG.training, curriculum_fraction=1.0))
    starts = [window.start_frame for window in curate_windows(kitti, CURATION)]
    assert starts == [0, 20, 40, 60, 80]  # 60 and 80 straddle the last training frame (109)
    picked = hardest_windows([kitti], everything, CURATION)
    assert sorted(window.window.start_frame for window in picked) == [0, 20, 40]


def test_curriculum_training_fine_tunes_on_the_hard_windows_bit_for_bit(tmp_path: Path) -> None:
    tiny = {"synthetic_seeds": (100,), "synthetic_duration": 6.2, "validation_seeds": (104,), "finetune_epochs": 2,
            "finetune_repeat": 2, "curriculum_fraction": 1.0,
            "finetune_families": ("street", "lead_brake")}  # fmt: skip
    small = dataclasses.replace(CONFIG, training=dataclasses.replace(CONFIG.training, **tiny))
    first = train_il(small, None, tmp_path / "a.pt", scheme="curriculum")
    second = train_il(small, None, tmp_path / "b.pt", scheme="curriculum")
    # candidates: the street log standard training reads (6.2 s: one window) and the training seed's
    # lead_brake log at the campaigns' length (8 s: two windows); every one with a curation signal is kept
    expected = {
        f"{scenario.scenario_id}@{window.start_frame}": window.collision_rate
        for scenario in (_log(100, duration=6.2), _log(100, "lead_brake"))
        for window in curate_windows(scenario, CURATION)
        if window.collision_rate > 0
    }
    assert any(name.startswith("synthetic_lead_brake_100@") for name in expected)
    ranked = dict(sorted(expected.items(), key=lambda item: -item[1]))  # hardest first, ties in candidate order
    assert first.hard_windows == ranked
    assert list(first.hard_windows) == list(ranked)
    assert first.sources == {"synthetic_100": 3} | {f"{name}/hard": 2 for name in expected}  # the log + 2 repeats
    assert len(first.validation_losses) == first.epochs + 1
    assert first.best_epoch == 1 + int(np.argmin(first.validation_losses[1:]))
    tuned, metadata = load_model(small, tmp_path / "a.pt")
    again, _ = load_model(small, tmp_path / "b.pt")
    pairs = zip(tuned.state_dict().values(), again.state_dict().values(), strict=True)
    assert all(torch.equal(a, b) for a, b in pairs)  # the same weights, bit for bit
    assert (tmp_path / "a.pt").read_bytes() == (tmp_path / "b.pt").read_bytes()
    assert second.validation_losses == first.validation_losses
    assert metadata["scheme"] == "curriculum"
    assert metadata["hard_windows"] == first.hard_windows
    assert metadata["best_epoch"] == first.best_epoch
    standard, _ = load_model(small)  # the packaged standard weights it started from
    pairs = zip(tuned.state_dict().values(), standard.state_dict().values(), strict=True)
    assert any(not torch.equal(a, b) for a, b in pairs)


def test_fine_tuning_validates_on_every_finetune_family_of_the_validation_seeds() -> None:
    training = dataclasses.replace(
        CONFIG.training, validation_seeds=(104,), synthetic_duration=6.2, finetune_families=("street", "cut_in")
    )
    data = validation_data(dataclasses.replace(CONFIG, training=training))
    assert data is not None
    counts = {log_id: sum(source.startswith(f"{log_id}@") for source in data.sources)
              for log_id in ("synthetic_104", "synthetic_cut_in_104")}  # fmt: skip
    assert counts == {"synthetic_104": 3, "synthetic_cut_in_104": 21}  # 6.2-s street, 8-s cut_in: frames 9..(n-51)
    assert data.count == sum(counts.values())
    with pytest.raises(ValueError, match="finetune_families: unknown \\['bogus'\\]"):
        TrainingConfig(finetune_families=("street", "bogus"))


def test_standard_training_reads_the_training_seeds_logs_of_every_family_it_names() -> None:
    training = dataclasses.replace(
        CONFIG.training, synthetic_seeds=(100, 101), synthetic_duration=6.2, families=("street", "cut_in")
    )
    logs = training_scenarios(dataclasses.replace(CONFIG, training=training), None)
    assert [scenario.scenario_id for scenario, _ in logs] == [
        "synthetic_100", "synthetic_101", "synthetic_cut_in_100", "synthetic_cut_in_101"
    ]  # fmt: skip
    assert [scenario.num_frames for scenario, _ in logs] == [62, 62, 80, 80]  # street 6.2 s, families as campaigns
    attacked = _log(101, "cut_in")  # the very log a campaign attacks
    assert all(np.array_equal(a.centers, b.centers) for a, b in zip(logs[3][0].actors, attacked.actors, strict=True))
    assert [scenario.scenario_id for scenario, _ in training_scenarios(CONFIG, None)] == [
        f"synthetic_{seed}" for seed in CONFIG.training.synthetic_seeds
    ]  # the packaged weights' data: street logs only
    with pytest.raises(ValueError, match="training families: name at least one"):
        TrainingConfig(families=())


SMALL = LearnedStackConfig(
    model=ModelConfig(channels=(4, 8), bottleneck=2, hidden=16),
    training=TrainingConfig(epochs=12, batch_size=4, seed=3, learning_rate=0.01, finetune_patience=2),
)


def test_early_stopping_keeps_the_pass_with_the_lowest_validation_loss(synthetic_log: SyntheticLog) -> None:
    data = samples_from_scenario(synthetic_log.scenario, SMALL, keep=lambda frame: frame % 2 == 1)
    validation = samples_from_scenario(synthetic_log.scenario, SMALL, keep=lambda frame: frame % 2 == 0)
    fit = train_planner(data, SMALL, validation=validation)
    best = fit.best_epoch
    assert len(fit.validation_losses) == len(fit.losses) + 1  # before training, then after every pass
    assert best == 1 + int(np.argmin(fit.validation_losses[1:]))
    assert 1 < best < len(fit.losses) == best + SMALL.training.finetune_patience < SMALL.training.epochs  # stopped
    assert validation_loss(fit.model, validation, 4) == fit.validation_losses[best]
    # the weights kept are exactly those of a run that stops at the best pass: measuring changes nothing
    plain = train_planner(data, dataclasses.replace(SMALL, training=dataclasses.replace(SMALL.training, epochs=best)))
    assert plain.losses == fit.losses[:best]
    pairs = zip(fit.model.state_dict().values(), plain.model.state_dict().values(), strict=True)
    assert all(torch.equal(a, b) for a, b in pairs)


def test_train_il_curriculum_errors_are_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from advsim_ros.cli import main

    params = tmp_path / "stack_learned.yaml"
    params.write_text(
        "/learned_stack:\n  ros__parameters:\n"
        "    training:\n      synthetic_seeds: [100]\n      synthetic_duration: 5.0\n"
        "      finetune_families: [street]\n"
    )  # a 5-s log has no 6-s curation window
    out = tmp_path / "il.pt"
    base = ["train-il", "-o", str(out), "--no-kitti", "--params", str(params), "--scheme", "curriculum"]
    assert main(base) == 1
    error = capsys.readouterr().err.strip().splitlines()[-1]
    assert error.startswith("advsim train-il: error: curriculum training: no train-split window")
    assert main([*base, "--adversarial", str(tmp_path)]) == 1
    assert capsys.readouterr().err.strip() == (
        "advsim train-il: error: --adversarial: only --scheme robust trains on found scenarios, not curriculum"
    )
    assert not out.exists()
    with pytest.raises(ValueError, match="validation_seeds: \\[100\\] also train"):
        TrainingConfig(synthetic_seeds=(100,), validation_seeds=(100,))
