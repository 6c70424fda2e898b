"""On-disk cache of built models: arrays in one .npz per key, written atomically.

The key is a hash of everything the model depends on (see ``core.digest.Digest``), so a changed log
or configuration builds anew instead of reading a stale file; files are written to a
temporary name in the same folder and renamed, so a crash never leaves a partial file.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import tempfile
import zipfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np


def load_arrays(path: Path) -> dict[str, np.ndarray] | None:
    """The arrays stored at path, or None when the file is missing or unreadable (then it is rebuilt)."""
    if not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as archive:
            return {name: archive[name] for name in archive.files}
    except (OSError, ValueError, zipfile.BadZipFile, EOFError):
        return None


def save_arrays(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """Store arrays at path atomically (temporary file in the same folder, then rename)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    handle, temporary = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=".npz.tmp", dir=path.parent)
    try:
        named: dict[str, Any] = dict(arrays)
        with os.fdopen(handle, "wb") as stream:
            np.savez(stream, **named)
        os.replace(temporary, path)
    except BaseException:
        Path(temporary).unlink(missing_ok=True)
        raise


@contextlib.contextmanager
def build_lock(path: Path) -> Iterator[None]:
    """An exclusive lock beside path while held: of the attacks that need the same file at once, one builds
    it and the others wait and read it (a campaign's attacks of one log). The kernel drops it with its process.

    The lock is one node's: caches live in each node's own cache folder (io.cache.cache_root), so each node of a
    cluster builds or loads its own. Nothing relies on it across machines: the file is keyed by what it is built
    from and written whole under a temporary name, then renamed, so builders the lock does not reach (a cache
    folder several nodes mount) cost a second build at worst, never a torn or stale file."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path.with_name(f"{path.name}.lock"), "a", encoding="utf-8") as stream:
        fcntl.flock(stream.fileno(), fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(stream.fileno(), fcntl.LOCK_UN)
