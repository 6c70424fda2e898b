"""The project's own cache folder (unpacked dataset archives and the like), and content digests kept there."""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
from collections.abc import Iterator
from pathlib import Path

from advsim_ros.core.atomic import write_text_atomically

CACHE_ENV = "ADVSIM_CACHE_DIR"  # overrides the cache location, e.g. for tests or read-only homes


def cache_root() -> Path:
    """$ADVSIM_CACHE_DIR, else $XDG_CACHE_HOME/advsim_ros, else ~/.cache/advsim_ros (not created here)."""
    override = os.environ.get(CACHE_ENV)
    if override:
        return Path(override).expanduser()
    xdg = os.environ.get("XDG_CACHE_HOME")
    base = Path(xdg).expanduser() if xdg else Path.home() / ".cache"
    return base / "advsim_ros"


def content_files(root: Path) -> Iterator[tuple[str, Path]]:
    """(name relative to root, path) of every file of a folder, sorted; ("", root) for a file."""
    if root.is_file():
        yield "", root
        return
    found = []
    for folder, _, names in os.walk(root):
        for name in names:
            path = Path(folder) / name
            found.append((path.relative_to(root).as_posix(), path))
    yield from sorted(found)


def content_digest(path: Path) -> str:
    """The digest of a file's or a folder's content: its files' names (relative to it), sizes and bytes.

    Kept in the cache by the files' paths, sizes and modification times: reading a whole log
    (300 MB, about a second) happens once per copy of it, not at every attack's or campaign's start.
    """
    path = path.resolve()
    files = [(name, file, file.stat()) for name, file in content_files(path)]
    key = hashlib.sha256(str(path).encode())
    for name, _, status in files:
        key.update(f"\0{name}\0{status.st_size}\0{status.st_mtime_ns}".encode())
    kept = cache_root() / "content-digests" / f"{key.hexdigest()[:32]}.json"
    with contextlib.suppress(OSError, ValueError, KeyError):
        return str(json.loads(kept.read_text())["digest"])
    digest = hashlib.sha256()
    for name, file, status in files:
        with file.open("rb") as stream:
            own = hashlib.file_digest(stream, "sha256").hexdigest()
        digest.update(f"{name}\0{status.st_size}\0{own}\n".encode())
    value = digest.hexdigest()[:32]
    with contextlib.suppress(OSError):  # a read-only cache: computed again next time
        write_text_atomically(kept, json.dumps({"path": str(path), "digest": value}))
    return value
