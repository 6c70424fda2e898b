"""MarkerArrays of an adversarial bag, read back with the independent mcap reader; layouts name only its channels."""

from __future__ import annotations

import json
from collections import defaultdict
from pathlib import Path
from typing import Any

import pytest
import yaml
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from advsim_ros.core.metrics import MetricsConfig
from advsim_ros.io.bag import read_scenario_bag
from advsim_ros.viz import markers
from advsim_ros.viz.attack_view import bag_plan

REPO = Path(__file__).resolve().parents[2]


def _decoded(bag: Path) -> dict[str, list[tuple[int, Any]]]:
    """topic -> [(log time, decoded message)] as mcap + mcap_ros2 decode the bag's storage file."""
    found: dict[str, list[tuple[int, Any]]] = defaultdict(list)
    (storage,) = bag.glob("*.mcap")
    with storage.open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        for _, channel, message, decoded in reader.iter_decoded_messages():
            found[channel.topic].append((message.log_time, decoded))
    return found


def _channels(bag: Path) -> set[str]:
    (storage,) = bag.glob("*.mcap")
    with storage.open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None
    return {channel.topic for channel in summary.channels.values()}


def test_markers_draw_every_frame_with_the_perturbed_actor_highlighted_and_the_collision_marked(
    attack_out: Path,
) -> None:
    bag = attack_out / "adversarial"
    decoded = _decoded(bag)
    scenario = read_scenario_bag(bag, load_sweeps=False)
    stamps = scenario.frame_stamps_ns.tolist()
    perturbed_id = json.loads((attack_out / "summary.json").read_text())["perturbed_actors"][0]
    assert [t for t, _ in decoded[markers.ACTORS.name]] == stamps
    assert [t for t, _ in decoded[markers.HUMAN.name]] == stamps
    decision = stamps[9]
    assert [t for t, _ in decoded[markers.PLAN.name]] == [s for s in stamps if s >= decision]
    for stamp, array in decoded[markers.ACTORS.name]:
        first, *rest = array.markers
        assert first.action == markers.DELETEALL  # each frame replaces the previous one's boxes
        assert all(m.header.frame_id == "world" and m.header.stamp.sec * 10**9 + m.header.stamp.nanosec == stamp
                   for m in rest)  # fmt: skip
        present = [a for a in scenario.actors if stamp in a.stamps_ns.tolist()]
        boxes = [m for m in rest if m.type == markers.CUBE and m.ns in ("actors", "perturbed")]
        assert len(boxes) == len(present)
        labels = {m.text for m in rest if m.type == markers.TEXT_VIEW_FACING}
        assert f"{perturbed_id} vehicle (perturbed)" in labels
        (red,) = [m for m in rest if m.ns == "perturbed" and m.type == markers.CUBE]
        assert (red.color.r, red.color.b) == pytest.approx(
            (markers.PERTURBED_COLOR[0], markers.PERTURBED_COLOR[2])
        )  # float32
        actor = scenario.actor(perturbed_id)
        i = actor.stamps_ns.tolist().index(stamp)
        assert abs(red.pose.position.x - actor.centers[i, 0]) < 1e-9
        assert abs(red.scale.x - actor.length) < 1e-9
    # the SDV's planned box turns red from the first collision on, which is where the scorer saw it
    plan = bag_plan(bag)
    assert plan is not None
    collision = markers.first_collision_ns(scenario, plan, 9, MetricsConfig())
    score = json.loads((attack_out / "summary.json").read_text())["adversarial"]
    assert score["collision_5s"] == 1.0
    assert collision is not None
    assert decision < collision <= decision + 5 * 10**9
    for stamp, array in decoded[markers.PLAN.name]:
        (box,) = [m for m in array.markers if m.ns == "sdv_planned"]
        colour = (box.color.r, box.color.g, box.color.b)
        expected = markers.COLLISION_COLOR if stamp >= collision else markers.PLAN_COLOR
        assert colour == pytest.approx(expected[:3])
        (line,) = [m for m in array.markers if m.ns == "plan"]
        assert len(line.points) == plan.xy.shape[0]


def test_the_foxglove_layout_and_the_rviz_config_name_only_topics_the_bag_has(attack_out: Path) -> None:
    channels = _channels(attack_out / "adversarial")
    layout = json.loads((REPO / "docs" / "foxglove" / "advsim.json").read_text())
    named = set()
    for panel in layout["configById"].values():
        named |= set(panel.get("topics", {}))
        named |= {path["value"].split(".")[0] for path in panel.get("paths", [])}
        if panel.get("topicPath"):
            named.add(panel["topicPath"].split(".")[0])
    rviz = yaml.safe_load((REPO / "docs" / "rviz" / "advsim.rviz").read_text())
    displays = rviz["Visualization Manager"]["Displays"]
    named_rviz = {display["Topic"]["Value"] for display in displays if "Topic" in display}
    assert {markers.ACTORS.name, markers.PLAN.name, "/sensor/lidar/points"} <= named & named_rviz
    assert named - channels == set()
    assert named_rviz - channels == set()
    assert rviz["Visualization Manager"]["Global Options"]["Fixed Frame"] == "world"


def test_detections_and_predictions_are_drawn_at_the_decision_frame_when_the_stack_gave_them(attack_out: Path) -> None:
    from advsim_ros.contract import codec
    from advsim_ros.core.types import ActorTrack

    scenario = read_scenario_bag(attack_out / "adversarial", load_sweeps=False)
    decision = int(scenario.frame_stamps_ns[9])
    present = [a for a in scenario.actors if decision in a.stamps_ns.tolist()]
    detections = tuple(
        ActorTrack(a.actor_id, a.actor_class, a.size, a.stamps_ns[i : i + 1], a.centers[i : i + 1], a.yaws[i : i + 1])
        for a in present
        for i in [a.stamps_ns.tolist().index(decision)]
    )
    predictions = tuple(a for a in present if a.stamps_ns.shape[0] >= 2)
    plan = bag_plan(attack_out / "adversarial")
    extra = markers.scenario_markers(scenario, [], markers.StackOutputs(plan, detections, predictions), 9, "world")
    by_topic = {topic: (stamp, codec.decode(raw, msgtype)) for topic, msgtype, stamp, raw in extra
                if topic in (markers.DETECTIONS.name, markers.PREDICTIONS.name)}  # fmt: skip
    stamp, drawn = by_topic[markers.DETECTIONS.name]
    assert stamp == decision
    assert len([m for m in drawn.markers if m.ns == "detections"]) == len(detections)
    stamp, drawn = by_topic[markers.PREDICTIONS.name]
    assert stamp == decision
    assert len([m for m in drawn.markers if m.ns == "predictions"]) == len(predictions)
    without = markers.scenario_markers(scenario, [], markers.StackOutputs(plan), 9, "world")
    assert {topic for topic, *_ in without} == {markers.ACTORS.name, markers.HUMAN.name, markers.PLAN.name}
