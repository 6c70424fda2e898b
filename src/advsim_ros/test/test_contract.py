"""The contract against rclpy: every message the graph and the bags exchange means the same on both paths.

The graph's nodes and the bag layer build and parse messages with rosbags (advsim_ros.contract);
stacks use rclpy's classes. For every advsim_msgs type (found from the .msg files, so a new
message is covered without touching this test) the two serialisations are byte for byte equal,
and every protocol message survives builder -> CDR -> rclpy -> CDR -> parser unchanged.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message
from rosidl_parser.definition import AbstractNestedType, BasicType, NamespacedType

from advsim_ros.contract import codec, names, topics
from advsim_ros.contract.enums import Outcome, Phase, Status
from advsim_ros.contract.plan import path_msg, plan_from_path
from advsim_ros.contract.protocol import (
    EpisodeRecord,
    FrameRequestRecord,
    ScoreRecord,
    SearchStatusRecord,
    SelectionRecord,
    episode_from_msg,
    episode_msg,
    frame_request_from_msg,
    frame_request_msg,
    perturbation_from_msg,
    perturbation_msg,
    score_from_msg,
    score_msg,
    search_status_from_msg,
    search_status_msg,
    selection_from_msg,
    selection_msg,
)
from advsim_ros.contract.scenario import drivable_area_from_grid, drivable_grid_msg, road_map_from_msg, road_map_msg
from advsim_ros.contract.tracks import TrackRecord, track_array_from_msg, track_array_msg
from advsim_ros.core.types import SOURCE_LOG, ActorClass, DrivableArea, Perturbation, Plan, RoadMap
from advsim_ros.ros.messages import message_class, message_to_dict

MSG_DIR = Path(__file__).resolve().parents[3] / "msg_defs" / "advsim_msgs" / "msg"
ADVSIM_TYPES = sorted(f"advsim_msgs/msg/{path.stem}" for path in MSG_DIR.glob("*.msg"))


def _sample(message_type: type[Any], rng: np.random.Generator) -> Any:
    """A message with every field set to a non-default value drawn from its type (rosidl introspection)."""
    message = message_type()
    for slot, name in zip(message_type.SLOT_TYPES, message_type.get_fields_and_field_types(), strict=True):
        setattr(message, name, _value(slot, rng))
    return message


def _value(slot: Any, rng: np.random.Generator) -> Any:
    if isinstance(slot, NamespacedType):
        return _sample(message_class("/".join([*slot.namespaces, slot.name])), rng)
    if isinstance(slot, AbstractNestedType):
        return [_value(slot.value_type, rng) for _ in range(2)]
    if isinstance(slot, BasicType):
        kind = slot.typename
        if kind == "boolean":
            return True
        if kind in ("float", "double"):
            return float(rng.integers(1, 100)) / 8.0  # exact in float32 as well
        if kind == "octet":
            return bytes([int(rng.integers(1, 255))])
        bits = 8 if "8" in kind else 16 if "16" in kind else 32 if "32" in kind else 63
        return int(rng.integers(1, 2 ** min(bits - 1, 31)))
    return "text"  # strings


@pytest.mark.parametrize("type_name", ADVSIM_TYPES)
def test_rclpy_and_the_contract_read_each_others_bytes_of_every_advsim_message(type_name: str) -> None:
    sample = _sample(message_class(type_name), np.random.default_rng(len(type_name)))
    decoded = codec.decode(bytes(serialize_message(sample)), type_name)  # rclpy's bytes, read by the contract
    back = deserialize_message(codec.encode(decoded), message_class(type_name))  # the contract's, read by rclpy
    assert message_to_dict(back) == message_to_dict(sample)
    assert message_to_dict(decoded) == message_to_dict(sample)
    # (the bytes themselves may differ: rclpy leaves alignment padding uninitialised, the contract writes zeros)


def _through_rclpy(value: Any) -> Any:
    """A contract message sent through rclpy: CDR -> rclpy object -> CDR -> contract object."""
    raw = codec.encode(value)
    rclpy_message = deserialize_message(raw, message_class(value.__msgtype__))
    return codec.decode(bytes(serialize_message(rclpy_message)), value.__msgtype__)


def _track(actor_id: str, steps: int = 3) -> TrackRecord:
    stamps = 1_000_000_000 + 100_000_000 * np.arange(steps, dtype=np.int64)
    return TrackRecord(
        actor_id, ActorClass.VEHICLE, np.array([4.5, 1.9, 1.6]), 0.5, stamps, np.arange(steps * 3.0).reshape(-1, 3),
        np.linspace(-0.5, 0.5, steps), np.full(steps, 7.5), np.full(steps, 0.01), np.full(steps, -0.5),
    )  # fmt: skip


def _same(a: Any, b: Any) -> bool:
    """Records equal field by field (arrays by value, floats to 1e-12, NaN equal to NaN)."""
    if hasattr(a, "__dataclass_fields__"):
        return type(a) is type(b) and all(_same(getattr(a, f), getattr(b, f)) for f in a.__dataclass_fields__)
    if isinstance(a, (tuple, list)):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, np.ndarray) and a.dtype.kind == "f":  # poses pass through quaternions: not bit-exact
        return bool(np.allclose(a, b, rtol=0.0, atol=1e-12, equal_nan=True))
    if isinstance(a, np.ndarray):
        return bool(np.array_equal(a, b))
    if isinstance(a, float) and math.isnan(a):
        return isinstance(b, float) and math.isnan(b)
    if hasattr(a, "__msgtype__"):
        return codec.encode(a) == codec.encode(b)
    return bool(a == b)


PLAN = Plan(1_100_000_000 + 100_000_000 * np.arange(4, dtype=np.int64), np.arange(8.0).reshape(4, 2), np.full(4, 0.25))
ROUND_TRIPS: dict[str, tuple[Any, Callable[[Any], Any], Callable[[Any], Any]]] = {
    names.PERTURBATION: (
        Perturbation(3, "kitti@0", ("4",), np.linspace(-1, 1, 12), "bo"),
        lambda record: perturbation_msg(record, 7),
        perturbation_from_msg,
    ),
    names.ACTOR_TRACK_ARRAY: (
        None,  # the record is built from the message below: an ActorTrackArray record
        lambda _: track_array_msg([_track("a"), _track("b", 1)], 5, "world", query_id=2, run_id=7),
        track_array_from_msg,
    ),
    names.ACTOR_SELECTION: (
        SelectionRecord("kitti@0", ("4",), 12, ("dx0", "dy0"), (_track("4"),), (1234,)),
        lambda record: selection_msg(record, 5, "world", 7),
        selection_from_msg,
    ),
    names.FRAME_REQUEST: (
        FrameRequestRecord(
            3,
            2,
            12,
            1_200_000_000,
            np.array([[0.0, -1, 0, 3], [1, 0, 0, 4], [0, 0, 1, 0.5], [0, 0, 0, 1]]),
            (_track("reacted", 1),),
        ),
        lambda record: frame_request_msg(record, "world", 7),
        frame_request_from_msg,
    ),
    names.EPISODE: (
        EpisodeRecord(
            3,
            Phase.DONE,
            9,
            10,
            (7_000_000_000, 14_000_000_000),
            10,
            9,
            Outcome.PLANS_MISSING,
            "ab",
            "cd",
            path_msg(PLAN, 1_000_000_000, "world"),
            executed=_track("ego", 5),
            reacted_actors=(_track("a", 5), _track("b", 5)),
        ),
        lambda record: episode_msg(record, 7),
        episode_from_msg,
    ),
    names.QUERY_SCORE: (
        ScoreRecord(3, Status.OK, "", 12.5, 1.0, 2.0, 3.0, 1.0, 1.0, 0.5, 1.5, 2.5, 3.5, 0.25, 10, 10, "ab", "cd"),
        lambda record: score_msg(record, 7),
        score_from_msg,
    ),
    names.SEARCH_STATUS: (
        SearchStatusRecord(12, True),
        lambda record: search_status_msg(record, 7),
        search_status_from_msg,
    ),
    names.ROAD_MAP: (
        RoadMap((np.array([[0.0, 0], [10, 0], [10, 5]]),), (np.array([[4200.125, -1500.25], [4210.5, -1490.0]]),)),
        lambda record: road_map_msg(record, 5, "world"),
        road_map_from_msg,
    ),
    names.OCCUPANCY_GRID: (
        DrivableArea(np.array([-10.0, 20.5]), 0.25, np.eye(3, 4, dtype=bool), SOURCE_LOG),
        lambda record: drivable_grid_msg(record, 5, "world"),
        drivable_area_from_grid,
    ),
    names.PATH: (PLAN, lambda record: path_msg(record, 1_000_000_000, "world"), plan_from_path),
}


@pytest.mark.parametrize("type_name", sorted(ROUND_TRIPS))
def test_every_contract_message_survives_builder_rclpy_and_parser_unchanged(type_name: str) -> None:
    record, build, parse = ROUND_TRIPS[type_name]
    built = build(record)
    if record is None:
        record = parse(built)
    assert built.__msgtype__ == type_name
    assert _same(parse(_through_rclpy(built)), record)


def test_every_protocol_topic_has_a_round_trip_and_a_run_id() -> None:
    protocol = (topics.ACTOR_SELECTION, topics.PERTURBATION, topics.PERTURBED_TRACKS, topics.FRAME_REQUEST,
                topics.EPISODE, topics.SCORE, topics.SEARCH_STATUS)  # fmt: skip
    for topic in protocol:
        assert topic.msgtype in ROUND_TRIPS
        assert "run_id" in message_class(topic.msgtype).get_fields_and_field_types()
    assert {spec.msgtype for spec in topics.ALL_TOPICS if spec.msgtype.startswith("advsim_msgs")} <= set(
        ROUND_TRIPS
    ) | {names.SCENARIO_INFO}
