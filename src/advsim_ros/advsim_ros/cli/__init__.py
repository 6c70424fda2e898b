"""The `advsim` command: one subcommand per job; each module registers its commands and calls the logic."""

from __future__ import annotations

import argparse
import errno
import logging
import signal
import sys
import traceback
from collections.abc import Sequence

from advsim_ros import __version__
from advsim_ros.cli.attack import add_attack_commands
from advsim_ros.cli.campaign import add_campaign_commands
from advsim_ros.cli.common import CommandError
from advsim_ros.cli.data import add_data_commands, add_label_commands, add_synth_commands
from advsim_ros.cli.doctor import add_doctor_commands
from advsim_ros.cli.stacks import add_stack_commands, add_training_export_command
from advsim_ros.core.errors import UserError
from advsim_ros.export.command import add_export_commands
from advsim_ros.viz.command import add_viz_commands

__all__ = ["CommandError", "build_parser", "main"]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="advsim",
        description="AdvSim for ROS 2: find safety-critical scenarios for a LiDAR-based autonomy stack.",
    )
    parser.add_argument("--version", action="version", version=f"advsim_ros {__version__}")
    subparsers = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    # each area registers its commands: add_<area>_commands(subparsers)
    add_data_commands(subparsers)
    add_label_commands(subparsers)
    add_synth_commands(subparsers)
    add_attack_commands(subparsers)
    add_campaign_commands(subparsers)
    add_doctor_commands(subparsers)
    add_stack_commands(subparsers)
    add_viz_commands(subparsers)
    add_training_export_command(add_export_commands(subparsers))
    return parser


class Terminated(Exception):  # noqa: N818 - named after the signal
    """SIGTERM arrived: stop like Ctrl-C does, with exit code 143."""


def _on_sigterm(signum: int, frame: object) -> None:
    raise Terminated


def _os_error_text(error: OSError, args: argparse.Namespace) -> str:
    """One line for a failed read or write; a full disk names where it was writing and what is kept."""
    if error.errno != errno.ENOSPC:
        return str(error)
    where = error.filename or getattr(args, "out", None) or getattr(args, "output", None)
    place = f" writing {where}" if where else ""
    return f"no space left on the device{place}; free some and run the same command again (what finished is kept)"


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    # the library's warnings (a damaged journal line set aside, ...) as one line each on stderr
    logging.basicConfig(level=logging.WARNING, format=f"advsim {args.command}: warning: %(message)s")
    previous = signal.signal(signal.SIGTERM, _on_sigterm)
    try:
        result: int = args.run(args)
    except OSError as error:
        print(f"advsim {args.command}: error: {_os_error_text(error, args)}", file=sys.stderr)
        return 1
    except UserError as error:
        print(f"advsim {args.command}: error: {error}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(
            f"advsim {args.command}: interrupted; finished queries are kept (run the same command to resume)",
            file=sys.stderr,
        )
        return 130
    except Terminated:
        print(
            f"advsim {args.command}: terminated; finished queries are kept (run the same command to resume)",
            file=sys.stderr,
        )
        return 143
    except Exception as error:  # a bug, not the user's: one line saying so, then where it happened
        summary = " ".join(str(error).split())[:300]  # one line, whatever the message spans
        print(f"advsim {args.command}: internal error: {type(error).__name__}: {summary}", file=sys.stderr)
        traceback.print_exc()
        return 1
    finally:
        signal.signal(signal.SIGTERM, previous)
    return result
