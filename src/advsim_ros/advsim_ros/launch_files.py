"""What the launch files (share/advsim_ros/launch/*.launch.py) declare, and the `advsim` command line they run.

`ros2 launch advsim_ros attack.launch.py bag:=... out:=...` runs the `advsim attack` orchestrator as
one process with the launch arguments as its options, so the graph's isolation, the journal and
resume, and the outputs are the command's own. Pure Python with no ROS import: the launch files
build their description from it, and the tests check it against the command's parser without the
launch framework (the ROS 2 wheels lack it).
"""

from __future__ import annotations

import shlex
import shutil
import sys
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Literal

Kind = Literal["positional", "value", "flag", "list"]
TRUE = ("true", "1", "yes", "on")


@dataclass(frozen=True)
class Argument:
    """One launch argument: the `advsim` option it sets, the command's default as text ("": unset)."""

    name: str
    option: str  # "" for the positional bag
    default: str | None  # None: required
    description: str
    kind: Kind = "value"


_STACK = (
    Argument("stack", "--stack", "reference", '"reference", "learned", or the command line that starts your stack'),
    Argument("stack_profile", "--stack-profile", "", "stack profile FILE.yaml (replaces stack and remap)"),
    Argument("remap", "--remap", "", "CONTRACT:=YOURS topic pairs, space-separated", "list"),
    Argument("remap_file", "--remap-file", "", "YAML mapping of contract topic -> your topic"),
    Argument("remap_mode", "--remap-mode", "relay", "relay or rename"),
    Argument("no_restart", "--no-restart", "false", "true: do not restart the stack when it exits", "flag"),
    Argument("loop", "--loop", "open", "open (the decision plan is scored) or closed (the ego drives the plans)"),
    Argument(
        "reactive_actors", "--reactive-actors", "false", "true: moving vehicles react to the ego (closed loop)", "flag"
    ),
    Argument("plan_timeout", "--plan-timeout", "10.0", "longest wait for a plan per frame [s]"),
    Argument("param", "--param", "", "NODE.KEY=VALUE node parameters, space-separated (shell quoting)", "list"),
    Argument("connect_timeout", "--connect-timeout", "120.0", "longest wait for the stack to connect [s]"),
    Argument("bag_params", "--bag-params", "", "the bag's layout FILE.yaml (topics, frames; docs/data.md)"),
)

ATTACK = (
    Argument("bag", "", None, "scenario bag (rosbag2 folder)", "positional"),
    Argument("out", "--out", None, "output folder (re-using it resumes the run)"),
    *_STACK,
    Argument("algo", "--algo", "bo", "search algorithm"),
    Argument("queries", "--queries", "75", "search queries"),
    Argument("actors", "--actors", "1", "actors perturbed at once"),
    Argument("seed", "--seed", "0", "seed of the search"),
    Argument("window_start", "--window-start", "", "first frame of the 6 s window (empty: the curated one)"),
    Argument("reruns", "--reruns", "2", "evaluate the best query this many more times"),
    Argument("rerun_top", "--rerun-top", "1", "re-run the N best queries"),
    Argument("lanes", "--lanes", "1", "evaluate up to N queries of a batch at once, each on its own graph"),
    Argument("no_visuals", "--no-visuals", "false", "true: leave out bev.gif and report.html", "flag"),
)

REPLAY = (
    Argument("bag", "", None, "OUTDIR/adversarial of an attack", "positional"),
    Argument("out", "--out", "", "output folder (empty: <bag>-replay)"),
    *_STACK,
    Argument("check", "--check", "false", "true: exit 3 unless every run reproduces the recorded score", "flag"),
    Argument("runs", "--runs", "1", "how many times to replay"),
    Argument("tolerance", "--tolerance", "1e-06", "check: allowed |L_adv difference|"),
    Argument("no_visuals", "--no-visuals", "false", "true: leave out bev.gif and report.html", "flag"),
)

ARGUMENTS: dict[str, tuple[Argument, ...]] = {"attack": ATTACK, "replay": REPLAY}


def advsim_command(command: str, values: Mapping[str, str]) -> list[str]:
    """The `advsim COMMAND ...` argv for these launch argument values (those equal to the default left out).

    Run with this interpreter; under `setpriv --pdeathsig TERM` where there is one, so that the
    orchestrator ends as on SIGTERM (exit 143, finished queries kept) if `ros2 launch` dies first.
    """
    argv = [sys.executable, "-m", "advsim_ros.cli", command]
    for argument in ARGUMENTS[command]:
        value = values.get(argument.name, argument.default or "")
        if argument.kind == "positional":
            argv.append(value)
        elif argument.kind == "flag":
            if value.strip().lower() in TRUE:
                argv.append(argument.option)
        elif argument.kind == "list":
            for item in shlex.split(value):
                argv += [argument.option, item]
        elif value != "" and value != argument.default:
            argv += [argument.option, value]
    setpriv = shutil.which("setpriv")
    return argv if setpriv is None else [setpriv, "--pdeathsig", "TERM", "--", *argv]


def generate(command: str) -> object:
    """The LaunchDescription of a launch file: its arguments and one process, `advsim COMMAND` with them."""
    from launch import LaunchContext, LaunchDescription
    from launch.actions import DeclareLaunchArgument, ExecuteProcess, OpaqueFunction, Shutdown
    from launch.events.process import ProcessExited
    from launch.substitutions import LaunchConfiguration

    arguments = ARGUMENTS[command]

    def exited(event: ProcessExited, context: LaunchContext) -> list[Shutdown]:
        # launch returns 0 whatever its processes return: fail the launch when the command failed
        if event.returncode != 0:
            raise RuntimeError(f"advsim {command} exited with code {event.returncode}")
        return [Shutdown(reason=f"advsim {command} finished")]

    def orchestrator(context: LaunchContext) -> list[ExecuteProcess]:
        values = {a.name: LaunchConfiguration(a.name).perform(context) for a in arguments}
        return [
            ExecuteProcess(
                cmd=advsim_command(command, values),
                name=f"advsim_{command}",
                output="screen",
                # Ctrl-C reaches the orchestrator itself; it then stops its graph and writes its outputs:
                # give it time before launch escalates to SIGTERM (exit 143, finished queries kept).
                sigterm_timeout="30",
                sigkill_timeout="30",
                on_exit=exited,
            )
        ]

    declared = [
        DeclareLaunchArgument(a.name, description=a.description)
        if a.default is None
        else DeclareLaunchArgument(a.name, default_value=a.default, description=a.description)
        for a in arguments
    ]
    return LaunchDescription([*declared, OpaqueFunction(function=orchestrator)])
