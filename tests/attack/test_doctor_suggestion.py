"""`advsim doctor`'s suggested profile starts the stack it was made from exactly as it was started.

Whatever started the stack (--stack once or more, quoting, --ros-args, rename rules, a reference
stack's parameters, a profile's processes, cwd and env) the suggestion, loaded from another folder,
gives the launcher the same processes; what the graph showed goes over a profile's keys without
dropping those it cannot see (a datum, the plan's frame). The report prints the stack's log tails
when no plan came.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import pytest
import yaml

from advsim_ros.adapters.profile import load_profile
from advsim_ros.attack.doctor import DoctorReport
from advsim_ros.attack.options import StackSpec
from advsim_ros.attack.suggestion import suggested_profile

QOS = {"reliability": "reliable", "durability": "volatile"}
PATH, POSES, FIX = "nav_msgs/msg/Path", "geometry_msgs/msg/PoseArray", "sensor_msgs/msg/NavSatFix"


def _node(name: str, subscribes: dict[str, str], publishes: dict[str, str]) -> dict[str, Any]:
    def endpoints(items: dict[str, str]) -> list[dict[str, Any]]:
        return [{"topic": topic, "type": msgtype, "qos": QOS} for topic, msgtype in items.items()]

    return {"node": f"/{name}", "subscribes": endpoints(subscribes), "publishes": endpoints(publishes)}


GNSS_NODES = [
    _node("clusterer", {"/points_raw": "sensor_msgs/msg/PointCloud2"}, {"/blocked": "std_msgs/msg/Bool"}),
    _node("planner", {"/fix": FIX, "/blocked": "std_msgs/msg/Bool"}, {"/route/poses": POSES, "/planner/path": PATH}),
]


def _reloaded(profile: dict[str, Any], folder: Path) -> StackSpec:
    """The suggestion as a user passes it: written to another folder, loaded with --stack-profile."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "suggested_profile.yaml").write_text(yaml.safe_dump(profile, sort_keys=False))
    return StackSpec.from_profile(load_profile(folder / "suggested_profile.yaml"))


def _started(spec: StackSpec) -> list[tuple[list[str], Path | None, dict[str, str]]]:
    return [(process.argv(), process.cwd, dict(process.env)) for process in spec.processes()]


@pytest.mark.parametrize(
    ("stacks", "remaps", "mode"),
    [
        (["reference"], {}, "relay"),
        (["sh -c 'python3 detect.py & exec python3 plan.py'"], {}, "relay"),  # quoting kept
        (["python3 node.py --ros-args -p rate:=10 -p name:='two words'"], {}, "relay"),
        (["python3 node.py --ros-args -p use_sim_time:=false", "bash run.sh"], {}, "relay"),
        (["python3 a.py --ros-args", "python3 b.py"], {"/sensor/lidar/points": "/points_raw"}, "rename"),
        (["sh -c 'echo $HOME'"], {}, "relay"),  # a $ the shell inside expands, not the profile
    ],
)
def test_a_suggestion_for_stack_commands_starts_the_same_processes(
    tmp_path: Path, stacks: list[str], remaps: dict[str, str], mode: str
) -> None:
    stack = dataclasses.replace(StackSpec.parse_all(stacks, remaps), remap_mode=mode)
    profile, _ = suggested_profile([], stack, timer=False)
    assert _started(_reloaded(profile, tmp_path / "out")) == _started(stack)


def test_a_suggestion_keeps_every_process_of_a_profile_its_datum_frames_cwd_and_env(tmp_path: Path) -> None:
    (tmp_path / "stack" / "conf").mkdir(parents=True)
    (tmp_path / "stack" / "conf" / "planner.yaml").write_text("/planner: {ros__parameters: {rate: 10}}\n")
    (tmp_path / "profile.yaml").write_text(
        "name: gnss\n"
        "processes:\n"
        "  - {name: clusterer, command: $ADVSIM_PYTHON clusterer.py, cwd: stack, env: {LIBS: '${HOME}/libs'}}\n"
        "  - {name: planner, command: $ADVSIM_PYTHON planner.py, cwd: stack, params_files: [stack/conf/planner.yaml]}\n"
        "timing: {mode: timer, decision_delay: 0.2}\n"
        "inputs: {lidar: {topic: /velodyne}, pose: {type: navsatfix, topic: /gps, datum: {latitude: 49.0, "
        "longitude: 8.4}}}\n"
        "outputs: {plan: {type: spatial_path, topic: /old, frame_id: map, frame_origin: first_fix}}\n"
    )
    stack = StackSpec.from_profile(load_profile(tmp_path / "profile.yaml"))
    profile, notes = suggested_profile(GNSS_NODES, stack, timer=True)
    suggested = _reloaded(profile, tmp_path / "elsewhere")
    assert _started(suggested) == _started(stack)
    assert profile["processes"][0]["command"] == "$ADVSIM_PYTHON clusterer.py"  # as written, not expanded
    loaded = suggested.profile
    assert loaded is not None
    assert (loaded.name, loaded.timing.decision_delay) == ("gnss", 0.2)
    assert (loaded.inputs.lidar.topic, loaded.inputs.pose.topic) == ("/points_raw", "/fix")  # what the graph showed
    assert loaded.inputs.pose.datum == stack.profile.inputs.pose.datum  # type: ignore[union-attr]
    plan = loaded.outputs.plan
    assert (plan.topic, plan.type, plan.frame_id, plan.frame_origin) == ("/planner/path", "spatial_path", "map",
                                                                         "first_fix")  # fmt: skip
    assert notes == [
        f"outputs.plan: chose /planner/path ({PATH}) of 2 candidates; the others: /route/poses ({POSES}) "
        "(change outputs.plan.topic and type if one of them is the plan)"
    ]


def test_a_gnss_stack_without_a_profile_gets_a_datum_to_fill_in_and_the_plan_it_publishes(tmp_path: Path) -> None:
    nodes = [_node("planner", {"/points_raw": "sensor_msgs/msg/PointCloud2", "/fix": FIX}, {"/route/poses": POSES})]
    profile, notes = suggested_profile(nodes, StackSpec.parse("python3 planner.py"), timer=True)
    assert profile["inputs"]["pose"] == {"topic": "/fix", "type": "navsatfix",
                                         "datum": {"latitude": 0.0, "longitude": 0.0, "altitude": 0.0}}  # fmt: skip
    assert profile["outputs"]["plan"] == {"topic": "/route/poses", "type": "pose_array"}
    assert profile["timing"] == {"mode": "timer"}
    assert notes == ["inputs.pose.datum: put the latitude, longitude and altitude of the world frame's origin"]


def test_no_plan_prints_each_stack_process_log_tail_under_the_verdict(tmp_path: Path) -> None:
    logs = tmp_path / "run" / "logs"
    logs.mkdir(parents=True)
    (logs / "stack.log").write_text("".join(f"line {n}\n" for n in range(30)) + "FileNotFoundError: route.csv\n")
    from advsim_ros.attack.follow import stack_log_tails

    stack = StackSpec.parse_all(["python3 planner.py", "python3 clusterer.py"])
    report = DoctorReport(
        nodes=[], rows=[], suggestions=[], error="", sweeps_delivered=10, plans_received=0, stack_ms_median=None,
        out_dir=tmp_path, log_tails=tuple(stack_log_tails(tmp_path, stack)),
    )  # fmt: skip
    text = report.as_text().splitlines()
    verdict = next(i for i, line in enumerate(text) if line.startswith("verdict: NOT ready"))
    assert text[verdict + 1 :] == [
        f"the last lines of the stack's log {logs / 'stack.log'}:",
        *[f"  line {n}" for n in range(21, 30)],
        "  FileNotFoundError: route.csv",
        f"the stack's log {logs / 'stack2.log'} is empty",
    ]
