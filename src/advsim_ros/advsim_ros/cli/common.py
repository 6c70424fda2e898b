"""What every `advsim` subcommand shares: the error type printed as one line, printing a result."""

from __future__ import annotations

from advsim_ros.core.errors import UserError


class CommandError(UserError, RuntimeError):
    """A command failed for a reason the user can act on; printed without a traceback."""


def print_result(text: str) -> int:
    """Print a command's result; exit code 0."""
    print(text)
    return 0
