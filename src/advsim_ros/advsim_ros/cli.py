"""The `advsim` command: one subcommand per job; each parses arguments and calls its module."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from advsim_ros import __version__


class CommandError(RuntimeError):
    """A command failed for a reason the user can act on; printed without a traceback."""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="advsim",
        description="AdvSim for ROS 2: find safety-critical scenarios for a LiDAR-based autonomy stack.",
    )
    parser.add_argument("--version", action="version", version=f"advsim_ros {__version__}")
    subparsers = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    del subparsers  # each area adds its commands here through _add_<name>_commands(subparsers)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        result: int = args.run(args)
    except (CommandError, ValueError, OSError) as error:
        print(f"advsim {args.command}: error: {error}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"advsim {args.command}: interrupted", file=sys.stderr)
        return 130
    return result


if __name__ == "__main__":
    sys.exit(main())
