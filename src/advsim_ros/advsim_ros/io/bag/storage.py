"""Opening rosbag2 folders (MCAP or sqlite3) with rosbags: errors as BagError, types from the bag itself.

A bag is self-describing: the message definitions it stores are registered first, then ROS 2
Jazzy's, advsim_msgs' and the Autoware messages' (codec.typestore) for what it lacks, so bags
written by older versions of the project (or by other tools) decode with their own definitions.
"""

from __future__ import annotations

import struct
from collections import defaultdict
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.interfaces import Connection, MessageDefinitionFormat
from rosbags.rosbag2 import Reader
from rosbags.rosbag2.errors import ReaderError
from rosbags.serde import SerdeError
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.base import TypesysError
from rosbags.typesys.store import Typestore

from advsim_ros.contract import codec, names
from advsim_ros.contract.pointcloud import cloud_to_points
from advsim_ros.core.types import ScenarioError
from advsim_ros.io.bag.config import BagConfig, BagError


class BagReader:
    """rosbags' Reader with errors turned into BagError and types from the bag and from advsim_msgs."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        if not self.path.exists():
            raise BagError(f"bag not found: {self.path}")
        if self.path.is_dir() and not (self.path / "metadata.yaml").is_file():
            raise BagError(
                f"{self.path} has no metadata.yaml: not a rosbag2 folder, or a recording that was not closed "
                "(`ros2 bag reindex` rebuilds it)"
            )
        try:
            self.reader = Reader(self.path)
            self.reader.open()
        except (ReaderError, OSError, KeyError, ValueError, TypeError) as error:
            raise BagError(f"cannot open bag {self.path}, it is truncated or corrupt: {error}") from None
        self.store = self._typestore()

    def _typestore(self) -> Typestore:
        """The bag's own message definitions first (it is self-describing), then codec.typestore()'s."""
        store = get_typestore(Stores.EMPTY)
        for connection in self.reader.connections:
            if connection.msgdef.format != MessageDefinitionFormat.MSG or not connection.msgdef.data:
                continue  # IDL or no definition stored (older sqlite3 bags): the defaults below decode it
            try:
                store.register(get_types_from_msg(connection.msgdef.data, connection.msgtype))
            except TypesysError as error:
                raise BagError(
                    f"bag {self.path}: topic {connection.topic} type {connection.msgtype}: {error}"
                ) from None
        defaults = codec.typestore().fielddefs
        store.register({name: value for name, value in defaults.items() if name not in store.fielddefs})
        return store

    def close(self) -> None:
        self.reader.close()

    def __enter__(self) -> BagReader:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def connection(self, topic: str, msgtype: str, required: str = "") -> Connection | None:
        """The topic's connection; BagError when it has another type, or is missing and ``required`` says why."""
        matches = [c for c in self.reader.connections if c.topic == topic]
        if not matches:
            if required:
                available = sorted({f"{c.topic} ({c.msgtype})" for c in self.reader.connections})
                raise BagError(f"bag {self.path} has no {required} topic {topic}; it has {available}")
            return None
        if any(c.msgtype != msgtype for c in matches):
            raise BagError(f"bag {self.path}: topic {topic} has type {matches[0].msgtype}, expected {msgtype}")
        return matches[0]

    def messages(self, connections: list[Connection]) -> Iterator[tuple[Connection, int, Any]]:
        """Decoded messages of these connections in time order; BagError on truncated or corrupt storage."""
        for connection, stamp, raw in self.raw_messages(connections):
            try:
                decoded = self.store.deserialize_cdr(raw, connection.msgtype)
            except (SerdeError, ValueError, IndexError, AssertionError, struct.error) as error:
                raise BagError(
                    f"bag {self.path}: message on {connection.topic} at {stamp} ns cannot be decoded "
                    f"as {connection.msgtype} (corrupt or truncated): {error}"
                ) from None
            yield connection, stamp, decoded

    def raw_messages(self, connections: list[Connection]) -> Iterator[tuple[Connection, int, bytes]]:
        """CDR bytes of these connections in time order; checks every message listed in metadata is there."""
        counts: dict[int, int] = defaultdict(int)
        try:
            for connection, stamp, raw in self.reader.messages(connections=connections):
                counts[connection.id] += 1
                yield connection, stamp, raw
        except (ReaderError, OSError, EOFError) as error:
            raise BagError(f"bag {self.path} is truncated or corrupt: {error}") from None
        for connection in connections:
            expected = int(connection.msgcount)
            if counts[connection.id] < expected:
                raise BagError(
                    f"bag {self.path} is truncated: metadata lists {expected} messages on {connection.topic} "
                    f"but the storage holds {counts[connection.id]}"
                )


@dataclass(frozen=True)
class TopicSummary:
    """One topic of a bag as metadata.yaml lists it."""

    msgtype: str
    message_count: int


@dataclass(frozen=True)
class BagSummary:
    """What a bag holds, without decoding messages."""

    path: Path
    storage: str  # "mcap" or "sqlite3"
    topics: dict[str, TopicSummary] = field(default_factory=dict)
    start_ns: int = 0  # time of the first message [ns]
    end_ns: int = 0  # just after the last message (exclusive end) [ns]
    size_bytes: int = 0  # storage files on disk [bytes]


def summarize_bag(path: Path) -> BagSummary:
    """Topics, message counts, time span and size of a bag (reads only its metadata and index)."""
    with BagReader(Path(path)) as bag:
        reader = bag.reader
        topics = {
            name: TopicSummary(msgtype=info.msgtype or "", message_count=int(info.msgcount))
            for name, info in reader.topics.items()
        }
        root = Path(path)
        files = [p for p in root.iterdir() if p.suffix in (".mcap", ".db3")] if root.is_dir() else [root]
        storage = "sqlite3" if any(p.suffix == ".db3" for p in files) else "mcap"
        return BagSummary(
            path=Path(path),
            storage=storage,
            topics=topics,
            start_ns=int(reader.start_time) if reader.message_count else 0,
            end_ns=int(reader.end_time) if reader.message_count else 0,
            size_bytes=sum(p.stat().st_size for p in files),
        )


def cloud_points(bag: BagReader, topic: str, cloud: Any, stamp: int) -> np.ndarray:
    """The points of a PointCloud2 read from a bag; BagError naming the topic and stamp when unreadable."""
    try:
        return cloud_to_points(cloud)
    except ScenarioError as error:
        raise BagError(f"bag {bag.path}: LiDAR topic {topic} at {stamp} ns: {error}") from None


def iter_bag_sweeps(path: Path, config: BagConfig | None = None) -> Iterator[tuple[int, str, np.ndarray]]:
    """(stamp [ns], frame_id, structured points) of every cloud on the LiDAR topic, one at a time."""
    config = config or BagConfig()
    with BagReader(Path(path)) as bag:
        lidar = bag.connection(config.lidar_topic, names.POINTCLOUD2, required="LiDAR")
        assert lidar is not None
        for _, stamp, cloud in bag.messages([lidar]):
            points = cloud_points(bag, lidar.topic, cloud, stamp)
            yield codec.stamp_ns(cloud.header.stamp), str(cloud.header.frame_id), points
