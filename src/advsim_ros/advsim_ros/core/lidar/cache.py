"""On-disk cache of built models: arrays in one .npz per key, written atomically.

The key is a hash of everything the model depends on (see ``core.digest.Digest``), so a changed log
or configuration builds anew instead of reading a stale file; files are written to a
temporary name in the same folder and renamed, so a crash never leaves a partial file.
"""

from __future__ import annotations

import os
import tempfile
import zipfile
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
