"""One description of a bag's layout, `--bag-params FILE`, taken alike by every command that reads a bag.

The bag is a drive recorded the way a user's recorder writes it (conftest.py, RecordedYourWay): the LiDAR on
/velodyne_points in frame `velodyne`, odometry on /vehicle/odom from `odom` to `base_footprint`, tracks on
/perception/tracks; no /clock, no /tf, no ScenarioInfo. With `--bag-params` each command reads it; without,
each says in one line what it missed and how to describe it. A missing or malformed file is one line naming
it, and nothing starts. (The attack through the graph, replay and report: src/advsim_ros/test/test_bag_params_graph.py.)
"""

from __future__ import annotations

import argparse
import csv
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from advsim_ros.attack.checks import preflight
from advsim_ros.attack.options import AttackOptions, StackSpec
from advsim_ros.attack.run import _base_overrides
from advsim_ros.campaign.config import CampaignError, FailureRule, expand, load_campaign
from advsim_ros.campaign.suite import export_suite, read_index
from advsim_ros.cli import build_parser, main
from advsim_ros.core.curation import crop_frames
from advsim_ros.core.types import ScenarioError
from advsim_ros.io.bag import BagConfig, bag_layout_json, bag_layout_of, read_scenario_bag
from advsim_ros.io.synthetic import SyntheticConfig, generate_synthetic_log

HINT = "describe its layout with --bag-params FILE.yaml"
# every command that reads a bag (a path of subcommands)
READERS = (
    ("label",), ("curate",), ("attack",), ("replay",), ("doctor",), ("report",), ("campaign",), ("export", "route"),
    ("export", "openscenario"), ("stack", "run"),
)  # fmt: skip


@pytest.fixture(scope="module")
def drive(recorded_your_way: Any, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """7 s of the synthetic lead_brake street recorded the user's way, and the --bag-params file describing it."""
    log = generate_synthetic_log(np.random.default_rng(1), SyntheticConfig(family="lead_brake"))
    folder = tmp_path_factory.mktemp("drive")
    bag = recorded_your_way.write(crop_frames(log.scenario, 0, 69), folder / "my_drive")
    return bag, recorded_your_way.params(folder / "my_bag.yaml")


def _subparser(parser: argparse.ArgumentParser, path: tuple[str, ...]) -> argparse.ArgumentParser:
    for name in path:
        action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        parser = action.choices[name]
    return parser


def test_every_command_that_reads_a_bag_takes_the_same_bag_params_option() -> None:
    parser = build_parser()
    options = []
    for path in READERS:
        (option,) = [a for a in _subparser(parser, path)._actions if "--bag-params" in a.option_strings]
        options.append((tuple(option.option_strings), option.dest, option.metavar, option.help, option.default))
    assert len(set(options)) == 1, options
    assert options[0][:3] == (("--bag-params",), "bag_params", "FILE.yaml")


def _argv(path: tuple[str, ...], bag: Path, tmp_path: Path) -> list[str]:
    """The command on the bag (an OUTDIR for report, a campaign config for campaign) with an output in tmp_path/out."""
    out = str(tmp_path / "out")
    arguments = {
        "label": [str(bag), "-o", out], "curate": [str(bag)], "attack": [str(bag), "-o", out],
        "replay": [str(bag), "-o", out], "doctor": [str(bag), "-o", out], "report": [out],
        "campaign": [str(tmp_path / "campaign.yaml"), "-o", out], "route": [str(bag), "-o", out + ".csv"],
        "openscenario": [str(bag), "-o", out + ".xosc"], "run": ["modular", "--bag", str(bag), "-o", out],
    }  # fmt: skip
    return [*path, *arguments[path[-1]]]


@pytest.mark.parametrize(
    ("content", "problem"),
    [
        (None, "cannot read parameters file"),
        ("/**: [unclosed", "not valid YAML"),
        (
            "/**:\n  ros__parameters:\n    bag:\n      lidar_topic: velodyne_points\n",
            "lidar_topic: must be an absolute",
        ),
        ("/**:\n  ros__parameters:\n    bag:\n      odom_topik: /odom\n", "odom_topik"),
        ("/advsim:\n  ros__parameters: {}\n", "no entry for node /**"),
    ],
    ids=["missing", "not YAML", "bad topic", "unknown key", "no /** entry"],
)
def test_a_missing_or_malformed_file_is_one_error_line_naming_it_and_nothing_starts(
    drive: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str], content: str | None, problem: str
) -> None:
    bag, _ = drive
    params = tmp_path / "bad.yaml"
    if content is not None:
        params.write_text(content)
    for path in READERS:
        code = main([*_argv(path, bag, tmp_path), "--bag-params", str(params)])
        lines = capsys.readouterr().err.splitlines()
        assert code == 1, path
        assert len(lines) == 1, (path, lines)
        assert lines[0].startswith(f"advsim {path[0]}: error: --bag-params {params}: "), (path, lines)
        assert problem in lines[0], (path, lines)
        assert not list(tmp_path.glob("out*")), path  # no output, no run folder, no process


def _checked(bag: Path, out: Path, layout: BagConfig | None, replay_only: bool) -> Any:
    """The pre-launch checks of `advsim attack` (replay_only: of `replay` and `doctor`) with the command's overrides."""
    options = AttackOptions(
        bag=bag, out_dir=out, stack=StackSpec.reference(), queries=2, window_start_frame=0, replay_only=replay_only,
        bag_config=layout,
    )  # fmt: skip
    return preflight(options, _base_overrides(options, out / "queries.jsonl"))


@pytest.mark.parametrize("replay_only", [False, True], ids=["attack", "doctor and replay"])
def test_the_pre_launch_checks_read_the_bag_in_its_layout_and_every_graph_node_gets_it(
    drive: tuple[Path, Path], recorded_your_way: Any, tmp_path: Path, replay_only: bool
) -> None:
    bag, _ = drive
    checked = _checked(bag, tmp_path / "out", recorded_your_way.layout, replay_only)
    assert checked.bag_config == recorded_your_way.layout
    assert checked.scenario.num_frames == 70
    assert checked.scenario.actors
    for node, parameters in checked.parameters.items():  # the same merge the nodes' parameter files get
        assert BagConfig(**parameters["bag"]) == recorded_your_way.layout, node
    with pytest.raises(ScenarioError, match=rf"has no ego pose \(nav_msgs/msg/Odometry\) topic /ego/odom.*{HINT}"):
        _checked(bag, tmp_path / "out", None, replay_only)


@pytest.mark.parametrize("command", ["attack", "doctor", "replay"])
def test_without_bag_params_attack_doctor_and_replay_refuse_the_bag_in_one_line_before_starting(
    drive: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str], command: str
) -> None:
    bag, _ = drive
    window = [] if command == "replay" else ["--window-start", "0"]
    assert main([command, str(bag), "-o", str(tmp_path / "out"), *window]) == 1
    (line,) = capsys.readouterr().err.strip().splitlines()[-1:]
    assert line.startswith(f"advsim {command}: error: bag {bag} has no ego pose")
    assert HINT in line
    assert not (tmp_path / "out").exists()


def test_curate_and_export_route_read_the_bag_with_bag_params_and_refuse_it_without(
    drive: tuple[Path, Path], recorded_your_way: Any, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bag, params = drive
    route = tmp_path / "route.csv"
    assert main(["export", "route", str(bag), "-o", str(route), "--bag-params", str(params)]) == 0
    assert "route: 70 poses" in capsys.readouterr().out
    rows = list(csv.DictReader(route.open()))
    scenario = read_scenario_bag(bag, config=recorded_your_way.layout, load_sweeps=False)
    assert len(rows) == 70
    np.testing.assert_allclose([float(rows[-1]["x"]), float(rows[-1]["y"])], scenario.ego.xy[-1], atol=1e-3)
    assert main(["curate", str(bag), "--bag-params", str(params), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["windows"]
    assert main(["stack", "run", "modular", "--bag", str(bag), "--bag-params", str(params)]) == 0
    assert json.loads(capsys.readouterr().out)["sweeps"] == 70
    for argv in (["export", "route", str(bag), "-o", str(tmp_path / "again.csv")], ["curate", str(bag)]):
        assert main(argv) == 1
        (line,) = capsys.readouterr().err.strip().splitlines()[-1:]
        assert "has no ego pose (nav_msgs/msg/Odometry) topic /ego/odom" in line
        assert HINT in line
    assert not (tmp_path / "again.csv").exists()


def test_a_campaign_reads_its_bags_in_the_layout_its_entry_or_bag_params_gives(
    drive: tuple[Path, Path], recorded_your_way: Any, tmp_path: Path
) -> None:
    bag, params = drive
    values: dict[str, Any] = {
        "scenarios": [{"bag": str(bag), "windows": "curated", "bag_params": str(params)}],
        "stacks": ["reference"],
        "algorithms": {"random": 2},
    }
    config = tmp_path / "campaign.yaml"
    config.write_text(yaml.safe_dump(values))
    (plan,) = expand(load_campaign(config))
    assert plan.options(tmp_path / "out", tmp_path).bag_config == recorded_your_way.layout
    del values["scenarios"][0]["bag_params"]
    config.write_text(yaml.safe_dump(values))
    with pytest.raises(ScenarioError, match=HINT):
        expand(load_campaign(config))  # the windows are curated from the bag: it must be readable
    given = load_campaign(config, recorded_your_way.layout)  # --bag-params
    (plan,) = expand(given)
    assert plan.options(tmp_path / "out", tmp_path).bag_config == recorded_your_way.layout
    assert given.digest != load_campaign(config).digest  # another layout, another campaign folder
    values["scenarios"] = [{"synthetic": {"seeds": [0]}, "bag_params": str(params)}]
    config.write_text(yaml.safe_dump(values))
    with pytest.raises(CampaignError, match=r"scenarios\[0\]\.bag_params: only for bag and bags"):
        load_campaign(config)


def test_a_campaign_suite_keeps_the_layout_of_its_scenarios_for_regress(
    drive: tuple[Path, Path], recorded_your_way: Any, tmp_path: Path
) -> None:
    bag, _ = drive
    row = {"attack": "my_drive-w0000", "stack": "reference", "scenario": "my_drive", "window_start": 0,
           "algorithm": "random"}  # fmt: skip
    entry = {"row": row, "bag": str(bag), "adversarial": {"collision_5s": 1.0, "adversarial_loss": 2.0},
             "bag_params": bag_layout_json(recorded_your_way.layout)}  # fmt: skip
    suite = export_suite(tmp_path, [entry], FailureRule(exclude=()))
    _, (scenario,) = read_index(suite)
    assert bag_layout_of(scenario["bag_params"], "index") == recorded_your_way.layout  # what regress replays with
