"""How a stack's processes are started: --stack repeated, the use_sim_time rule, a profile's cwd and env."""

from __future__ import annotations

import shlex
import sys
from pathlib import Path

import pytest

from advsim_ros.adapters.profile import load_profile
from advsim_ros.attack.checks import check_stack_command
from advsim_ros.attack.options import StackSpec
from advsim_ros.campaign.config import stack_spec as campaign_stack_spec
from advsim_ros.cli import build_parser
from advsim_ros.cli.attack import stack_spec
from advsim_ros.core.types import ScenarioError

SIM_TIME = ["--ros-args", "-p", "use_sim_time:=true"]


def _argv(text: str) -> list[str]:
    (process,) = StackSpec.parse(text).processes()
    return process.argv()


def test_a_command_that_hands_ros_args_on_gets_sim_time_after_its_own_ros_args() -> None:
    assert _argv("python3 node.py --ros-args -p rate:=10") == ["python3", "node.py", "--ros-args", "-p", "rate:=10",
                                                               *SIM_TIME]  # fmt: skip


@pytest.mark.parametrize(
    "command",
    [
        "python3 node.py",  # no --ros-args: it may not take them (argparse, a script, ros2 launch)
        "sh -c 'node.py --ros-args'",  # not a token of its own: inside the shell's string
        "python3 node.py --ros-args -p use_sim_time:=false",  # sets it itself
        "ros2 launch pkg stack.launch.py use_sim_time:=true",
    ],
)
def test_a_command_without_ros_args_or_setting_sim_time_itself_is_left_alone(command: str) -> None:
    assert _argv(command) == shlex.split(command)


def test_the_reference_stacks_keep_their_arguments() -> None:
    for name, module in (("reference", "modular"), ("learned", "learned")):
        spec = StackSpec.parse(name)
        (process,) = spec.processes()
        params = ["--params-file", str(spec.params_files[0])]
        assert process.argv() == [sys.executable, "-m", f"advsim_ros.stacks.{module}.node", "--ros-args", *params,
                                  "-p", "use_sim_time:=true"]  # fmt: skip


def test_stack_repeated_is_one_process_each_the_first_the_main_one_and_remaps_apply_to_all() -> None:
    args = build_parser().parse_args(
        ["attack", "bag", "-o", "out", "--stack", "python3 detector.py --ros-args", "--stack", "sh -c 'a & exec b'",
         "--remap", "/sensor/lidar/points:=/points_raw", "--remap-mode", "rename"]
    )  # fmt: skip
    spec = stack_spec(args)
    main, helper = spec.processes()
    assert (main.name, helper.name) == ("stack", "stack2")
    assert main.argv() == ["python3", "detector.py", "--ros-args", "--ros-args", "-r",
                           "/points_raw:=/sensor/lidar/points", "-p", "use_sim_time:=true"]  # fmt: skip
    assert helper.argv() == ["sh", "-c", "a & exec b", "--ros-args", "-r", "/points_raw:=/sensor/lidar/points"]
    assert spec.command == ("python3", "detector.py", "--ros-args")


def test_a_reference_stack_is_only_the_first_stack_and_the_default_is_the_reference() -> None:
    with pytest.raises(ScenarioError, match="only the first --stack may name a reference stack"):
        StackSpec.parse_all(["python3 a.py", "reference"])
    assert stack_spec(build_parser().parse_args(["attack", "bag", "-o", "out"])).name == "modular_stack"
    args = build_parser().parse_args(["doctor", "bag", "--stack", "learned", "--stack", "python3 helper.py"])
    assert [process.name for process in stack_spec(args).processes()] == ["learned_stack", "learned_stack2"]


def test_campaign_stacks_follow_the_same_sim_time_rule(tmp_path: Path) -> None:
    (own,) = campaign_stack_spec({"name": "own", "command": "python3 n.py --ros-args -p a:=1"}, tmp_path).processes()
    assert own.argv()[-3:] == SIM_TIME
    (plain,) = campaign_stack_spec({"name": "own", "command": "python3 n.py"}, tmp_path).processes()
    assert plain.argv() == ["python3", "n.py"]


def test_a_profile_process_starts_in_its_cwd_with_its_env_and_its_executable_is_found_there(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    (tmp_path / "stack").mkdir()
    script = tmp_path / "stack" / "planner"
    script.write_text("#!/bin/sh\n")
    script.chmod(0o755)
    monkeypatch.setenv("ROUTE", "route.csv")
    (tmp_path / "p.yaml").write_text(
        "processes:\n"
        "  - {name: planner, command: ./planner, cwd: stack, env: {ROUTE_FILE: $ROUTE}}\n"
        "  - {name: detector, command: ./planner --ros-args -p use_sim_time:=false, cwd: stack}\n"
    )
    spec = StackSpec.from_profile(load_profile(tmp_path / "p.yaml"))
    planner, detector = spec.processes()
    assert (planner.cwd, dict(planner.env)) == ((tmp_path / "stack").resolve(), {"ROUTE_FILE": "route.csv"})
    assert planner.argv() == ["./planner", "--ros-args", "-p", "use_sim_time:=true"]
    assert detector.argv() == ["./planner", "--ros-args", "-p", "use_sim_time:=false"]  # its own, not overridden
    check_stack_command(spec)  # ./planner is found in the process's cwd, not in the one advsim runs in
    script.chmod(0o644)
    with pytest.raises(ScenarioError, match=r"stack profile: process planner: \./planner is not an executable file"):
        check_stack_command(spec)
