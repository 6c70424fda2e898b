"""The attack graph end to end: real node processes over Fast DDS on a 6 s KITTI 0000 window.

Each test runs `run_attack` (the API behind `advsim attack`), which starts scenario_player,
perturber, lidar_resim, scorer, search and a stack process on an isolated ROS_DOMAIN_ID.
The stack is a small rclpy process written as a user would (processes/simple_stack.py).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from advsim_ros.attack import AttackOptions, StackSpec, run_attack
from advsim_ros.core.curation import CurationConfig, crop_scenario, evaluate_window
from advsim_ros.io.bag import write_scenario_bag
from advsim_ros.io.kitti import load_kitti_tracking
from advsim_ros.io.synthetic import generate_synthetic_log
from advsim_ros.report import recorded_score

SHARED_DATA = (Path(__file__).resolve().parents[3] / ".." / "shared" / "data").resolve()
SIMPLE_STACK = Path(__file__).resolve().parent / "processes" / "simple_stack.py"
# Small feasible sets keep the test fast; the selection and projection are the real ones.
FAST = {"perturber": {"num_candidates": 20_000}}


@pytest.fixture(scope="module")
def kitti_window_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Frames 0..59 of KITTI tracking 0000 (1 s history + 5 s future) as a scenario bag."""
    root = SHARED_DATA / "kitti_tracking_0000"
    if not root.is_dir():
        pytest.skip(f"KITTI tracking 0000 not found at {root} (real data, see README 'Data')")
    scenario = load_kitti_tracking(root, "0000")
    window = crop_scenario(scenario, evaluate_window(scenario, 0, CurationConfig()))
    return write_scenario_bag(window, tmp_path_factory.mktemp("kitti") / "window", source="kitti_tracking/0000")


def _stack(tmp_path: Path, **faults: int | float) -> StackSpec:
    parameters = " ".join(f"-p {key}:={value}" for key, value in faults.items())
    command = f"{sys.executable} {SIMPLE_STACK} --ros-args -p marker_dir:={tmp_path} {parameters}"
    return StackSpec.parse(command)


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


@pytest.mark.slow
def test_attack_scores_every_query_without_dropping_frames_and_writes_a_replayable_bag(
    kitti_window_bag: Path, tmp_path: Path
) -> None:
    out = tmp_path / "attack"
    options = AttackOptions(
        bag=kitti_window_bag,
        out_dir=out,
        stack=_stack(tmp_path),
        algorithm="random",
        queries=3,
        window_start_frame=0,
        parameter_overrides=FAST,
    )
    result = run_attack(options)

    summary = json.loads((out / "summary.json").read_text())
    assert summary == result.summary
    queries = summary["queries"]
    assert [q["query_id"] for q in queries] == [0, 1, 2, 3, 4]  # original, 3 searched, replay of the best
    assert all(q["score"]["status"] == "ok" for q in queries), queries
    assert [q["sweeps_delivered"] for q in queries] == [10] * 5  # zero dropped frames
    assert [q["plans_received"] for q in queries] == [10] * 5
    assert summary["perturbed_actors"]
    assert summary["best"] is not None
    assert summary["adversarial"]["adversarial_loss"] == pytest.approx(summary["best"]["score"]["adversarial_loss"])
    assert (out / "bev.png").stat().st_size > 10_000

    counts = _mcap_messages(out / "adversarial")
    assert counts["/sensor/lidar/points"] == 10  # the re-simulated history the stack saw
    assert counts["/planning/trajectory"] == 1
    assert counts["/advsim/score"] == 1
    assert counts["/actors/tracks"] == 60
    assert counts["/ego/odom"] == 60

    recorded = recorded_score(out / "adversarial")
    replay = run_attack(
        AttackOptions(
            bag=out / "adversarial", out_dir=tmp_path / "replay", stack=_stack(tmp_path), queries=0, replay_only=True
        )
    )
    assert recorded is not None
    assert replay.summary["original"]["adversarial_loss"] == pytest.approx(recorded, abs=1e-6)


@pytest.mark.slow
def test_queries_of_a_crashing_or_hanging_stack_fail_and_the_attack_completes(
    kitti_window_bag: Path, tmp_path: Path
) -> None:
    out = tmp_path / "faulty"
    # sweep 15 is frame 5 of query 1 (crash); sweep 25 of the restarted process falls in query 3 (hang)
    stack = _stack(tmp_path, crash_at_sweep=15, hang_at_sweep=25, hang_seconds=20.0)
    options = AttackOptions(
        bag=kitti_window_bag,
        out_dir=out,
        stack=stack,
        algorithm="random",
        queries=4,
        window_start_frame=0,
        plan_timeout=3.0,
        parameter_overrides=FAST,
    )
    summary = run_attack(options).summary
    statuses = {q["query_id"]: q["score"]["status"] for q in summary["queries"]}
    assert len(statuses) == 6, statuses
    assert "stack_error" in statuses.values(), statuses
    assert "stack_timeout" in statuses.values(), statuses
    assert statuses[0] == "ok"
    assert len(summary["stack_crashes"]) == 1
    recorded = [json.loads(line) for line in (out / "queries.jsonl").read_text().splitlines()]
    assert [r["query_id"] for r in recorded] == sorted(statuses)


@pytest.fixture(scope="module")
def synthetic_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A synthetic street log (ray-cast LiDAR, tracks, map) as a scenario bag."""
    log = generate_synthetic_log(np.random.default_rng(3), scenario_id="synthetic_seed3")
    return write_scenario_bag(log.scenario, tmp_path_factory.mktemp("synthetic") / "log", source="synthetic/seed=3")


def _advsim(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "advsim_ros.cli", *args], capture_output=True, text=True, timeout=900, check=False
    )


@pytest.mark.slow
def test_cli_attack_on_the_reference_stack_then_replay_reproduces_the_score(
    synthetic_bag: Path, tmp_path: Path
) -> None:
    out = tmp_path / "out"
    attack = _advsim(
        "attack", str(synthetic_bag), "--stack", "reference", "--algo", "random", "--queries", "2", "-o", str(out)
    )
    assert attack.returncode == 0, attack.stderr
    assert f"outputs: {out.resolve()}/adversarial" in attack.stdout
    summary = json.loads((out / "summary.json").read_text())
    assert summary["stack"]["name"] == "modular_stack"
    assert [q["score"]["status"] for q in summary["queries"]] == ["ok"] * 4

    replay = _advsim("replay", str(out / "adversarial"), "--stack", "reference", "--check", "-o", str(tmp_path / "r"))
    assert replay.returncode == 0, replay.stdout + replay.stderr
    assert "recorded L_adv" in replay.stdout


def test_cli_attack_on_a_folder_that_is_not_a_bag_fails_with_a_clear_message(tmp_path: Path) -> None:
    result = _advsim("attack", str(tmp_path), "-o", str(tmp_path / "out"))
    assert result.returncode == 1
    assert "not a rosbag2 folder" in result.stderr
