"""A campaign's storage: where its jobs' inputs and outputs meet when Ray nodes share no folder (fsspec).

A storage is a URI every node of the cluster can reach: ``s3://BUCKET/PREFIX`` (S3 or an S3-compatible
server; each node's own environment names the credentials and, for a server of your own, its endpoint:
``AWS_ACCESS_KEY_ID``, ``AWS_SECRET_ACCESS_KEY``, ``AWS_ENDPOINT_URL``), ``gs://BUCKET/PREFIX`` (gcsfs),
``file:///a/folder/every/node/mounts``, or a plain path. Under it:

    inputs/DIGEST/manifest.json     one input of the campaign's jobs (a scenario bag, a parameter file),
    inputs/DIGEST/NAME[/...]        uploaded once by the driver, keyed by the digest of its content;
                                    the manifest is written last: an input without one is incomplete
    attacks/KEY/..., transfer/...   each job's outputs, as they lie in OUTDIR; job_result.json last

A node keeps what it downloaded of the inputs in its own cache folder (``cache_root()/campaign-inputs``,
one download per digest and node), so a bag attacked many times crosses the network once per node.
Keys are '/'-separated paths relative to the storage's root.
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import fsspec
import yaml
from fsspec.implementations.local import LocalFileSystem

from advsim_ros.campaign.config import CampaignError
from advsim_ros.core.atomic import atomic_file, atomic_folder
from advsim_ros.core.lidar.cache import build_lock
from advsim_ros.io.cache import cache_root, content_digest, content_files

MANIFEST_NAME = "manifest.json"
INPUTS = "inputs"


class Storage:
    """One campaign storage by URI; counts the bytes this process sent to it and received from it."""

    def __init__(self, uri: str) -> None:
        self.uri = uri
        self.fs, root = fsspec.core.url_to_fs(uri)
        self.root = str(root).rstrip("/") or "/"
        self.sent = 0  # [bytes]
        self.received = 0  # [bytes]

    @property
    def local_root(self) -> Path | None:
        """The storage's folder when it is one on this machine's file system (file:// or a plain path)."""
        return Path(self.root) if isinstance(self.fs, LocalFileSystem) else None

    def _path(self, key: str) -> str:
        return f"{self.root}/{key.strip('/')}" if key.strip("/") else self.root

    def exists(self, key: str) -> bool:
        path = self._path(key)
        self.fs.invalidate_cache(path)  # another process (a worker, the driver) may have written it since
        return bool(self.fs.exists(path))

    def read_bytes(self, key: str) -> bytes:
        data = bytes(self.fs.cat_file(self._path(key)))
        self.received += len(data)
        return data

    def read_json(self, key: str) -> Any:  # a JSON document: its reader knows its format
        return json.loads(self.read_bytes(key))

    def write_bytes(self, key: str, data: bytes) -> None:
        """Whole or not at all: on a file system renamed into place, in an object store one PUT of the object."""
        local = self.local_root
        if local is not None:
            with atomic_file(local / key, "wb") as stream:
                stream.write(data)
        else:
            self.fs.pipe_file(self._path(key), data)
        self.sent += len(data)

    def write_json(self, key: str, document: Any) -> None:  # any JSON document (json.dumps takes Any)
        self.write_bytes(key, json.dumps(document, indent=2).encode())

    def put_file(self, source: Path, key: str) -> None:
        path = self._path(key)
        if self.local_root is not None:
            Path(path).parent.mkdir(parents=True, exist_ok=True)
        self.fs.put_file(str(source), path)
        self.sent += source.stat().st_size

    def get_file(self, key: str, target: Path) -> None:
        target.parent.mkdir(parents=True, exist_ok=True)
        self.fs.get_file(self._path(key), str(target))
        self.received += target.stat().st_size

    def files(self, key: str) -> list[str]:
        """The files under key, relative to it, sorted (none when nothing is stored there)."""
        path = self._path(key)
        self.fs.invalidate_cache(path)
        prefix = path.rstrip("/") + "/"
        found = self.fs.find(path) if self.fs.exists(path) else []
        return sorted(str(p)[len(prefix) :] for p in found if str(p).startswith(prefix))

    def remove(self, key: str) -> None:
        """Remove what is stored under key (a file, or a folder and all it holds); nothing when nothing is."""
        if self.exists(key):
            self.fs.rm(self._path(key), recursive=True)

    def put_tree(self, source: Path, key: str, skip: Iterable[str] = ()) -> None:
        """Upload a file, or every file of a folder under key (but those named in skip, relative to source)."""
        left_out = set(skip)
        for name, file in content_files(source):
            if name not in left_out:
                self.put_file(file, f"{key}/{name}" if name else key)

    def get_tree(self, key: str, target: Path) -> None:
        """Download every file under key into the folder target."""
        for name in self.files(key):
            self.get_file(f"{key}/{name}", target / name)

    # ----- inputs, keyed by the digest of their content ------------------------------------------

    def put_input(self, source: Path) -> dict[str, str]:
        """Upload a file or folder once (kept when an input of the same content is there); its reference."""
        digest = content_digest(source)
        key = f"{INPUTS}/{digest}"
        if self.exists(f"{key}/{MANIFEST_NAME}"):
            return {"digest": digest, "name": str(self.read_json(f"{key}/{MANIFEST_NAME}")["name"])}
        self.put_tree(source, f"{key}/{source.name}")
        self.write_json(f"{key}/{MANIFEST_NAME}", {"digest": digest, "name": source.name})  # complete now
        return {"digest": digest, "name": source.name}

    def fetch_input(self, reference: dict[str, str], cache: Path | None = None) -> Path:
        """The input's path in this node's cache, downloaded (and its digest checked) when it is not there yet.

        Jobs on one node that need the same input at once download it once: one downloads under a lock in
        the cache folder (a lock of this node only), the others wait and find it there."""
        digest, name = reference["digest"], reference["name"]
        folder = (cache or cache_root() / "campaign-inputs") / digest
        with build_lock(folder):
            if not (folder / MANIFEST_NAME).is_file():
                with atomic_folder(folder, overwrite=True) as staged:
                    self.get_tree(f"{INPUTS}/{digest}", staged)
                    if not (staged / MANIFEST_NAME).is_file():
                        raise CampaignError(f"{self.uri}: input {digest} is not in the storage (or incomplete)")
                    if content_digest(staged / name) != digest:
                        raise CampaignError(f"{self.uri}: input {digest} ({name}) arrived with another content")
        return folder / name


def storage_uri(config: Path, given: str | None) -> str | None:
    """The campaign's storage: ``--storage`` (given), else the config's ``storage:``, else None (OUTDIR itself).

    A plain path is a folder: relative to the working folder on the command line, to the config's folder in it.
    """
    if given is not None:
        return _absolute(given, Path.cwd())
    try:
        values = yaml.safe_load(Path(config).read_text(encoding="utf-8"))
    except (OSError, yaml.YAMLError):
        return None  # config.load_campaign names the problem
    value = values.get("storage") if isinstance(values, dict) else None
    if value is None:
        return None
    if not isinstance(value, str) or not value.strip():
        raise CampaignError(f"{Path(config).resolve()}: storage: expected a URI (s3://BUCKET/PREFIX, file:///...)")
    return _absolute(value, Path(config).resolve().parent)


def _absolute(uri: str, base: Path) -> str:
    if "://" in uri:
        return uri
    return (base / uri).resolve().as_uri()
