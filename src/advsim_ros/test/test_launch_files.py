"""The launch files (launch/*.launch.py, installed to share/advsim_ros/launch): the command's attack and replay.

Everywhere: their arguments are the options of `advsim attack` / `replay` with the command's
defaults, and the command line they run is the one a user types. Where the ROS 2 launch framework
is installed (a full ROS 2 install, the docker build; the wheels lack it, so these skip in the venv):
the launch files load and resolve to that command line, and an attack started through LaunchService
is the command's attack (the command resumes its journal instead of refusing it).
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import shutil
import sys
from pathlib import Path
from typing import Any

import pytest

from advsim_ros.cli import build_parser
from advsim_ros.launch_files import ARGUMENTS, advsim_command

LAUNCH_DIR = Path(__file__).resolve().parents[1] / "launch"
COMMANDS = sorted(ARGUMENTS)


def _has_launch_framework() -> bool:
    try:
        return importlib.util.find_spec("launch.launch_description_sources") is not None
    except ImportError:
        return False


needs_launch = pytest.mark.skipif(
    not _has_launch_framework(), reason="the ROS 2 launch framework is not installed (the wheels lack it)"
)


def _subparser(command: str) -> argparse.ArgumentParser:
    parser = build_parser()
    subparsers = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return subparsers.choices[command]


def _options(command: str) -> dict[str, argparse.Action]:
    """The command's options by their long name ("" for the positional bag)."""
    actions = [a for a in _subparser(command)._actions if not isinstance(a, argparse._HelpAction)]
    return {max(a.option_strings, key=len, default=""): a for a in actions}


def _typed(argv: list[str]) -> list[str]:
    """The `advsim ...` part of a launch file's command line (after setpriv and the interpreter)."""
    return argv[argv.index("advsim_ros.cli") + 1 :]


def _required(command: str) -> dict[str, str]:
    return {"bag": "logs/drive", "out": "out/drive"} if command == "attack" else {"bag": "out/drive/adversarial"}


@pytest.mark.parametrize("command", COMMANDS)
def test_the_launch_arguments_are_the_options_of_the_command(command: str) -> None:
    assert sorted(a.option for a in ARGUMENTS[command]) == sorted(_options(command))


@pytest.mark.parametrize("command", COMMANDS)
def test_the_launch_defaults_are_the_commands(command: str) -> None:
    options = _options(command)
    base = [_required(command)["bag"], *(["--out", "out/drive"] if command == "attack" else [])]
    plain = _subparser(command).parse_args(base)
    for argument in ARGUMENTS[command]:
        if argument.default is None or argument.kind == "positional":
            continue
        dest = options[argument.option].dest
        if argument.kind == "flag":
            assert (argument.default, getattr(plain, dest)) == ("false", False), argument.name
        elif argument.kind == "list":
            assert (argument.default, getattr(plain, dest)) == ("", []), argument.name
        elif argument.default == "":
            assert getattr(plain, dest) is None, argument.name
        else:
            given = _subparser(command).parse_args([*base, argument.option, argument.default])
            assert getattr(given, dest) == getattr(plain, dest), argument.name


def test_the_attack_command_line_is_the_one_a_user_types() -> None:
    values = {
        "bag": "logs/drive", "out": "out/drive", "stack_profile": "my stack.yaml", "no_restart": "true",
        "param": "perturber.num_candidates=20000 'scorer.note=a b'", "algo": "ga", "queries": "1",
        "window_start": "3", "reruns": "2", "plan_timeout": "5",
    }  # fmt: skip
    typed = [
        "attack", "logs/drive", "--out", "out/drive", "--stack-profile", "my stack.yaml", "--no-restart",
        "--plan-timeout", "5", "--param", "perturber.num_candidates=20000", "--param", "scorer.note=a b",
        "--algo", "ga", "--queries", "1", "--window-start", "3",
    ]  # fmt: skip
    argv = advsim_command("attack", values)
    assert _typed(argv) == typed  # values equal to the default (reruns 2) are left to the command
    assert argv[argv.index("-m") - 1] == sys.executable
    if shutil.which("setpriv"):  # ends as on SIGTERM (finished queries kept) when ros2 launch dies
        assert argv[:4] == [shutil.which("setpriv"), "--pdeathsig", "TERM", "--"]
    assert _typed(advsim_command("attack", _required("attack"))) == ["attack", "logs/drive", "--out", "out/drive"]


def test_the_replay_command_line_is_the_one_a_user_types() -> None:
    values = {**_required("replay"), "remap": "/sensor/lidar/points:=/points_raw /plan:=/my_plan", "check": "True"}
    assert _typed(advsim_command("replay", values)) == [
        "replay", "out/drive/adversarial", "--remap", "/sensor/lidar/points:=/points_raw", "--remap",
        "/plan:=/my_plan", "--check",
    ]  # fmt: skip
    assert build_parser().parse_args(_typed(advsim_command("replay", {**values, "check": "false"}))).check is False


@pytest.mark.parametrize("command", COMMANDS)
def test_each_launch_file_runs_its_command_and_is_installed(command: str) -> None:
    text = (LAUNCH_DIR / f"{command}.launch.py").read_text()
    assert f'generate("{command}")' in text
    assert 'glob("launch/*.launch.py")' in (LAUNCH_DIR.parent / "setup.py").read_text()


def _resolve(command: str, values: dict[str, str]) -> tuple[list[str], list[str]]:
    """The launch file loaded and resolved by the launch framework: its argument names and command line."""
    from launch import LaunchContext
    from launch.actions import DeclareLaunchArgument, OpaqueFunction
    from launch.launch_description_sources import get_launch_description_from_python_launch_file
    from launch.utilities import perform_substitutions

    description = get_launch_description_from_python_launch_file(str(LAUNCH_DIR / f"{command}.launch.py"))
    context = LaunchContext()
    context.launch_configurations.update(values)
    for entity in description.entities:
        if isinstance(entity, DeclareLaunchArgument):
            entity.visit(context)  # the default where no value is given; an error where a required one is missing
    (opaque,) = [e for e in description.entities if isinstance(e, OpaqueFunction)]
    (process,) = opaque.execute(context)
    names = [argument.name for argument in description.get_launch_arguments()]
    return names, [perform_substitutions(context, part) for part in process.cmd]


@needs_launch
@pytest.mark.parametrize("command", COMMANDS)
def test_the_launch_framework_resolves_the_launch_file_to_the_command(command: str) -> None:
    values = {**_required(command), "queries" if command == "attack" else "runs": "3", "param": "scorer.a=1"}
    names, argv = _resolve(command, values)
    assert names == [argument.name for argument in ARGUMENTS[command]]
    assert argv == advsim_command(command, values)
    with pytest.raises(Exception, match="bag"):
        _resolve(command, {})


@needs_launch
@pytest.mark.slow
def test_an_attack_through_the_launch_file_is_the_commands_attack(
    synthetic_bag: Path, tmp_path: Path, advsim: Any
) -> None:
    from launch import LaunchDescription, LaunchService
    from launch.actions import IncludeLaunchDescription
    from launch.launch_description_sources import PythonLaunchDescriptionSource

    out = tmp_path / "out"
    arguments = {
        "bag": str(synthetic_bag), "out": str(out), "algo": "random", "queries": "1", "reruns": "0",
        "param": "perturber.num_candidates=20000",
    }  # fmt: skip
    service = LaunchService()
    source = PythonLaunchDescriptionSource(str(LAUNCH_DIR / "attack.launch.py"))
    service.include_launch_description(
        LaunchDescription([IncludeLaunchDescription(source, launch_arguments=arguments.items())])
    )
    assert service.run() == 0
    summary = json.loads((out / "summary.json").read_text())
    assert [q["score"]["status"] for q in summary["queries"]] == ["ok", "ok"]  # the original and one query
    header = (out / "queries.jsonl").read_text().splitlines()[0]
    # the same attack typed as a command: it resumes the journal (another attack's is refused), nothing to redo
    again = advsim(
        "attack", str(synthetic_bag), "--algo", "random", "--queries", "1", "--reruns", "0",
        "--param", "perturber.num_candidates=20000", "-o", str(out),
    )  # fmt: skip
    assert again.returncode == 0, again.stderr
    assert (out / "queries.jsonl").read_text().splitlines()[0] == header
    assert json.loads((out / "summary.json").read_text())["queries"] == summary["queries"]
