"""Fuzz of the bag readers: scenario bags in both storage formats rosbags writes (MCAP, plain and zstd,
and sqlite3) truncated, byte-corrupted and made adversarial (records and chunks declaring huge sizes,
metadata.yaml corrupt or claiming huge counts, rows of the sqlite3 tables rewritten, CDR declaring huge
arrays). Every case must end in a BagError with a one-line message or a read that holds what a read
promises (sweeps with finite x, y, z; the unchanged bag read exactly as before), within its time limit
and without the process's memory growing."""

from __future__ import annotations

import re
import shutil
import sqlite3
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from advsim_ros.contract import names
from advsim_ros.contract.pointcloud import DroppedPoints
from advsim_ros.io.bag import (
    BagConfig,
    BagError,
    BagReader,
    check_lidar_sweeps,
    iter_bag_sweeps,
    read_scenario_bag,
    summarize_bag,
)
from advsim_ros.io.bag.storage import MAX_CHUNK_BYTES, cloud_points

SEED = 32  # the fuzz is reproducible: same seed, same cases
FILE_CASES = {"mcap": 260, "mcap-zstd": 160, "sqlite3": 220}  # each opens a bag (~30 ms)
METADATA_CASES = 120
MESSAGE_CASES = 3300  # CDR bytes decoded through the reader's boundary (~1 ms)
HUGE = (2**64 - 1, 2**63 - 1, 2**40, 2**32 + 7, MAX_CHUNK_BYTES + 1, 10**12)
VARIANTS = {"mcap": ("mcap", False), "mcap-zstd": ("mcap", True), "sqlite3": ("sqlite3", False)}


class Base:
    """One small scenario bag (4 frames; 3 organised sweeps with NaN and inf), its files and what it reads as."""

    def __init__(self, cloud_bags: Any, folder: Path, storage: str, compress: bool) -> None:
        clouds = {}
        for frame in range(3):
            points = cloud_bags.points(48, frame)
            points["x"][frame::5] = np.nan
            points["z"][1::7] = -np.inf
            clouds[frame] = cloud_bags.cloud_cdr(points, frame, height=3)
        self.path = cloud_bags.write(folder / "base", clouds, num_frames=4, storage=storage, compress=compress)
        self.files = {path.name: path.read_bytes() for path in self.path.iterdir()}
        (self.storage_name,) = [name for name in self.files if name != "metadata.yaml"]
        self.sweeps = [sweep.points.tobytes() for sweep in read_scenario_bag(self.path).sweeps]
        self.stamps = [cloud_bags.stamp(frame) for frame in range(3)]
        self.work = folder / "case"

    def write(self, files: dict[str, bytes]) -> Path:
        """The case's bag folder holding ``files`` (name -> bytes)."""
        shutil.rmtree(self.work, ignore_errors=True)
        self.work.mkdir()
        for name, data in files.items():
            (self.work / name).write_bytes(data)
        return self.work


@pytest.fixture(scope="module")
def bases(cloud_bags: Any, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Base]:
    folder = tmp_path_factory.mktemp("fuzz_bases")
    return {name: Base(cloud_bags, folder / name, *variant) for name, variant in VARIANTS.items()}


def _mcap_size_fields(data: bytes) -> list[int]:
    """Offsets of the uint64 sizes in an MCAP file: every record's length, a chunk's compressed and
    uncompressed sizes (in the chunk and in its index), the records inside uncompressed chunks."""
    offsets: list[int] = []
    position = 8  # after the magic
    while position + 9 <= len(data) - 8:
        op, length = data[position], int.from_bytes(data[position + 1 : position + 9], "little")
        offsets.append(position + 1)
        body = position + 9
        if op == 0x06:  # chunk: start, end, uncompressed size, crc, compression, compressed size, records
            name_length = int.from_bytes(data[body + 28 : body + 32], "little")
            sizes = body + 32 + name_length
            offsets += [body + 16, sizes]
            compressed = int.from_bytes(data[sizes : sizes + 8], "little")
            inner = sizes + 8
            while name_length == 0 and inner + 9 <= sizes + 8 + compressed:
                offsets.append(inner + 1)
                inner += 9 + int.from_bytes(data[inner + 1 : inner + 9], "little")
        elif op == 0x08:  # chunk index: ends with compressed and uncompressed size
            offsets += [body + length - 16, body + length - 8]
        position = body + length
    return offsets


# a line of a stored message definition: "<type> <field>", e.g. "float64 x" or "std_msgs/Header header"
DEFINITION_LINE = re.compile(rb"\n([A-Za-z][A-Za-z0-9_/]*(?:\[\d*\])?) ([a-z][a-z0-9_]*)")
SAME_LENGTH_TYPES = {b"float64": b"float32", b"float32": b"float64", b"uint32": b"uint16", b"uint8": b"int8"}


def _redefine(data: bytes, rng: np.random.Generator) -> bytes:
    """A field of a stored message definition renamed (one letter) or given another type of the same length."""
    lines = list(DEFINITION_LINE.finditer(data))
    line = lines[int(rng.integers(0, len(lines)))]
    buffer = bytearray(data)
    if line.group(1) in SAME_LENGTH_TYPES and rng.random() < 0.5:
        buffer[line.start(1) : line.end(1)] = SAME_LENGTH_TYPES[line.group(1)]
    else:
        at = line.start(2) + int(rng.integers(0, len(line.group(2))))
        buffer[at] = ord("q") if buffer[at] != ord("q") else ord("z")
    return bytes(buffer)


def _corrupt_bytes(data: bytes, rng: np.random.Generator, structure: list[int]) -> tuple[str, bytes]:
    """One corruption of a storage file's bytes."""
    buffer = bytearray(data)
    kind = int(rng.integers(0, 7))
    if kind == 6 and DEFINITION_LINE.search(data):  # plain MCAP stores the definitions as text
        return "a field of a stored definition renamed or retyped", _redefine(data, rng)
    if kind == 0:
        return "truncated", bytes(buffer[: int(rng.integers(0, len(buffer) + 1))])
    if kind == 1:
        for _ in range(int(rng.integers(1, 9))):
            buffer[int(rng.integers(0, len(buffer)))] = int(rng.integers(0, 256))
        return "bytes changed", bytes(buffer)
    if kind == 2 and structure:
        at = structure[int(rng.integers(0, len(structure)))]
        buffer[at : at + 8] = int(HUGE[int(rng.integers(0, len(HUGE)))]).to_bytes(8, "little")
        return "a record or chunk declaring a huge size", bytes(buffer)
    if kind == 3:
        at, width = int(rng.integers(0, len(buffer))), int(rng.choice([4, 8]))
        buffer[at : at + width] = b"\xff" * width
        return "0xff over a field", bytes(buffer[: len(data)])
    if kind == 4:
        start = int(rng.integers(0, len(buffer)))
        buffer[start : start + int(rng.integers(1, 4096))] = bytes(min(4096, len(buffer) - start))
        return "a range zeroed", bytes(buffer[: len(data)])
    return "junk appended", bytes(buffer) + rng.integers(0, 256, int(rng.integers(1, 600)), dtype=np.uint8).tobytes()


def _rewrite_rows(base: Base, rng: np.random.Generator) -> tuple[str, bytes]:
    """The sqlite3 storage with one table rewritten by SQL: valid sqlite, adversarial content."""
    database = base.work.parent / "rows.db3"
    database.write_bytes(base.files[base.storage_name])
    edits = [
        ("a message's CDR truncated", "UPDATE messages SET data = substr(data, 1, abs(random()) % length(data))"),
        ("a message on an unknown topic", "UPDATE messages SET topic_id = 999 WHERE id % 3 = 0"),
        ("a huge or negative timestamp", "UPDATE messages SET timestamp = 9223372036854775807 WHERE id % 4 = 0"),
        ("a negative timestamp", "UPDATE messages SET timestamp = -5 WHERE id % 5 = 1"),
        ("messages missing", "DELETE FROM messages WHERE id % 7 = 2"),
        ("a message that is text", "UPDATE messages SET data = 'not cdr' WHERE id % 6 = 0"),
        ("a message that is a number", "UPDATE messages SET data = 42 WHERE id % 6 = 3"),
        ("a topic of another type", "UPDATE topics SET type = 'sensor_msgs/msg/Image' WHERE id % 2 = 0"),
        ("a topic serialized as json", "UPDATE topics SET serialization_format = 'json' WHERE id = 2"),
        ("a corrupt message definition", "UPDATE message_definitions SET encoded_message_definition = 'int32[ x'"),
        ("the topics table emptied", "DELETE FROM topics"),
        ("the messages table dropped", "DROP TABLE messages"),
        (
            "a definition retyped",
            "UPDATE message_definitions SET encoded_message_definition = "
            "replace(encoded_message_definition, 'float64 x', 'float32 x')",
        ),
        (
            "a definition's field renamed",
            "UPDATE message_definitions SET encoded_message_definition = "
            "replace(encoded_message_definition, ' header', ' headex')",
        ),
    ]
    what, statement = edits[int(rng.integers(0, len(edits)))]
    with sqlite3.connect(database) as connection:
        connection.execute(statement)
    connection.close()
    return what, database.read_bytes()


def _edit_metadata(text: str, rng: np.random.Generator) -> tuple[str, str]:
    """metadata.yaml corrupted, or valid YAML claiming what is not so."""
    kind = int(rng.integers(0, 4))
    if kind == 0:
        return "truncated", text[: int(rng.integers(0, len(text)))]
    if kind == 1:
        chars = list(text)
        for _ in range(int(rng.integers(1, 6))):
            chars[int(rng.integers(0, len(chars)))] = chr(int(rng.choice([0, 9, 10, 34, 38, 42, 58, 91, 123, 0xFFFD])))
        return "characters changed", "".join(chars)
    if kind == 2:
        depth = int(rng.choice([100, 600]))  # ruamel.yaml gives up at Python's recursion limit
        return "deeply nested", "rosbag2_bagfile_information: " + "[" * depth + "]" * depth
    info = yaml.safe_load(text)["rosbag2_bagfile_information"]
    topic = info["topics_with_message_count"][int(rng.integers(0, len(info["topics_with_message_count"])))]
    value = [10**18, 2**64, -1, "many", None, [1, 2], {"a": 1}][int(rng.integers(0, 7))]
    edits: list[tuple[str, Callable[[], None]]] = [
        ("a topic's message count", lambda: topic.update(message_count=value)),
        ("the message count", lambda: info.update(message_count=value)),
        ("the duration", lambda: info["duration"].update(nanoseconds=value)),
        ("the starting time", lambda: info["starting_time"].update(nanoseconds_since_epoch=value)),
        ("a topic's name", lambda: topic["topic_metadata"].update(name=value)),
        ("a topic's type", lambda: topic["topic_metadata"].update(type=value)),
        ("the storage", lambda: info.update(storage_identifier=value)),
        ("the files", lambda: info.update(relative_file_paths=value)),
        ("the version", lambda: info.update(version=value)),
        ("the compression", lambda: info.update(compression_mode="message", compression_format="zstd")),
        ("the topics", lambda: info.update(topics_with_message_count=value)),
        ("a topic's QoS", lambda: topic["topic_metadata"].update(offered_qos_profiles=value)),
    ]
    what, edit = edits[int(rng.integers(0, len(edits)))]
    edit()
    return f"{what} set to {value!r}", yaml.safe_dump({"rosbag2_bagfile_information": info})


def _read(base: Base, bag: Path, reader: int, unchanged: bool) -> None:
    """One of the readers over the case's bag; what it returns must hold what a read promises. A huge size
    must be refused by a check, not by a failed allocation (a MemoryError)."""
    try:
        _read_with(base, bag, reader, unchanged)
    except BagError as error:
        if "MemoryError" in str(error):
            raise AssertionError(f"a huge size reached an allocation: {error}") from None
        raise


def _read_with(base: Base, bag: Path, reader: int, unchanged: bool) -> None:
    if reader == 0:
        scenario = read_scenario_bag(bag)
        for sweep in scenario.sweeps:
            assert np.all(np.isfinite(sweep.xyz))
        if unchanged:
            assert [sweep.points.tobytes() for sweep in scenario.sweeps] == base.sweeps
    elif reader == 1:
        summary = summarize_bag(bag)
        assert all(topic.message_count >= 0 for topic in summary.topics.values())
    elif reader == 2:
        stamps = check_lidar_sweeps(bag, BagConfig(), base.stamps)
        assert all(isinstance(stamp, int) for stamp in stamps)
    else:
        for _, _, points in iter_bag_sweeps(bag):
            assert np.all(np.isfinite(np.stack([points[name] for name in "xyz"]).astype(np.float64)))


def test_every_fuzzed_bag_file_reads_correctly_or_fails_with_a_bag_error(
    bases: dict[str, Base], fuzz_cases: Any
) -> None:
    rng = np.random.default_rng(SEED)
    cases = fuzz_cases((BagError,), 10.0)
    for variant, count in FILE_CASES.items():
        base = bases[variant]
        data = base.files[base.storage_name]
        structure = _mcap_size_fields(data) if variant.startswith("mcap") else []
        for index in range(count):
            if variant == "sqlite3" and index % 3 == 0:
                what, mutated = _rewrite_rows(base, rng)
            else:
                what, mutated = _corrupt_bytes(data, rng, structure)
            bag = base.write({**base.files, base.storage_name: mutated})
            reader = index % 4
            name = f"{variant} case {index}: {what} (reader {reader}, seed {SEED})"
            cases.run(
                name, lambda base=base, bag=bag, reader=reader, same=mutated == data: _read(base, bag, reader, same)
            )
    for index in range(METADATA_CASES):
        base = bases[list(VARIANTS)[index % 3]]
        what, text = _edit_metadata(base.files["metadata.yaml"].decode(), rng)
        bag = base.write({**base.files, "metadata.yaml": text.encode("utf-8", "surrogatepass")})
        cases.run(f"metadata case {index}: {what} (seed {SEED})", lambda base=base, bag=bag: _read(base, bag, 0, False))
    cases.check(minimum=sum(FILE_CASES.values()) + METADATA_CASES, memory_mb=300)


def _corrupt_cdr(raw: bytes, rng: np.random.Generator, data_length_at: int | None) -> tuple[str, bytes]:
    buffer = bytearray(raw)
    kind = int(rng.integers(0, 5))
    if kind == 0:
        return "truncated", bytes(buffer[: int(rng.integers(0, len(buffer)))])
    if kind == 1:
        for _ in range(int(rng.integers(1, 5))):
            buffer[int(rng.integers(0, len(buffer)))] = int(rng.integers(0, 256))
        return "bytes changed", bytes(buffer)
    if kind == 2 and data_length_at is not None:
        buffer[data_length_at : data_length_at + 4] = int(rng.choice([2**32 - 1, 2**31, 10**9])).to_bytes(4, "little")
        return "the point data declaring a huge length", bytes(buffer)
    # an aligned uint32 near the start (string lengths, sequence lengths, sizes) set huge
    at = 4 + 4 * int(rng.integers(0, max(1, min(len(buffer), 160) // 4 - 1)))
    buffer[at : at + 4] = int(rng.choice([2**32 - 1, 2**31 - 1, 2**24, 70_000])).to_bytes(4, "little")
    return "a length near the start set huge", bytes(buffer)


def test_every_fuzzed_message_decodes_correctly_or_fails_with_a_bag_error(
    bases: dict[str, Base], fuzz_cases: Any
) -> None:
    rng = np.random.default_rng(SEED + 1)
    cases = fuzz_cases((BagError,), 5.0)
    base = bases["mcap"]
    lidar_topic = BagConfig().lidar_topic
    with BagReader(base.path) as bag:
        connections = list(bag.reader.connections)
        messages = list(bag.raw_messages(connections))
        clouds = [message for message in messages if message[0].topic == lidar_topic]
        for index in range(MESSAGE_CASES):
            connection, stamp, raw = messages[index % len(messages)] if index % 2 else clouds[index % len(clouds)]
            lidar = connection.topic == lidar_topic
            data_length_at = None
            if lidar:  # the uint8[] data ends the message but for is_dense (1 byte)
                decoded = bag.decode(connection, stamp, raw)
                data_length_at = len(raw) - 1 - len(decoded.data) - 4
            what, mutated = _corrupt_cdr(raw, rng, data_length_at)

            def case(connection: Any = connection, stamp: int = stamp, mutated: bytes = mutated) -> None:
                message = bag.decode(connection, stamp, mutated)
                assert message.__msgtype__ == connection.msgtype
                if connection.msgtype == names.POINTCLOUD2:
                    points = cloud_points(bag, connection.topic, message, stamp, DroppedPoints())
                    assert np.all(np.isfinite(np.stack([points[n] for n in "xyz"]).astype(np.float64)))

            cases.run(f"message case {index}: {connection.topic} {what} (seed {SEED + 1})", case)
    cases.check(minimum=MESSAGE_CASES, memory_mb=200)


@pytest.mark.parametrize(
    ("old", "new", "difference"),
    [
        (
            b"uint32 height\nuint32 width",
            b"uint32 height\nuint32 widtq",
            r"unknown fields \['widtq'\]; lacks \['width'\]",
        ),
        (b"uint32 height\nuint32 width", b"uint16 height\nuint32 width", r"other types for \['height'\]"),
    ],
)
def test_a_stored_definition_unlike_the_contract_s_is_refused_naming_the_fields(
    tmp_path: Path, cloud_bags: Any, old: bytes, new: bytes, difference: str
) -> None:
    bag = cloud_bags.write(tmp_path / "bag", {0: cloud_bags.cloud_cdr(cloud_bags.points(10), 0)}, num_frames=2)
    (storage,) = bag.glob("*.mcap")
    storage.write_bytes(storage.read_bytes().replace(old, new))
    message = rf"topic /sensor/lidar/points: the bag's own definition of sensor_msgs/msg/PointCloud2 .*\({difference}\)"
    with pytest.raises(BagError, match=message):
        read_scenario_bag(bag)


def test_a_cdr_declaring_a_huge_point_array_is_refused_before_allocation(tmp_path: Path, cloud_bags: Any) -> None:
    raw = bytearray(cloud_bags.cloud_cdr(cloud_bags.points(30), 0))
    at = len(raw) - 1 - 30 * 24 - 4
    assert int.from_bytes(raw[at : at + 4], "little") == 30 * 24
    raw[at : at + 4] = (2**32 - 1).to_bytes(4, "little")
    bag = cloud_bags.write(tmp_path / "bag", {0: bytes(raw)}, num_frames=2)
    with pytest.raises(BagError, match=r"message on /sensor/lidar/points at 1000000000 ns cannot be decoded"):
        read_scenario_bag(bag)


def test_a_chunk_inflating_past_its_declared_size_is_refused_without_inflating_it() -> None:
    from rosbags.rosbag2 import storage_mcap

    bomb = storage_mcap.zstd.compress(bytes(256 << 20))  # 256 MiB of zeros in a few kB
    with pytest.raises(Exception, match="decompresses to more than its declared 4096 bytes"):
        storage_mcap.DECOMPRESSORS["zstd"](bomb, 4096)
    with pytest.raises(Exception, match=f"declares {2**40} bytes uncompressed"):
        storage_mcap.DECOMPRESSORS["lz4"](bomb, 2**40)
    assert storage_mcap.DECOMPRESSORS["zstd"](storage_mcap.zstd.compress(b"abc" * 9), 27) == b"abc" * 9
