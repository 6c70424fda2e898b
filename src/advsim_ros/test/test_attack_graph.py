"""The attack graph end to end: real node processes over Fast DDS on a 6 s KITTI 0000 window.

`run_attack` (the API behind `advsim attack`) starts scenario_player, perturber, lidar_resim,
scorer, search and the stack as processes on a reserved ROS_DOMAIN_ID. An attack is a
measurement: the same attack run twice gives the same score for every query, and the stack
received the same bytes (the per-query input digests) both times.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from advsim_ros.attack import AttackOptions, StackSpec, run_attack
from advsim_ros.attack.outputs import recorded_score
from advsim_ros.viz.outputs import write_viz_outputs

QUERIES = 8


def _mcap_messages(bag: Path) -> dict[str, int]:
    """Messages per topic as the independent mcap reader decodes them."""
    counts: dict[str, int] = {}
    (storage,) = bag.glob("*.mcap")
    with storage.open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        for _, channel, _, decoded in reader.iter_decoded_messages():
            assert decoded is not None
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
    return counts


def _reference_attack(bag: Path, out: Path, fast: dict[str, Any]) -> dict[str, Any]:
    options = AttackOptions(
        bag=bag,
        out_dir=out,
        stack=StackSpec.reference(),
        algorithm="random",
        queries=QUERIES,
        window_start_frame=0,
        parameter_overrides=fast,
    )
    return run_attack(options).summary


@pytest.fixture(scope="module")
def reference_attack(
    kitti_window_bag: Path, tmp_path_factory: pytest.TempPathFactory, fast_parameters: dict[str, Any]
) -> tuple[Path, dict[str, Any]]:
    out = tmp_path_factory.mktemp("attack") / "first"
    return out, _reference_attack(kitti_window_bag, out, fast_parameters)


@pytest.mark.slow
def test_an_attack_scores_every_query_without_dropping_frames_and_records_what_the_stack_saw(
    reference_attack: tuple[Path, dict[str, Any]],
) -> None:
    out, summary = reference_attack
    assert json.loads((out / "summary.json").read_text()) == summary
    queries = summary["queries"]
    # the original, the search's queries, two re-runs of the best, then the controls
    assert [q["query_id"] for q in queries] == list(range(QUERIES + 6))
    controls = ["original", "original", "identity"]
    assert [q["algorithm"] for q in queries] == ["original"] + ["random"] * QUERIES + ["rerun", "rerun", *controls]
    assert all(q["score"]["status"] == "ok" for q in queries), queries
    assert {q["score"]["sweeps_delivered"] for q in queries} == {10}  # no frame dropped
    assert {q["score"]["plans_received"] for q in queries} == {10}
    (reproduction,) = summary["reproductions"]
    assert reproduction["reproduced"]
    assert reproduction["inputs_identical"]
    assert reproduction["plans_identical"]
    assert summary["flaky"] == []
    assert summary["best"]["query_id"] == reproduction["query_id"]
    assert summary["adversarial"]["adversarial_loss"] == summary["best"]["score"]["adversarial_loss"]
    # the bag's sweeps, re-simulated again from the journal, are byte for byte what the stack received
    assert summary["recorded_inputs_reproduced"] is True
    assert (out / "bev.png").stat().st_size > 10_000
    counts = _mcap_messages(out / "adversarial")
    assert counts["/sensor/lidar/points"] == 10  # the re-simulated history the stack saw
    assert counts["/planning/trajectory"] == 1
    assert counts["/advsim/score"] == 1
    assert counts["/map/drivable"] == 1  # KITTI has no map: the estimate the scorer used travels with the bag
    assert counts["/actors/tracks"] == 60
    assert counts["/ego/odom"] == 60


@pytest.mark.slow
def test_the_same_attack_run_again_gives_the_same_score_and_the_same_stack_inputs_for_every_query(
    reference_attack: tuple[Path, dict[str, Any]],
    kitti_window_bag: Path,
    tmp_path: Path,
    fast_parameters: dict[str, Any],
) -> None:
    _, first = reference_attack
    second = _reference_attack(kitti_window_bag, tmp_path / "second", fast_parameters)
    assert _measured(second) == _measured(first)
    assert len({q["score"]["input_digest"] for q in first["queries"]}) > 1  # the perturbations changed the LiDAR


def _measured(summary: dict[str, Any]) -> list[tuple[Any, ...]]:
    keys = ("status", "adversarial_loss", "collision_5s", "input_digest", "plan_digest")
    return [(q["query_id"], *(q["score"][k] for k in keys)) for q in summary["queries"]]


@pytest.mark.slow
def test_lidar_resim_keeping_only_the_history_sweeps_gives_the_stack_the_same_inputs_and_the_same_scores(
    reference_attack: tuple[Path, dict[str, Any]],
    kitti_window_bag: Path,
    tmp_path: Path,
    fast_parameters: dict[str, Any],
) -> None:
    # open loop: the attack has lidar_resim keep only the 10 history sweeps of the 60 (memory); keeping them all
    # must not change a byte the stack receives
    out, first = reference_attack
    assert "keeping 10 of 60 sweeps" in (out / "run" / "logs" / "lidar_resim.log").read_text()
    every = {**fast_parameters, "lidar_resim": {"history_sweeps_only": False}}
    second = _reference_attack(kitti_window_bag, tmp_path / "every_sweep", every)
    assert "keeping 60 of 60 sweeps" in (tmp_path / "every_sweep" / "run" / "logs" / "lidar_resim.log").read_text()
    assert _measured(second) == _measured(first)


@pytest.mark.slow
def test_the_adversarial_bag_replays_to_its_recorded_score_on_every_run(
    reference_attack: tuple[Path, dict[str, Any]], tmp_path: Path, advsim: Any
) -> None:
    out, summary = reference_attack
    recorded = recorded_score(out / "adversarial")
    assert recorded is not None
    assert recorded.adversarial_loss == summary["adversarial"]["adversarial_loss"]
    replay = advsim("replay", str(out / "adversarial"), "--stack", "reference", "--check", "--runs", "2",
                    "-o", str(tmp_path / "replay"))  # fmt: skip
    assert replay.returncode == 0, replay.stdout + replay.stderr
    assert "reproduced 2 of 2 runs" in replay.stdout


@pytest.mark.slow
def test_queries_of_a_crashing_or_hanging_stack_fail_and_the_attack_completes(
    kitti_window_bag: Path, tmp_path: Path, simple_stack: Any, fast_parameters: dict[str, Any]
) -> None:
    out = tmp_path / "faulty"
    # sweep 15 is frame 5 of query 1 (crash); sweep 25 of the restarted process falls in query 3 (hang)
    command = simple_stack(crash_at_sweep=15, hang_at_sweep=25, hang_seconds=20.0)
    options = AttackOptions(
        bag=kitti_window_bag,
        out_dir=out,
        stack=StackSpec.parse(command),
        algorithm="random",
        queries=4,
        window_start_frame=0,
        plan_timeout=3.0,
        reruns=0,
        parameter_overrides=fast_parameters,
    )
    summary = run_attack(options).summary
    statuses = {q["query_id"]: q["score"]["status"] for q in summary["queries"]}
    assert sorted(statuses) == [0, 1, 2, 3, 4, 5], statuses  # the original, 4 searched, the identity control
    assert "stack_error" in statuses.values(), statuses
    assert "stack_timeout" in statuses.values(), statuses
    assert statuses[0] == "ok"
    assert len(summary["stack_crashes"]) == 1
    journaled = [json.loads(line) for line in (out / "queries.jsonl").read_text().splitlines()[1:]]
    assert [r["query_id"] for r in journaled if "query_id" in r] == sorted(statuses)


@pytest.mark.slow
def test_cli_attack_on_the_reference_stack_prints_where_the_outputs_are(
    synthetic_bag: Path, tmp_path: Path, advsim: Any
) -> None:
    out = tmp_path / "out"
    attack = advsim(
        "attack", str(synthetic_bag), "--stack", "reference", "--algo", "random", "--queries", "2", "--reruns", "1",
        "-o", str(out),
    )  # fmt: skip
    assert attack.returncode == 0, attack.stderr
    assert f"outputs: {out.resolve()}/adversarial" in attack.stdout
    summary = json.loads((out / "summary.json").read_text())
    assert summary["stack"]["name"] == "modular_stack"
    # the original, 2 searched, the best's re-run, then the controls: the original's re-run and the identity
    assert [q["algorithm"] for q in summary["queries"]] == ["original", "random", "random", "rerun", "original",
                                                             "identity"]  # fmt: skip
    assert [q["score"]["status"] for q in summary["queries"]] == ["ok"] * 6


@pytest.mark.slow
def test_the_attack_writes_markers_an_animated_bev_and_a_report_and_its_bag_exports_to_openscenario(
    reference_attack: tuple[Path, dict[str, Any]], tmp_path: Path
) -> None:
    from advsim_ros.export.openscenario import export_openscenario, perturbed_entities

    out, summary = reference_attack
    counts = _mcap_messages(out / "adversarial")  # decoded by the independent mcap reader
    assert counts["/advsim/markers/actors"] == counts["/advsim/markers/human"] == 60
    assert counts["/advsim/markers/plan"] == 51  # from the decision frame on
    assert summary["outputs"]["report"] == str(out.resolve() / "report.html")
    assert 0 < (out / "bev.gif").stat().st_size < 3_000_000
    assert "data:image/gif;base64," in (out / "report.html").read_text()
    # the attack drew them from what it had just written; `advsim report` draws them from the bag: the same bytes
    drawn = {name: (out / name).read_bytes() for name in ("bev.gif", "report.html")}
    write_viz_outputs(out, summary)
    for name, content in drawn.items():
        assert (out / name).read_bytes() == content, name
    exported = export_openscenario(out / "adversarial", tmp_path / "scenario.xosc")
    assert perturbed_entities(exported.path) == set(summary["perturbed_actors"])
