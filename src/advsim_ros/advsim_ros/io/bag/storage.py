"""Opening rosbag2 folders (MCAP or sqlite3) with rosbags: errors as BagError, types from the bag itself.

A bag is self-describing: the message definitions it stores are registered first, then ROS 2
Jazzy's, advsim_msgs' and the Autoware messages' (codec.typestore) for what it lacks, so bags
written by older versions of the project (or by other tools) decode with their own definitions.
"""

from __future__ import annotations

import functools
import io
import logging
import os
import struct
import sys
from collections import defaultdict
from collections.abc import Callable, Collection, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, BinaryIO, Protocol

import apsw
import numpy as np
import yaml
from lz4.frame import LZ4FrameDecompressor
from rosbags.interfaces import Connection, MessageDefinitionFormat, Nodetype
from rosbags.rosbag2 import Reader, storage_mcap
from rosbags.rosbag2.errors import ReaderError
from rosbags.serde import SerdeError
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.base import TypesysError
from rosbags.typesys.store import Typestore

from advsim_ros.contract import codec, names, topics
from advsim_ros.contract.codec import Msg
from advsim_ros.contract.pointcloud import DroppedPoints, cloud_to_points, cloud_view, finite_mask
from advsim_ros.core.types import ScenarioError
from advsim_ros.io.bag.config import LAYOUT_HINT, BagConfig, BagError

if sys.version_info >= (3, 14):  # the zstd module rosbags' MCAP reader uses (rosbags.rosbag2.storage_mcap)
    from compression import zstd
else:
    from backports import zstd

if TYPE_CHECKING:
    from rosbags.interfaces.typing import BaseDesc, Fielddefs, FieldDesc, NameDesc, Typesdict

log = logging.getLogger(__name__)

# What rosbags and the layers under it (ruamel.yaml, apsw/sqlite3, zstd, lz4, the CDR deserializer) raise on
# truncated, corrupt or adversarial storage (a fuzz test found each). Caught around rosbags' own calls only,
# at this one boundary, and raised as BagError naming the bag and what is wrong.
_CORRUPT: tuple[type[BaseException], ...] = (
    ReaderError, SerdeError, TypesysError, apsw.Error, zstd.ZstdError, OSError, EOFError, MemoryError,
    ArithmeticError, LookupError, ValueError, TypeError, AttributeError, AssertionError, RuntimeError, struct.error,
)  # fmt: skip

# rosbags decompresses an MCAP chunk whole and checks its size afterwards: a chunk that declares (or inflates to)
# gigabytes would be allocated first. A chunk holds whole messages; no LiDAR sweep comes near this.
MAX_CHUNK_BYTES = 1 << 30


def _corrupt(what: str, error: BaseException) -> BagError:
    detail = " ".join(str(error).split())[:300] or type(error).__name__  # one line (YAML errors span several)
    return BagError(f"{what}: {detail}")


# Fields the contract gained after bags were first written: older bags' own definitions lack them, and the
# readers default them (contract/scenario.py, contract/tracks.py).
_ADDED_LATER = {("advsim_msgs/msg/ScenarioInfo", "ego_forward_offset"), ("advsim_msgs/msg/ActorTrackArray", "run_id")}


def _type_names(kind: FieldDesc | BaseDesc | NameDesc) -> list[str]:
    """The message types a rosbags field type refers to: (NAME, type), or arrays and sequences of those."""
    match kind:
        case (Nodetype.NAME, name):
            return [name]
        case (Nodetype.ARRAY | Nodetype.SEQUENCE, (element, _)):
            return _type_names(element)
    return []


def _difference(stored: Fielddefs, expected: Fielddefs) -> str:
    names, kinds = [f for f, _ in stored], dict(expected)
    unknown = [f for f in names if f not in kinds]
    missing = [f for f, _ in expected if f not in names]
    retyped = [f for f, kind in stored if f in kinds and kinds[f] != kind]
    found = (("unknown fields", unknown), ("lacks", missing), ("other types for", retyped))
    return "; ".join(f"{what} {fields}" for what, fields in found if fields) or "fields in another order"


def _count(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= 0


class _Decompressor(Protocol):
    """A streaming decompressor (zstd's ZstdDecompressor, lz4's LZ4FrameDecompressor): one frame."""

    @property
    def eof(self) -> bool: ...

    @property
    def unused_data(self) -> bytes: ...

    def decompress(self, data: bytes, max_length: int = -1) -> bytes: ...


def _bounded(decompressor: Callable[[], _Decompressor]) -> Callable[[bytes, int], bytes]:
    """A chunk decompressor that never produces more than the chunk's declared size (frame after frame)."""

    def decompress(data: bytes, size: int) -> bytes:
        if size > MAX_CHUNK_BYTES:
            raise ReaderError(f"an MCAP chunk declares {size} bytes uncompressed, more than {MAX_CHUNK_BYTES}")
        out = bytearray()
        while data:
            frame = decompressor()
            out += frame.decompress(data, max_length=size + 1 - len(out))
            if len(out) > size:
                raise ReaderError(f"an MCAP chunk decompresses to more than its declared {size} bytes")
            if not frame.eof:
                raise ReaderError("an MCAP chunk's compressed data is truncated")
            data = frame.unused_data
        return bytes(out)

    return decompress


def _read_within(bio: BinaryIO, size: int) -> bytes:
    """rosbags' read_exact, refusing a size the file (or chunk) does not hold before read() allocates it."""
    position = bio.tell()
    if isinstance(bio, io.BytesIO):
        remaining = bio.getbuffer().nbytes - position
    else:
        try:
            remaining = os.fstat(bio.fileno()).st_size - position
        except (OSError, ValueError):  # not a plain file: rosbags' own read
            return _read_exact(bio, size)
    if size > remaining:
        raise ReaderError(f"a record at offset {position} declares {size} bytes; {remaining} follow")
    return _read_exact(bio, size)


# rosbags (pinned) reads MCAP records and chunks whole: sizes are checked against what is there first, and
# decompression stops at the declared size, so a corrupt size never allocates more than the bag holds.
_read_exact = getattr(storage_mcap.read_exact, "__wrapped__", storage_mcap.read_exact)  # once, if imported again
_read_within.__wrapped__ = _read_exact  # type: ignore[attr-defined]  # functools' marker, set by hand here
storage_mcap.read_exact = _read_within
storage_mcap.DECOMPRESSORS.update(zstd=_bounded(zstd.ZstdDecompressor), lz4=_bounded(LZ4FrameDecompressor))


STORAGES = ("sqlite3", "mcap")  # the rosbag2 storage plugins rosbags reads


def _check_storage(path: Path) -> None:
    """BagError naming a storage plugin rosbags cannot read (it would say "please report issue")."""
    if not path.is_dir():
        return
    try:
        info = yaml.safe_load((path / "metadata.yaml").read_text(errors="replace"))
        storage = info["rosbag2_bagfile_information"]["storage_identifier"]
    except (yaml.YAMLError, OSError, KeyError, TypeError, ValueError, RecursionError):
        return  # rosbags reports what is wrong with the metadata itself
    if storage not in STORAGES:
        raise BagError(
            f"bag {path}: storage {storage!r} is not one this reads ({', '.join(STORAGES)}); convert it with "
            "`ros2 bag convert` to mcap or sqlite3"
        )


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
        _check_storage(self.path)
        try:
            self.reader = Reader(self.path)
            self.reader.open()
        except _CORRUPT as error:
            raise _corrupt(f"cannot open bag {self.path}, it is truncated or corrupt", error) from None
        for c in self.reader.connections:
            if not (isinstance(c.topic, str) and isinstance(c.msgtype, str) and _count(c.msgcount)):
                self.reader.close()
                raise BagError(
                    f"bag {self.path}: its metadata lists topic {c.topic!r} of type {c.msgtype!r} with "
                    f"{c.msgcount!r} messages; expected a topic name, a type name and a message count"
                )
        definitions = tuple(
            (c.topic, c.msgtype, c.msgdef.data)
            for c in self.reader.connections
            # IDL or no definition stored (older sqlite3 bags): codec.typestore()'s decodes it
            if c.msgdef.format == MessageDefinitionFormat.MSG and c.msgdef.data
        )
        try:
            self.store = _typestore(definitions, frozenset(c.msgtype for c in self.reader.connections))
        except _CORRUPT as error:
            self.reader.close()
            raise _corrupt(f"bag {self.path}: its message definitions", error) from None

    def close(self) -> None:
        try:
            self.reader.close()
        except _CORRUPT as error:
            raise _corrupt(f"bag {self.path}: closing it", error) from None

    def __enter__(self) -> BagReader:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def lidar_connection(self, configured: str, required: str) -> Connection:
        """The LiDAR's connection: the configured topic, or the bag's only PointCloud2 topic (lidar_topic_of)."""
        topic = lidar_topic_of({c.topic: c.msgtype for c in self.reader.connections}, configured)
        if topic != configured:
            _say_lidar_found(str(self.path), topic)
        found = self.connection(topic, names.POINTCLOUD2, required=required)
        assert found is not None  # required
        return found

    def connection(self, topic: str, msgtype: str, required: str = "") -> Connection | None:
        """The topic's connection; BagError when it has another type, or is missing and ``required`` says why."""
        matches = [c for c in self.reader.connections if c.topic == topic]
        if not matches:
            if required:
                available = sorted({f"{c.topic} ({c.msgtype})" for c in self.reader.connections})
                raise BagError(f"bag {self.path} has no {required} topic {topic}; it has {available}{LAYOUT_HINT}")
            return None
        if any(c.msgtype != msgtype for c in matches):
            raise BagError(f"bag {self.path}: topic {topic} has type {matches[0].msgtype}, expected {msgtype}")
        self._check_definition(topic, msgtype)
        return matches[0]

    def _check_definition(self, topic: str, msgtype: str) -> None:
        """The bag's own definition of a type the contract reads (and of the types inside it) has the contract's
        fields, in order, with their types; older bags may lack the fields added since (_ADDED_LATER)."""
        contract = codec.typestore().fielddefs
        pending, seen = [msgtype], set()
        while pending:
            name = pending.pop()
            if name in seen or name not in contract:
                continue
            seen.add(name)
            stored = list(self.store.fielddefs[name][1])
            present = {field for field, _ in stored}
            expected = [(f, kind) for f, kind in contract[name][1] if f in present or (name, f) not in _ADDED_LATER]
            if stored != expected:
                raise BagError(
                    f"bag {self.path}: topic {topic}: the bag's own definition of {name} is not the one advsim_ros "
                    f"reads ({_difference(stored, expected)}): a corrupt bag, or another message of that name"
                )
            pending += [reference for _, kind in expected for reference in _type_names(kind)]

    def messages(self, connections: list[Connection]) -> Iterator[tuple[Connection, int, Msg]]:
        """Decoded messages of these connections in time order; BagError on truncated or corrupt storage."""
        for connection, stamp, raw in self.raw_messages(connections):
            yield connection, stamp, self.decode(connection, stamp, raw)

    def decode(self, connection: Connection, stamp: int, raw: bytes) -> Msg:
        """One message's CDR bytes decoded; BagError naming the topic and stamp when they are corrupt."""
        try:
            return self.store.deserialize_cdr(raw, connection.msgtype)
        except _CORRUPT as error:
            what = f"bag {self.path}: message on {connection.topic} at {stamp} ns cannot be decoded as "
            raise _corrupt(f"{what}{connection.msgtype} (corrupt or truncated)", error) from None

    def raw_messages(self, connections: list[Connection]) -> Iterator[tuple[Connection, int, bytes]]:
        """CDR bytes of these connections in time order; checks every message listed in metadata is there."""
        counts: dict[int, int] = defaultdict(int)
        try:
            for connection, stamp, raw in self.reader.messages(connections=connections):
                counts[connection.id] += 1
                yield connection, stamp, raw
        except _CORRUPT as error:
            raise _corrupt(f"bag {self.path} is truncated or corrupt", error) from None
        for connection in connections:
            expected = connection.msgcount
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


@functools.lru_cache(maxsize=16)
def _typestore(definitions: tuple[tuple[str, str, str], ...], msgtypes: frozenset[str]) -> Typestore:
    """The bag's own message definitions (topic, type, text) first, as it is self-describing, then
    codec.typestore()'s for the types its topics (``msgtypes``) need and it lacks. Cached, and only
    what the topics need: registering every known type took ~0.1 s per bag opened."""
    store = get_typestore(Stores.EMPTY)
    for topic, msgtype, text in definitions:
        try:
            store.register(get_types_from_msg(text, msgtype))
        except TypesysError as error:
            raise TypesysError(f"topic {topic} type {msgtype}: {error}") from None
    defaults = codec.typestore().fielddefs
    added: Typesdict = {}
    seen: set[str] = set()
    pending = list(msgtypes)
    while pending:
        name = pending.pop()
        if name in seen:
            continue
        seen.add(name)
        if name in store.fielddefs:
            fields = store.fielddefs[name][1]
        elif name in defaults:
            added[name] = defaults[name]
            fields = defaults[name][1]
        else:
            continue  # unknown: decoding it names the type
        pending += [ref for _, kind in fields for ref in _type_names(kind)]
    store.register(added)
    return store


def lidar_topic_of(topic_types: Mapping[str, str], configured: str) -> str:
    """The topic the LiDAR is read from: the configured one; but when that is the contract's default (the
    user named none) and the bag lacks it, the bag's PointCloud2 topic if it has exactly one."""
    if configured in topic_types or configured != topics.LIDAR.name:
        return configured
    clouds = sorted(topic for topic, msgtype in topic_types.items() if msgtype == names.POINTCLOUD2)
    return clouds[0] if len(clouds) == 1 else configured


@functools.cache
def _say_lidar_found(path: str, topic: str) -> None:
    log.warning(f"bag {path}: LiDAR read from {topic}, its only PointCloud2 topic (lidar_topic names another)")


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
        try:
            start_ns, end_ns = (int(reader.start_time), int(reader.end_time)) if reader.message_count else (0, 0)
        except _CORRUPT as error:  # metadata.yaml's own numbers
            raise _corrupt(f"bag {path}: metadata.yaml gives no time span", error) from None
        return BagSummary(
            path=Path(path),
            storage=storage,
            topics=topics,
            start_ns=start_ns,
            end_ns=end_ns,
            size_bytes=sum(p.stat().st_size for p in files),
        )


def cloud_points(bag: BagReader, topic: str, cloud: Msg, stamp: int, dropped: DroppedPoints) -> np.ndarray:
    """The points of a PointCloud2 read from a bag, those with non-finite x, y or z dropped (tallied in
    ``dropped``: organised clouds mark missing returns with NaN); BagError naming the topic and stamp when
    the cloud is unreadable."""
    try:
        return dropped.keep_finite(cloud_to_points(cloud))
    except ScenarioError as error:
        raise BagError(f"bag {bag.path}: LiDAR topic {topic} at {stamp} ns: {error}") from None


def check_lidar_sweeps(path: Path, config: BagConfig, stamps: Collection[int]) -> set[int]:
    """The header stamps of a bag's LiDAR sweeps, each cloud checked without copying its points.

    Every cloud must be readable (x, y, z present as single numbers, sizes that its data holds);
    the sweeps at ``stamps`` (header stamps [ns]) must have at least one point with finite x, y
    and z. BagError naming the bag, topic and stamp otherwise.
    """
    wanted = set(stamps)
    found: set[int] = set()
    with BagReader(Path(path)) as bag:
        lidar = bag.lidar_connection(config.lidar_topic, required="LiDAR (sensor_msgs/msg/PointCloud2)")
        for _, stamp, cloud in bag.messages([lidar]):
            try:
                points = cloud_view(cloud)
            except ScenarioError as error:
                raise BagError(f"bag {bag.path}: LiDAR topic {lidar.topic} at {stamp} ns: {error}") from None
            header_stamp = codec.stamp_ns(cloud.header.stamp)
            found.add(header_stamp)
            if header_stamp in wanted and not np.any(finite_mask(points)):
                raise BagError(
                    f"bag {bag.path}: LiDAR topic {lidar.topic} at {header_stamp} ns: the sweep has no valid point "
                    f"({points.size} points, none with finite x, y and z)"
                )
    return found


def iter_bag_sweeps(path: Path, config: BagConfig | None = None) -> Iterator[tuple[int, str, np.ndarray]]:
    """(stamp [ns], frame_id, structured points) of every cloud on the LiDAR topic, one at a time."""
    config = config or BagConfig()
    dropped = DroppedPoints()
    with BagReader(Path(path)) as bag:
        lidar = bag.lidar_connection(config.lidar_topic, required="LiDAR")
        for _, stamp, cloud in bag.messages([lidar]):
            points = cloud_points(bag, lidar.topic, cloud, stamp, dropped)
            yield codec.stamp_ns(cloud.header.stamp), str(cloud.header.frame_id), points
    dropped.report(log, f"bag {path}", lidar.topic)
