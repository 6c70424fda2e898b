"""On-disk cache of built models: arrays in one .npz per key, written atomically.

The key is a hash of everything the model depends on (see ``Digest``), so a changed log
or configuration builds anew instead of reading a stale file; files are written to a
temporary name in the same folder and renamed, so a crash never leaves a partial file.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt


class Digest:
    """An incremental BLAKE2b hash over strings, numbers and arrays (shape and dtype included)."""

    def __init__(self, purpose: str) -> None:
        self._hash = hashlib.blake2b(digest_size=16)
        self.text(purpose)

    def text(self, value: str) -> None:
        encoded = value.encode()
        self._hash.update(len(encoded).to_bytes(8, "little") + encoded)

    def array(self, value: npt.ArrayLike) -> None:
        array = np.ascontiguousarray(value)
        self.text(f"{array.dtype.str}{array.shape}")
        self._hash.update(array.data.cast("B"))

    def hexdigest(self) -> str:
        return self._hash.hexdigest()


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
