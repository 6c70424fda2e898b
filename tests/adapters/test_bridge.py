"""What stack_adapter does for a profile (adapters.bridge): relays, conversions, and the contract's answers."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from advsim_ros.adapters import bridge
from advsim_ros.adapters.profile import StackProfile, load_profile, profile_from_mapping
from advsim_ros.contract import codec, names, topics
from advsim_ros.contract.codec import ContractError
from advsim_ros.contract.plan import path_msg, plan_from_path
from advsim_ros.contract.qos import Reliability
from advsim_ros.contract.scenario import cloud_msg
from advsim_ros.contract.spatial import odometry_msg, transforms_of
from advsim_ros.contract.tracks import TrackRecord, track_array_from_msg, track_array_msg
from advsim_ros.core.types import ActorClass, Plan, ScenarioError, Sweep

PROFILES = Path(__file__).resolve().parents[2] / "params" / "stacks"
MS = 1_000_000
S = 10_000 * MS  # a sweep's stamp
STACK = {"processes": [{"command": "my_stack"}]}


def _profile(**sections: Any) -> StackProfile:
    return profile_from_mapping({**STACK, **sections}, Path("."), "test profile")


def _odometry(stamp_ns: int, x: float, speed: float = 5.0) -> Any:
    pose = np.eye(4)
    pose[0, 3] = x
    return odometry_msg(stamp_ns, "map_world", "base_link", pose, np.array([speed, 0.0, 0.0]), 0.0)


def _path_cdr(stamp_ns: int, xy: list[tuple[float, float]], frame: str) -> bytes:
    stamps = stamp_ns + 100 * MS * np.arange(1, len(xy) + 1, dtype=np.int64)
    plan = Plan(stamps_ns=stamps, xy=np.array(xy, dtype=np.float64), yaws=np.zeros(len(xy)))
    return codec.encode(path_msg(plan, stamp_ns, frame))


def test_the_autoware_profile_relays_only_the_lidar_and_converts_the_rest() -> None:
    profile = load_profile(PROFILES / "autoware.yaml")
    assert bridge.converted_topics(profile) == {
        topics.ODOM.name, topics.PLAN.name, topics.DETECTIONS.name, topics.PREDICTIONS.name,
    }  # fmt: skip
    (relay,) = bridge.relays(profile, profile.renamed())
    assert relay.contract is topics.LIDAR
    assert relay.source is topics.LIDAR
    assert relay.target.name == "/sensing/lidar/concatenated/pointcloud"
    assert relay.target.offered == topics.LIDAR.offered  # the contract's QoS
    assert relay.to_stack
    routes = bridge.answer_routes(profile)
    assert [(r.contract, r.converted) for r in routes] == [
        (topics.PLAN, True), (topics.DETECTIONS, True), (topics.PREDICTIONS, True),
    ]  # fmt: skip
    assert routes[0].theirs.name == "/planning/scenario_planning/trajectory"
    assert routes[0].theirs.msgtype == "autoware_planning_msgs/msg/Trajectory"


def test_renamed_answers_in_the_contracts_types_are_relayed_from_the_stack_to_the_contracts_name() -> None:
    profile = _profile(
        inputs={"topics": {topics.TF.name: "/my_tf"}},
        outputs={"plan": {"topic": "/my_plan"}, "detections": {"topic": "/my_boxes"}},
    )
    relays = {relay.contract.name: relay for relay in bridge.relays(profile, profile.renamed())}
    assert set(relays) == {topics.TF.name, topics.PLAN.name, topics.DETECTIONS.name}
    plan = relays[topics.PLAN.name]
    assert (plan.source.name, plan.target.name, plan.to_stack) == ("/my_plan", topics.PLAN.name, False)
    tf = relays[topics.TF.name]
    assert (tf.source.name, tf.target.name, tf.to_stack) == (topics.TF.name, "/my_tf", True)
    assert not any(route.converted for route in bridge.answer_routes(profile))
    assert bridge.pose_target(profile) is None
    assert bridge.sweep_targets(profile) is None
    assert bridge.under_stack_name(topics.TF, profile.renamed()).name == "/my_tf"
    assert bridge.under_stack_name(topics.TF_STATIC, profile.renamed()) == topics.TF_STATIC


def test_answers_the_stack_publishes_best_effort_are_read_best_effort() -> None:
    profile = _profile(outputs={"plan": {"topic": "/my_plan", "reliability": "best_effort"}})
    theirs = bridge.answer_routes(profile)[0].theirs
    assert bridge.read_qos(profile, topics.PLAN.name, theirs).reliability is Reliability.BEST_EFFORT
    assert bridge.read_qos(profile, topics.PLAN.name, theirs).durability == theirs.offered.durability
    assert bridge.read_qos(profile, topics.DETECTIONS.name, topics.DETECTIONS) == topics.DETECTIONS.offered
    assert bridge.read_qos(profile, topics.TF.name, topics.TF) == topics.TF.offered


def test_the_pose_goes_in_the_stacks_type_and_the_sweeps_to_its_topics() -> None:
    profile = _profile(
        inputs={
            "pose": {"type": "navsatfix", "topic": "/fix", "datum": {"latitude": 49.0, "longitude": 8.4}},
            "lidar": {"topic": "/points", "frame_id": "velodyne", "also": ["/points_top"]},
        }
    )
    target = bridge.pose_target(profile)
    assert target is not None
    assert (target.name, target.msgtype, target.offered) == ("/fix", "sensor_msgs/msg/NavSatFix", topics.ODOM.offered)
    assert bridge.sweep_targets(profile) == ["/points", "/points_top"]
    assert topics.LIDAR.name in bridge.converted_topics(profile)
    bridge.convert_pose_once(profile.inputs.pose)  # the warm-up runs the real conversion
    framed = _profile(inputs={"pose": {"frame_id": "odom"}})
    target = bridge.pose_target(framed)
    assert target is not None
    assert target.name == topics.ODOM.name


def test_a_sweep_is_renamed_into_the_stacks_frame_and_its_own_frame_gets_one_transform() -> None:
    points = np.zeros(3, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4")])
    points["x"] = [1.0, 2.0, 3.0]
    raw = codec.encode(cloud_msg(Sweep(S, "lidar_top", points, np.eye(4))))
    seen: set[str] = set()
    out, transform = bridge.reframed(raw, "velodyne", seen)
    cloud = codec.decode(out, names.POINTCLOUD2)
    assert (cloud.header.frame_id, codec.stamp_ns(cloud.header.stamp)) == ("velodyne", S)
    assert bytes(cloud.data) == bytes(codec.decode(raw, names.POINTCLOUD2).data)
    edges = transforms_of(transform)
    np.testing.assert_array_equal(edges[("lidar_top", "velodyne")], np.eye(4))
    assert seen == {"lidar_top"}
    again, none = bridge.reframed(raw, "velodyne", seen)
    assert none is None
    assert again == out


def test_a_per_sweep_plan_in_a_static_frame_answers_its_own_sweep_in_the_world() -> None:
    profile = _profile(
        outputs={
            "plan": {
                "topic": "/my_plan",
                "frame_id": "local",
                "frame_origin": "static",
                "origin_pose": [10.0, 0.0, 0.0],
            }
        }
    )
    answers = bridge.Answers(profile)
    assert answers.books == {}  # per sweep: nothing is held back
    answers.heard_odometry(_odometry(S, 10.0))
    stamp, poses = answers.decode(topics.PLAN, names.PATH, _path_cdr(S, [(1.0, 0.0), (2.0, 0.0)], "local"))
    ((contract, sweep, made, answer),) = list(answers.arrived(topics.PLAN, stamp, poses))
    assert (contract, sweep, made, answer) == (topics.PLAN, S, S, poses)
    path = answers.message(contract, sweep, made, answer, answers.transform())
    assert (path.header.frame_id, codec.stamp_ns(path.header.stamp)) == ("map_world", S)
    plan = plan_from_path(path)
    assert len(plan.stamps_ns) == profile.outputs.plan.num_steps
    np.testing.assert_allclose(plan.xy[:2], [[11.0, 0.0], [12.0, 0.0]])  # moved 10 m into the world
    with pytest.raises(ContractError, match="frame 'other'"):
        answers.decode(topics.PLAN, names.PATH, _path_cdr(S, [(1.0, 0.0)], "other"))


def test_a_timer_driven_stacks_plan_answers_once_made_past_the_sweeps_decision_time() -> None:
    profile = _profile(
        timing={"mode": "timer", "decision_delay": 0.1, "answer_margin": 0.5},
        outputs={"plan": {"topic": "/my_plan"}, "detections": {"topic": "/my_boxes"}},
    )
    answers = bridge.Answers(profile)
    assert list(answers.books) == [topics.PLAN.name, topics.DETECTIONS.name]
    stamp = answers.heard_odometry(_odometry(S, 0.0))
    answers.sweep(stamp)
    early = answers.decode(topics.PLAN, names.PATH, _path_cdr(S + 50 * MS, [(1.0, 0.0), (2.0, 0.0)], ""))
    assert list(answers.arrived(topics.PLAN, *early)) == []  # a plan made at the decision time may still come
    late = answers.decode(topics.PLAN, names.PATH, _path_cdr(S + 120 * MS, [(3.0, 0.0), (4.0, 0.0)], ""))
    ((contract, sweep, made, answer),) = list(answers.arrived(topics.PLAN, *late))
    assert (contract, sweep, made, answer) == (topics.PLAN, S, S + 50 * MS, early[1])
    answers.clock_ns = S + 700 * MS  # the detections' answer time passed with none: still owed, none in force
    assert list(answers.due()) == []


def test_predictions_go_on_the_plans_time_grid_and_detections_on_the_sweep() -> None:
    profile = _profile(
        outputs={"plan": {"topic": "/my_plan", "horizon": 1.0, "step": 0.5},
                 "detections": {"topic": "/my_boxes", "type": "autoware_detected_objects"}},
    )  # fmt: skip
    answers = bridge.Answers(profile)
    stamps = S + 100 * MS * np.arange(12, dtype=np.int64)
    xy = np.column_stack([np.arange(12, dtype=np.float64), np.zeros(12), np.zeros(12)])
    track = TrackRecord(
        "car", ActorClass.VEHICLE, np.array([4.0, 2.0, 1.5]), 1.0, stamps, xy, np.zeros(12), np.zeros(12),
        np.zeros(12), np.zeros(12),
    )  # fmt: skip
    raw = codec.encode(track_array_msg([track], S, "map_world"))
    stamp, answer = answers.decode(topics.PREDICTIONS, names.ACTOR_TRACK_ARRAY, raw)
    assert stamp == S
    message = answers.message(topics.PREDICTIONS, S + 200 * MS, S, answer, answers.transform())
    (predicted,) = track_array_from_msg(message).tracks
    np.testing.assert_array_equal(predicted.stamps_ns, S + 200 * MS + 500 * MS * np.arange(3))
    np.testing.assert_allclose(predicted.xyz[:, 0], [2.0, 7.0, 11.0])  # held after its last state
    message = answers.message(topics.DETECTIONS, S + 200 * MS, S, ("", [track]), answers.transform())
    (detected,) = track_array_from_msg(message).tracks
    np.testing.assert_array_equal(detected.stamps_ns, [S + 200 * MS])


def test_the_odometry_kept_is_bounded_and_the_first_fix_is_the_first_odometry_sent() -> None:
    profile = _profile(
        inputs={"pose": {"type": "navsatfix", "topic": "/fix", "datum": {"latitude": 49.0, "longitude": 8.4}}},
        outputs={"plan": {"topic": "/my_plan", "frame_id": "map", "frame_origin": "first_fix"}},
    )
    answers = bridge.Answers(profile)
    with pytest.raises(ScenarioError, match="no fix was sent yet"):
        answers.transform()
    for index in range(bridge.KEPT_ODOMETRY + 5):
        answers.heard_odometry(_odometry(S + index * 100 * MS, 3.0 + index))
    assert len(answers.odometry) == bridge.KEPT_ODOMETRY
    assert min(answers.odometry) == S + 5 * 100 * MS  # the oldest dropped
    assert answers.world_frame == "map_world"
    transform = answers.transform()
    assert (transform.x, transform.y) == (3.0, 0.0)
