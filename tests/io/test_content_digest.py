"""content_digest: a bag named by its content (attack fingerprints), read once per copy, kept in the cache."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest

from advsim_ros.io.cache import CACHE_ENV, cache_root, content_digest


@pytest.fixture
def bag(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    monkeypatch.setenv(CACHE_ENV, str(tmp_path / "cache"))
    folder = tmp_path / "drive"
    folder.mkdir()
    (folder / "metadata.yaml").write_text("rosbag2_bagfile_information: {}\n")
    (folder / "drive_0.mcap").write_bytes(bytes(range(256)) * 4096)
    return folder


def test_the_same_content_elsewhere_has_the_same_digest_and_a_changed_byte_another(bag: Path, tmp_path: Path) -> None:
    first = content_digest(bag)
    copy = shutil.copytree(bag, tmp_path / "node_cache" / "drive")
    assert content_digest(copy) == first
    data = bytearray((copy / "drive_0.mcap").read_bytes())
    data[1000] ^= 1  # the same size: only the bytes tell
    (copy / "drive_0.mcap").write_bytes(bytes(data))
    assert content_digest(copy) != first
    (copy / "extra").write_text("")
    assert content_digest(bag) == first


def test_the_digest_is_kept_and_a_rewritten_file_is_read_again(bag: Path) -> None:
    first = content_digest(bag)
    kept = list((cache_root() / "content-digests").glob("*.json"))
    assert len(kept) == 1
    mcap = bag / "drive_0.mcap"
    status = mcap.stat()
    mcap.write_bytes(b"\0" * status.st_size)  # rewritten: a new modification time
    os.utime(mcap, ns=(status.st_atime_ns, status.st_mtime_ns + 1_000_000))
    assert content_digest(bag) != first
    assert len(list((cache_root() / "content-digests").glob("*.json"))) == 2
