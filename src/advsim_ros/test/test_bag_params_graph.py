"""An attack through the real graph on a bag in a layout of its own, described once with `--bag-params`.

The bag is the demo's lead_brake scene recorded the way a user's recorder writes a drive (conftest.py,
RecordedYourWay: /velodyne_points in `velodyne`, /vehicle/odom from `odom` to `base_footprint`,
/perception/tracks; no /clock, /tf or ScenarioInfo). The scenario player, lidar_resim and scorer read it
in that layout, the stack gets its frames, the adversarial bag keeps it (so `ros2 bag play` feeds the
user's stack its own topics), the report finds it in summary.json, and `advsim replay` takes the same
`--bag-params` (and says how to describe the bag without it). About 40 s with the re-simulation model
cached (the demo's scene), 90 s without.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from rosbags.highlevel import AnyReader

from advsim_ros.core.curation import crop_frames
from advsim_ros.io.synthetic import SyntheticConfig, generate_synthetic_log


@pytest.mark.slow
def test_an_attack_replay_and_report_on_a_bag_in_its_own_layout_with_bag_params(
    recorded_your_way: Any, tmp_path: Path, advsim: Any
) -> None:
    log = generate_synthetic_log(np.random.default_rng(1), SyntheticConfig(family="lead_brake"))
    bag = recorded_your_way.write(crop_frames(log.scenario, 0, 59), tmp_path / "my_drive")
    params = str(recorded_your_way.params(tmp_path / "my_bag.yaml"))
    out = tmp_path / "out"

    attack = advsim(
        "attack", str(bag), "--bag-params", params, "--stack", "reference", "--algo", "random", "--queries", "2",
        "--reruns", "0", "--window-start", "0", "--param", "perturber.num_candidates=20000", "-o", str(out),
    )  # fmt: skip
    assert attack.returncode == 0, attack.stdout[-2000:] + attack.stderr[-3000:]
    summary = json.loads((out / "summary.json").read_text())
    assert {query["score"]["status"] for query in summary["queries"]} == {"ok"}
    assert summary["scenario"]["bag_params"] == dataclasses.asdict(recorded_your_way.layout)
    # bev.gif and report.html: drawn as `advsim report OUTDIR` draws them, from both bags in the layout summary.json
    # recorded (this step read adversarial/ in the contract's layout before, and failed on such bags)
    assert (out / "report.html").is_file()
    assert (out / "bev.gif").is_file()
    with AnyReader([out / "adversarial"]) as reader:
        held = {connection.topic for connection in reader.connections}
        odometry = next(c for c in reader.connections if c.topic == "/vehicle/odom")
        _, _, raw = next(reader.messages([odometry]))
        message = reader.deserialize(raw, odometry.msgtype)
    assert {"/velodyne_points", "/vehicle/odom", "/perception/tracks"} <= held
    assert "/sensor/lidar/points" not in held
    assert "/ego/odom" not in held
    assert (message.header.frame_id, message.child_frame_id) == ("odom", "base_footprint")

    refused = advsim("replay", str(out / "adversarial"), "-o", str(tmp_path / "refused"))
    assert refused.returncode == 1
    assert "has no ego pose (nav_msgs/msg/Odometry) topic /ego/odom" in refused.stderr
    assert "describe its layout with --bag-params FILE.yaml" in refused.stderr
    assert not (tmp_path / "refused").exists()

    replay = advsim(
        "replay", str(out / "adversarial"), "--bag-params", params, "--stack", "reference", "--check",
        "-o", str(tmp_path / "replay"),
    )  # fmt: skip
    assert replay.returncode == 0, replay.stdout[-2000:] + replay.stderr[-3000:]
    assert "reproduced 1 of 1 runs" in replay.stdout
