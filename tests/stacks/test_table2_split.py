"""Table 2's campaigns stay on their side of the split: robust training's on training seeds, evaluation on test."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from advsim_ros.campaign.config import load_campaign
from advsim_ros.io.synthetic import synthetic_name
from advsim_ros.stacks.learned.config import LearnedStackConfig
from advsim_ros.stacks.learned.dataset import synthetic_seed, window_split

PARAMS = Path(__file__).resolve().parents[2] / "params"
CONFIG = LearnedStackConfig()


def _log_ids(config_file: str) -> list[str]:
    campaign = load_campaign(PARAMS / config_file)
    assert all(source.synthetic_seed is not None for source in campaign.scenarios), "Table 2 uses synthetic logs only"
    return [synthetic_name(source.synthetic_family, source.synthetic_seed or 0) for source in campaign.scenarios]


def test_the_robust_training_campaign_attacks_only_training_split_logs() -> None:
    log_ids = _log_ids("campaign_table2_train.yaml")
    assert len(log_ids) >= 16  # many found scenarios, not one log's windows
    # a synthetic log's split depends on its seed only, so every window of these logs is "train"
    for log_id in log_ids:
        for start in (0, 20, 40):
            assert window_split(log_id, start, 60, CONFIG) == "train", (log_id, start)


def test_the_table2_evaluation_attacks_only_test_split_logs_disjoint_from_training() -> None:
    test_ids = _log_ids("campaign_table2.yaml")
    assert all(window_split(log_id, 0, 60, CONFIG) == "test" for log_id in test_ids)
    train_seeds = {synthetic_seed(log_id) for log_id in _log_ids("campaign_table2_train.yaml")}
    test_seeds = {synthetic_seed(log_id) for log_id in test_ids}
    assert train_seeds.isdisjoint(test_seeds)
    assert test_seeds.isdisjoint(CONFIG.training.validation_seeds)


def test_synthetic_seed_reads_the_names_synthetic_logs_get() -> None:
    assert synthetic_seed(synthetic_name("street", 101)) == 101
    assert synthetic_seed(synthetic_name("left_turn", 3)) == 3
    assert synthetic_seed("synthetic_bogus_3") is None
    assert synthetic_seed("kitti_tracking_0000") is None


def test_table2_pairs_each_fine_tuned_stack_with_the_standard_one_scene_by_scene(tmp_path: Path) -> None:
    import json

    from advsim_ros.campaign.table2 import campaign_rows, paired_differences, table2_markdown

    def row(stack: str, scene: str, adversarial: float) -> dict[str, object]:
        return {"stack": stack, "scenario": scene, "window_start": 0, "status": "ok",
                "original_collision_5s": 0.0, "adversarial_collision_5s": adversarial,
                "original_l2_human_5s": 1.0, "adversarial_l2_human_5s": 2.0,
                "original_lateral_acceleration": 0.5, "adversarial_lateral_acceleration": 1.5,
                "original_jerk": 0.25, "adversarial_jerk": 0.75}  # fmt: skip

    rows = [row("learned", "a", 1.0), row("learned", "b", 1.0), row("learned", "c", 0.0),
            row("learned_robust", "a", 0.0), row("learned_robust", "b", 1.0)]  # fmt: skip
    header = {"campaign_journal": 1, "config_digest": "d"}
    journal = tmp_path / "campaign.jsonl"
    lines = [header, *({"job": f"attack/{i}", "row": r} for i, r in enumerate(rows)),
             {"job": "attack/failed", "row": {**rows[0], "status": "error"}}]  # fmt: skip
    journal.write_text("".join(json.dumps(line) + "\n" for line in lines))
    read = campaign_rows([tmp_path])
    assert len(read) == 5  # the failed attack and the header are not rows
    assert paired_differences(read, "learned_robust", "adversarial_collision_5s") == [-1.0, 0.0]  # scene c unpaired
    table = table2_markdown(read).splitlines()
    assert table[2].startswith("| learned | 3 | 0.0 [0.0, 0.0] | 66.7")
    assert "| 0.5 [0.5, 0.5] | 1.5 [1.5, 1.5] | 0.25 [0.25, 0.25] | 0.75 [0.75, 0.75] |" in table[2]
    assert table[3].startswith("| learned_robust | 2 |")
    assert table[3].endswith("pp (n=2) |")
    # another training seed's run of the same scenes: pooled, each robust stack paired with its own standard one
    other = tmp_path / "seed1"
    other.mkdir()
    seed1 = [row("learned", "a", 0.0), row("learned_robust", "a", 1.0)]
    (other / "campaign.jsonl").write_text("".join(json.dumps(line) + "\n" for line in
                                                  [header, *({"job": f"attack/{i}", "row": r}
                                                             for i, r in enumerate(seed1))]))  # fmt: skip
    pooled = campaign_rows([tmp_path, other])
    assert len(pooled) == 7
    assert paired_differences(pooled, "learned_robust", "adversarial_collision_5s") == [-1.0, 0.0, 1.0]
    # the command: the same tables, pooled from the folders given
    written = tmp_path / "table2.md"
    result = subprocess.run(
        [sys.executable, "-m", "advsim_ros.cli", "campaign-table2", str(tmp_path), str(other), "-o", str(written)],
        capture_output=True, text=True, timeout=120, check=True,
    )  # fmt: skip
    assert result.stdout == written.read_text() == table2_markdown(pooled)
    assert "| learned_robust | 3 |" in result.stdout
    assert "| family | learned | learned_robust |" in result.stdout
    missing = subprocess.run([sys.executable, "-m", "advsim_ros.cli", "campaign-table2", str(tmp_path / "none")],
                             capture_output=True, text=True, timeout=120, check=False)  # fmt: skip
    assert missing.returncode == 1
    assert "no campaign journal" in missing.stderr


def test_table2_counts_collided_scenes_per_scene_family() -> None:
    from advsim_ros.campaign.config import scene_family, synthetic_source_name
    from advsim_ros.campaign.table2 import family_table

    assert scene_family(synthetic_source_name("lead_brake", 3)) == "lead_brake"
    assert scene_family(synthetic_source_name("street", 101)) == "street"
    assert scene_family("kitti_0000") == "kitti_0000"  # a bag is its own family

    def row(stack: str, scene: str, original: float, adversarial: float) -> dict[str, object]:
        return {"stack": stack, "scenario": scene, "original_collision_5s": original,
                "adversarial_collision_5s": adversarial}  # fmt: skip

    rows = [row("learned", "synthetic_lead_brake_seed0", 1.0, 1.0),
            row("learned", "synthetic_lead_brake_seed1", 0.0, 1.0),
            row("learned", "synthetic_cut_in_seed0", 0.0, float("nan")),
            row("learned_robust", "synthetic_lead_brake_seed0", 1.0, 0.0),
            row("learned_robust", "synthetic_cut_in_seed0", 0.0, 1.0)]  # fmt: skip
    assert family_table(rows).markdown().splitlines() == [
        "| family | learned | learned_robust |",
        "| --- | --- | --- |",
        "| cut_in | 0 / 0 of 1 | 1 / 0 of 1 |",
        "| lead_brake | 2 / 1 of 2 | 0 / 1 of 1 |",
    ]


def test_table2_standard_stack_trains_on_the_families_its_training_campaign_attacks() -> None:
    from advsim_ros.stacks.learned.config import load_learned_config

    table2 = load_learned_config(PARAMS / "stack_learned_table2.yaml")
    campaign = load_campaign(PARAMS / "campaign_table2_train.yaml")
    attacked = {source.synthetic_family for source in campaign.scenarios}
    assert attacked == set(table2.training.families) == set(table2.training.finetune_families)
    assert {source.synthetic_seed for source in campaign.scenarios} == set(table2.training.synthetic_seeds)
    assert "left_turn" not in attacked  # no route input: a left turn's target is not in what the stack sees
    assert table2.model == CONFIG.model  # only the training data differs from the packaged stack's
    assert table2.raster == CONFIG.raster


def test_a_training_seed_appended_as_scripts_table2_does_reaches_the_training(tmp_path: Path) -> None:
    from advsim_ros.stacks.learned.config import load_learned_config

    script = (PARAMS.parent / "scripts" / "table2.sh").read_text()
    # the seed is appended under training:, the file's last section
    assert "printf '      seed: %s\\n' \"$TRAINING_SEED\"" in script
    seeded = tmp_path / "stack_learned_table2.yaml"
    seeded.write_text((PARAMS / "stack_learned_table2.yaml").read_text() + "      seed: 7\n")
    config = load_learned_config(seeded)
    assert config.training.seed == 7
    assert config.training.families == load_learned_config(PARAMS / "stack_learned_table2.yaml").training.families


def test_the_table2_evaluation_on_av2_logs_attacks_as_the_synthetic_one_does_on_test_split_logs() -> None:
    import yaml

    synthetic = yaml.safe_load((PARAMS / "campaign_table2.yaml").read_text())
    av2 = yaml.safe_load((PARAMS / "campaign_table2_av2.yaml").read_text())
    assert av2["scenarios"] == [{"bags": "av2", "windows": "curated"}]  # scripts/table2.sh converts the logs there
    assert {key: value for key, value in av2.items() if key != "scenarios"} == {
        key: value for key, value in synthetic.items() if key != "scenarios"
    }
    # the converter's scenario ids of AV2 logs are never a training or validation log
    assert window_split("av2_7fab2350-7eaf-3b7e-a39d-6937a4c1bede", 0, 60, CONFIG) == "test"
