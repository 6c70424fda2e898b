"""The campaign YAML: expanded into one attack per combination; every mistake one line naming its key, before
anything starts; the journal keeps what finished and refuses another configuration's folder."""

from __future__ import annotations

import logging
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from advsim_ros.campaign.config import AttackPlan, CampaignError, FailureRule, expand, load_campaign, materialize
from advsim_ros.campaign.journal import CampaignJournal
from advsim_ros.campaign.results import identity_of
from advsim_ros.io.bag import write_scenario_bag
from advsim_ros.io.synthetic import generate_synthetic_log

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    log = generate_synthetic_log(np.random.default_rng(5), scenario_id="synthetic_seed5")
    return write_scenario_bag(log.scenario, tmp_path_factory.mktemp("logs") / "street", source="synthetic/seed=5")


def _write(tmp_path: Path, values: dict[str, object]) -> Path:
    path = tmp_path / "campaign.yaml"
    path.write_text(yaml.safe_dump(values))
    return path


def _good(bag: Path) -> dict[str, object]:
    return {
        "scenarios": [{"bag": str(bag), "windows": {"starts": [0, 20]}}],
        "stacks": [
            "reference",
            "learned",
            {"name": "mine", "command": "true", "remap": {"/planning/trajectory": "/my/plan"}},
        ],
        "algorithms": {"bo": 75, "ga": 500},
        "actors": [1, 2],
        "objectives": ["M5", "closest_distance"],
        "seeds": [0],
    }


def test_every_combination_is_one_attack_with_a_unique_key(bag: Path, tmp_path: Path) -> None:
    campaign = load_campaign(_write(tmp_path, _good(bag)))
    plans = expand(campaign)
    assert len(plans) == 2 * 3 * 2 * 2 * 2
    assert len({plan.key for plan in plans}) == len(plans)
    first = plans[0]
    options = first.options(tmp_path / "a", tmp_path)
    assert options.window_start_frame == 0
    assert options.parameter_overrides["scorer"]["objective"]["preset"] == first.objective
    mine = next(p for p in plans if p.stack == "mine").options(tmp_path / "b", tmp_path)
    assert mine.stack.remappings == {"/planning/trajectory": "/my/plan"}


def test_both_loops_double_the_attacks_and_closed_loop_ones_say_so(bag: Path, tmp_path: Path) -> None:
    campaign = load_campaign(_write(tmp_path, {**_good(bag), "loops": ["open", "closed"]}))
    plans = expand(campaign)
    assert len(plans) == 2 * 3 * 2 * 2 * 2 * 2
    opened = [plan for plan in plans if plan.loop == "open"]
    closed = [plan for plan in plans if plan.loop == "closed"]
    assert {plan.key for plan in opened} == {plan.key for plan in expand(load_campaign(_write(tmp_path, _good(bag))))}
    assert all(plan.key.endswith("-closed") for plan in closed)
    assert closed[0].options(tmp_path / "c", tmp_path).loop == "closed"
    assert identity_of(closed[0])["loop"] == "closed"
    with pytest.raises(CampaignError, match="loops: expected open, closed or both"):
        load_campaign(_write(tmp_path, {**_good(bag), "loops": ["sideways"]}))


def test_reactive_actors_make_the_closed_loop_attacks_reactive_and_only_those(bag: Path, tmp_path: Path) -> None:
    campaign = load_campaign(_write(tmp_path, {**_good(bag), "loops": ["open", "closed"], "reactive_actors": True}))
    plans = expand(campaign)
    assert all(plan.reactive_actors == (plan.loop == "closed") for plan in plans)
    assert all(plan.key.endswith("-closed-reactive") for plan in plans if plan.loop == "closed")
    closed = next(plan for plan in plans if plan.loop == "closed")
    assert closed.options(tmp_path / "r", tmp_path).reactive_actors
    assert AttackPlan.from_json({k: v for k, v in closed.as_json().items() if k != "reactive_actors"}).loop == "closed"
    with pytest.raises(CampaignError, match="reactive_actors: only for closed-loop attacks"):
        load_campaign(_write(tmp_path, {**_good(bag), "reactive_actors": True}))


def test_curated_windows_are_the_top_k_by_collision_rate_and_synthetic_logs_are_written(tmp_path: Path) -> None:
    values = {"scenarios": [{"synthetic": {"seed_range": [0, 2]}, "windows": {"curated": 2}}],
              "stacks": ["reference"], "algorithms": {"simba": 3}}  # fmt: skip
    campaign = materialize(load_campaign(_write(tmp_path, values)), tmp_path / "logs")
    plans = expand(campaign)
    assert sorted({p.scenario for p in plans}) == ["synthetic_seed0", "synthetic_seed1"]
    assert all(
        (tmp_path / "logs" / name / "metadata.yaml").is_file() for name in ("synthetic_seed0", "synthetic_seed1")
    )
    assert len(plans) == 4  # two windows each


def test_synthetic_families_give_one_log_per_family_and_seed_written_with_that_family(tmp_path: Path) -> None:
    from advsim_ros.io.bag import read_scenario_bag

    synthetic = {"seeds": [4], "families": ["street", "cut_in"]}
    values = {"scenarios": [{"synthetic": synthetic, "windows": {"starts": [0]}}], "stacks": ["reference"],
              "algorithms": {"simba": 3}}  # fmt: skip
    campaign = materialize(load_campaign(_write(tmp_path, values)), tmp_path / "logs")
    assert [p.scenario for p in expand(campaign)] == ["synthetic_seed4", "synthetic_cut_in_seed4"]
    written = read_scenario_bag(tmp_path / "logs" / "synthetic_cut_in_seed4")
    assert written.scenario_id == "synthetic_cut_in_4"
    assert "cutter" in {actor.actor_id for actor in written.actors}


def test_the_shipped_smoke_config_is_valid() -> None:
    campaign = load_campaign(REPO / "params" / "campaign_smoke.yaml")
    assert list(campaign.stacks) == ["reference", "learned"]


@pytest.mark.parametrize(
    ("change", "named"),
    [
        ({"stackz": ["reference"]}, "stackz: unknown key"),
        ({"stacks": ["autoware"]}, "stacks[0]: 'autoware': not a reference stack"),
        ({"algorithms": {"sgd": 5}}, "algorithms.sgd: unknown algorithm"),
        ({"algorithms": {"bo": 0}}, "algorithms.bo: the query budget must be a positive integer"),
        ({"objectives": ["M9"]}, "objectives: 'M9' is not one of"),
        ({"actors": [0]}, "actors: expected an integer >= 1"),
        ({"scenarios": [{"bag": "/nowhere/log"}]}, "scenarios[0].bag: /nowhere/log is not a rosbag2 folder"),
        ({"scenarios": [{"bag": "X", "bags": "Y"}]}, "scenarios[0]: needs exactly one of bag, bags, synthetic"),
        ({"scenarios": [{"synthetic": {"seeds": [1]}, "window": "all"}]}, "scenarios[0].window: unknown key"),
        (
            {"scenarios": [{"synthetic": {"seeds": [1], "families": ["roundabout"]}}]},
            "scenarios[0].synthetic.families: unknown family 'roundabout' (one of street, lead_brake",
        ),
        ({"stacks": [{"name": "x"}]}, "stacks[0]: a stack of your own needs a name and a command"),
        ({"stacks": [{"name": "x", "command": "no_such_stack_binary_here --go"}]}, "stacks[0]:"),
        ({"failure": {"exclude": ["boring"]}}, "failure.exclude: expected a list of flaky, original_flaky"),
    ],
)
def test_a_mistake_is_one_line_naming_its_key(bag: Path, tmp_path: Path, change: dict[str, object], named: str) -> None:
    path = _write(tmp_path, {**_good(bag), **change})
    with pytest.raises(CampaignError) as error:
        expand(load_campaign(path))
    message = str(error.value)
    assert "\n" not in message
    assert named in message


def test_a_window_beyond_the_log_is_refused_by_the_command_before_anything_starts(bag: Path, tmp_path: Path) -> None:
    path = _write(tmp_path, {**_good(bag), "scenarios": [{"bag": str(bag), "windows": {"starts": [0, 5000]}}]})
    out = tmp_path / "out"
    result = subprocess.run(
        [sys.executable, "-m", "advsim_ros.cli", "campaign", str(path), "-o", str(out)],
        capture_output=True, text=True, timeout=300, check=False,
    )  # fmt: skip
    assert result.returncode == 1
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert "scenarios[street].windows" in lines[0]
    assert not out.exists()


def test_the_journal_keeps_finished_jobs_drops_a_torn_line_and_refuses_another_config(tmp_path: Path) -> None:
    journal = CampaignJournal.open(tmp_path, "digest-a", tmp_path / "a.yaml")
    journal.append("attack/one", {"row": {"attack": "one"}})
    journal.append("attack/two", {"row": {"attack": "two"}, "error": "the stack crashed"})
    with journal.path.open("a") as stream:
        stream.write('{"job": "attack/three", "ro')  # a kill in the middle of a line
    again = CampaignJournal.open(tmp_path, "digest-a", tmp_path / "a.yaml")
    assert "attack/one" in again
    assert "attack/two" not in again  # failed: tried again on the next run
    assert "attack/three" not in again.entries
    assert journal.path.read_text().endswith("\n")
    with pytest.raises(CampaignError, match="another configuration"):
        CampaignJournal.open(tmp_path, "digest-b", tmp_path / "b.yaml")


def test_simba_under_its_old_name_rs_is_simba_in_the_config_and_in_a_journal_of_before(
    bag: Path, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    with caplog.at_level(logging.WARNING):
        campaign = load_campaign(_write(tmp_path, {**_good(bag), "algorithms": {"rs": 5}}))
    assert dict(campaign.algorithms) == {"simba": 5}
    assert [record.getMessage() for record in caplog.records] == [
        "search algorithm 'rs' is deprecated: use 'simba' (the same algorithm)"
    ]
    with pytest.raises(CampaignError, match="named twice"):
        load_campaign(_write(tmp_path, {**_good(bag), "algorithms": {"rs": 5, "simba": 7}}))
    key = expand(campaign)[0].key
    assert "-simba5-" in key
    old_key = key.replace("-simba5-", "-rs5-")
    journal = CampaignJournal.open(tmp_path, "digest-a", tmp_path / "a.yaml")
    journal.append(f"attack/{old_key}", {"row": {"attack": old_key, "algorithm": "rs", "budget": 5}})
    journal.append(f"transfer/{old_key}/learned", {"row": {"attack": old_key, "target_stack": "learned"}})
    again = CampaignJournal.open(tmp_path, "digest-a", tmp_path / "a.yaml")
    assert f"attack/{key}" in again  # the campaign resumes: the attack is not run again
    assert again.entries[f"attack/{key}"]["row"] == {"attack": key, "algorithm": "simba", "budget": 5}
    assert again.entries[f"transfer/{key}/learned"]["row"]["attack"] == key


def test_the_failure_rule() -> None:
    assert FailureRule().failed({"collision_5s": 1.0, "adversarial_loss": 1.0})
    assert not FailureRule().failed({"collision_5s": 0.0, "adversarial_loss": 99.0})
    assert FailureRule(collision=False, adversarial_loss_above=10.0).failed(
        {"collision_5s": 0.0, "adversarial_loss": 11}
    )
    assert not FailureRule().failed(None)


def test_the_failure_rule_leaves_out_the_collisions_a_finding_is_excluded_for_as_configured() -> None:
    collision = {"collision_5s": 1.0, "adversarial_loss": 1.0}
    unavoidable = {"excluded": ["unavoidable: no ego within its limits escapes (actor_into_ego, rear)"]}
    assert not FailureRule().failed(collision, unavoidable)
    assert FailureRule().failed(collision, {"excluded": []})
    assert FailureRule(exclude=("flaky", "sim_dominated")).failed(collision, unavoidable)  # not excluded for that
    assert FailureRule().counts({"adversarial": collision, "finding": unavoidable}) is False


def test_a_bo_budget_its_initial_design_fills_gets_a_note_once(bag: Path, tmp_path: Path) -> None:
    from advsim_ros.campaign.schedule import campaign_search_notes

    def notes(values: dict[str, object]) -> list[str]:
        campaign = load_campaign(_write(tmp_path, {**_good(bag), "stacks": ["reference", "learned"], **values}))
        return campaign_search_notes(expand(campaign), tmp_path / "out", tmp_path)

    (note,) = notes({"algorithms": {"bo": 20, "ga": 500}})  # 2 windows x 2 stacks x 2 actors x 2 objectives: once
    assert note.startswith("algorithms {bo: 20}: the initial design of 20 uniform queries takes the whole budget")
    assert notes({"algorithms": {"bo": 20}, "parameters": {"search": {"bo": {"initial_points": 8}}}}) == []
    assert notes({"algorithms": {"bo": 75}}) == []
