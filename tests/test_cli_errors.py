"""`advsim`'s exit on an error: a user error is one line; anything else is a bug and keeps its traceback."""

from __future__ import annotations

import argparse

import pytest

from advsim_ros import cli
from advsim_ros.attack import AttackError
from advsim_ros.cli.common import CommandError
from advsim_ros.contract.codec import ContractError
from advsim_ros.core.errors import UserError
from advsim_ros.core.lidar.errors import ResimError
from advsim_ros.core.params import ParamsError
from advsim_ros.core.types import ScenarioError
from advsim_ros.io.bag import BagError
from advsim_ros.ros.launcher import LaunchError


def _stderr_of_failing(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], error: BaseException
) -> list[str]:
    """The lines `advsim fail` writes to stderr when it raises ``error`` (its exit status checked: 1)."""
    _failing(monkeypatch, error)
    assert cli.main(["fail"]) == 1
    return capsys.readouterr().err.splitlines()


def _failing(monkeypatch: pytest.MonkeyPatch, error: BaseException) -> None:
    """`advsim fail` raises ``error``."""

    def run(args: argparse.Namespace) -> int:
        raise error

    def parser() -> argparse.ArgumentParser:
        built = argparse.ArgumentParser(prog="advsim")
        commands = built.add_subparsers(dest="command", required=True)
        commands.add_parser("fail").set_defaults(run=run)
        return built

    monkeypatch.setattr(cli, "build_parser", parser)


@pytest.mark.parametrize(
    "error",
    [
        BagError("bag x: topic /lidar missing"),
        ScenarioError("window of 3 frames, 11 needed"),
        CommandError("--remap 'a': expected FROM:=TO"),
        LaunchError("the stack exited at once"),
        AttackError("OUTDIR holds another attack"),
    ],
    ids=lambda error: type(error).__name__,
)
def test_a_user_error_is_one_line_without_a_traceback_and_a_non_zero_exit(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], error: Exception
) -> None:
    assert _stderr_of_failing(monkeypatch, capsys, error) == [f"advsim fail: error: {error}"]


@pytest.mark.parametrize(
    "error",
    [ValueError("operands could not be broadcast together"), KeyError("query_id"), ZeroDivisionError("division")],
    ids=lambda error: type(error).__name__,
)
def test_an_unexpected_exception_is_a_summary_line_then_its_traceback_and_a_non_zero_exit(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], error: Exception
) -> None:
    lines = _stderr_of_failing(monkeypatch, capsys, error)
    assert lines[0] == f"advsim fail: internal error: {type(error).__name__}: {error}"
    assert lines[1] == "Traceback (most recent call last):"
    assert lines[-1].startswith(type(error).__name__)
    assert any("in run" in line for line in lines)  # where it happened


def test_a_multi_line_message_of_a_bug_still_gives_a_one_line_summary(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    lines = _stderr_of_failing(monkeypatch, capsys, RuntimeError("first\nsecond"))
    assert lines[0] == "advsim fail: internal error: RuntimeError: first second"
    assert lines[1] == "Traceback (most recent call last):"


def test_the_package_errors_are_one_family_and_scenario_errors_stay_value_errors() -> None:
    for kind in (
        ScenarioError,
        BagError,
        ContractError,
        ResimError,
        ParamsError,
        CommandError,
        LaunchError,
        AttackError,
    ):
        assert issubclass(kind, UserError), kind
    assert issubclass(ScenarioError, ValueError)  # callers that catch ValueError still catch them
    assert not issubclass(ValueError, UserError)
