"""The project's own cache folder (unpacked dataset archives and the like), and content digests kept there."""

from __future__ import annotations

import contextlib
import json
import os
from pathlib import Path

from advsim_ros.core.atomic import write_text_atomically
from advsim_ros.core.digest import Digest

CACHE_ENV = "ADVSIM_CACHE_DIR"  # overrides the cache location, e.g. for tests or read-only homes


def cache_root() -> Path:
    """$ADVSIM_CACHE_DIR, else $XDG_CACHE_HOME/advsim_ros, else ~/.cache/advsim_ros (not created here)."""
    override = os.environ.get(CACHE_ENV)
    if override:
        return Path(override).expanduser()
    xdg = os.environ.get("XDG_CACHE_HOME")
    base = Path(xdg).expanduser() if xdg else Path.home() / ".cache"
    return base / "advsim_ros"


def content_digest(path: Path) -> str:
    """The digest of a file's or a folder's content (every file's relative name and bytes).

    Kept in the cache by the files' paths, sizes and modification times: reading a whole log
    (300 MB, about a second) happens once per copy of it, not at every attack's start.
    """
    path = path.resolve()
    files = sorted(f for f in path.rglob("*") if f.is_file()) if path.is_dir() else [path]
    stamp = Digest("content digest key")
    stamp.text(str(path))
    for file in files:
        status = file.stat()
        stamp.text(f"{file.relative_to(path) if path.is_dir() else file.name}:{status.st_size}:{status.st_mtime_ns}")
    kept = cache_root() / "content-digests" / f"{stamp.hexdigest()}.json"
    try:
        return str(json.loads(kept.read_text())["digest"])
    except (OSError, ValueError, KeyError):
        pass
    digest = Digest("scenario bag content")
    for file in files:
        digest.text(file.relative_to(path).as_posix() if path.is_dir() else file.name)
        with file.open("rb") as stream:
            while chunk := stream.read(1 << 22):
                digest.raw(chunk)
    value = digest.hexdigest()
    with contextlib.suppress(OSError):  # a read-only cache: computed again next time
        write_text_atomically(kept, json.dumps({"path": str(path), "digest": value}))
    return value
