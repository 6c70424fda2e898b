"""The CDR writers of the stacks' outputs (path_cdr, track_array_cdr) give the bytes of the message builders."""

from __future__ import annotations

import numpy as np
import pytest

from advsim_ros.contract import codec, names
from advsim_ros.contract.plan import path_cdr, path_msg
from advsim_ros.contract.tracks import TrackRecord, track_array_cdr, track_array_from_msg, track_array_msg
from advsim_ros.core.types import ActorClass, Plan


def _records(
    ids: list[str], classes: list[ActorClass], sizes: np.ndarray, confidences: np.ndarray, stamps: np.ndarray,
    states: np.ndarray,
) -> list[TrackRecord]:  # fmt: skip
    return [
        TrackRecord(
            actor_id=ids[index],
            actor_class=classes[index],
            size=sizes[index],
            confidence=float(confidences[index]),
            stamps_ns=stamps,
            xyz=states[index, :, :3],
            yaw=states[index, :, 3],
            velocity=states[index, :, 4],
            curvature=states[index, :, 5],
            acceleration=states[index, :, 6],
        )
        for index in range(len(ids))
    ]


@pytest.mark.parametrize("steps", [0, 1, 2, 50])
@pytest.mark.parametrize("frame_id", ["", "map", "world", "odom_frame"])
def test_array_encoding_matches_the_message_builder_byte_for_byte(steps: int, frame_id: str) -> None:
    rng = np.random.default_rng(steps + len(frame_id))
    count = 9
    # Ids of every length mod 4 move the states on and off 8-byte boundaries.
    ids = ["", "7", "12", "345", "6789", "10111", "ü-track", "a" * 13, "42"]
    classes = [list(ActorClass)[index % len(ActorClass)] for index in range(count)]
    sizes = rng.uniform(0.3, 6.0, (count, 3))
    confidences = rng.uniform(0.0, 1.0, count)
    stamps = 1_300_000_000_123_456_789 + 100_000_000 * np.arange(steps, dtype=np.int64)
    states = rng.normal(0.0, 50.0, (count, steps, 7))
    expected = codec.encode(
        track_array_msg(
            _records(ids, classes, sizes, confidences, stamps, states), 1_300_000_000_023_456_789, frame_id,
            query_id=5, run_id=2**40 + 3,
        )
    )  # fmt: skip
    got = track_array_cdr(
        ids, classes, sizes, confidences, stamps, states, 1_300_000_000_023_456_789, frame_id, query_id=5,
        run_id=2**40 + 3,
    )  # fmt: skip
    assert got == expected


def test_no_tracks_encode_as_the_empty_array_and_decode_back() -> None:
    empty = track_array_cdr([], [], np.zeros((0, 3)), np.zeros(0), np.array([1, 2]), np.zeros((0, 2, 7)), 7, "w")
    assert empty == codec.encode(track_array_msg([], 7, "w"))
    stamps = np.array([10, 20], dtype=np.int64)
    states = np.arange(14.0).reshape(1, 2, 7)
    raw = track_array_cdr(["3"], [ActorClass.PEDESTRIAN], np.ones((1, 3)), np.array([0.5]), stamps, states, 7, "w")
    record = track_array_from_msg(codec.decode(raw, names.ACTOR_TRACK_ARRAY)).tracks[0]
    assert (record.actor_id, record.actor_class, record.confidence) == ("3", ActorClass.PEDESTRIAN, 0.5)
    assert record.stamps_ns.tolist() == [10, 20]
    np.testing.assert_array_equal(record.xyz, states[0, :, :3])
    np.testing.assert_array_equal(record.acceleration, states[0, :, 6])


@pytest.mark.parametrize("frame_id", ["", "map", "world", "odom_frame", "wörld"])
@pytest.mark.parametrize("steps", [1, 2, 50])
def test_path_encoding_matches_the_message_builder_byte_for_byte(frame_id: str, steps: int) -> None:
    rng = np.random.default_rng(steps)
    stamps = 1_300_000_000_123_456_789 + 100_000_000 * np.arange(1, steps + 1, dtype=np.int64)
    plan = Plan(stamps_ns=stamps, xy=rng.normal(0.0, 100.0, (steps, 2)), yaws=rng.uniform(-7.0, 7.0, steps))
    for z in (0.0, -1.73):
        expected = codec.encode(path_msg(plan, 1_300_000_000_023_456_789, frame_id, z))
        assert path_cdr(plan, 1_300_000_000_023_456_789, frame_id, z) == expected
