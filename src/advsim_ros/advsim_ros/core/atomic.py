"""Atomic outputs: a file or a folder appears complete at its path, or not at all.

Everything is first written under a hidden temporary name in the target's own folder (same
file system, so the final rename is atomic) and renamed into place when complete. Replacing
an existing target (``overwrite``) keeps the old one until the new one is in place and puts
it back if the rename fails, so a crash or a full disk never leaves a partial or missing
output where a complete one stood.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

from advsim_ros.core.types import ScenarioError


class OutputExistsError(ScenarioError):
    """The output path exists and overwriting was not asked for."""


@contextlib.contextmanager
def atomic_file(path: Path, mode: str = "w") -> Iterator[IO[Any]]:
    """A stream to a temporary file beside ``path``; renamed onto ``path`` (fsync'd) when the block ends cleanly."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    handle, temporary = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with open(handle, mode, encoding=None if "b" in mode else "utf-8") as stream:
            yield stream
            stream.flush()
            os.fsync(stream.fileno())
        os.chmod(temporary, 0o666 & ~_umask())  # mkstemp makes it private; outputs get the usual mode
        os.replace(temporary, path)
    except BaseException:
        Path(temporary).unlink(missing_ok=True)
        raise


def _umask() -> int:
    current = os.umask(0)
    os.umask(current)
    return current


def write_text_atomically(path: Path, text: str) -> None:
    with atomic_file(path) as stream:
        stream.write(text)


def write_json_atomically(path: Path, document: Any) -> None:
    with atomic_file(path) as stream:
        json.dump(document, stream, indent=2)


def publish_folder(staged: Path, target: Path, overwrite: bool) -> None:
    """Move a finished folder (or file) into place; an old target (overwrite only) goes only after that succeeded."""
    if target.exists() or target.is_symlink():
        if not overwrite:
            raise OutputExistsError(f"{target} exists already; remove it or choose another output path")
        trash = Path(tempfile.mkdtemp(prefix=f".{target.name}.old-", dir=target.parent))
        os.replace(target, trash / target.name)
        try:
            os.replace(staged, target)
        except OSError:
            os.replace(trash / target.name, target)
            raise
        finally:
            shutil.rmtree(trash, ignore_errors=True)
    else:
        os.replace(staged, target)


@contextlib.contextmanager
def atomic_folder(target: Path, overwrite: bool = False) -> Iterator[Path]:
    """A path in a hidden staging folder beside ``target``, published at ``target`` when the block ends cleanly."""
    target = Path(target)
    if (target.exists() or target.is_symlink()) and not overwrite:
        raise OutputExistsError(f"{target} exists already; remove it or choose another output path")
    target.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{target.name}.partial-", dir=target.parent))
    try:
        yield staging / target.name
        publish_folder(staging / target.name, target, overwrite)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
