"""The project's own cache folder (unpacked dataset archives and the like)."""

from __future__ import annotations

import os
from pathlib import Path

CACHE_ENV = "ADVSIM_CACHE_DIR"  # overrides the cache location, e.g. for tests or read-only homes


def cache_root() -> Path:
    """$ADVSIM_CACHE_DIR, else $XDG_CACHE_HOME/advsim_ros, else ~/.cache/advsim_ros (not created here)."""
    override = os.environ.get(CACHE_ENV)
    if override:
        return Path(override).expanduser()
    xdg = os.environ.get("XDG_CACHE_HOME")
    base = Path(xdg).expanduser() if xdg else Path.home() / ".cache"
    return base / "advsim_ros"
