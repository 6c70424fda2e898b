"""The reference stacks as real processes: KITTI sweeps and odometry in over DDS, one valid plan out per sweep."""

import json
import sys
from pathlib import Path

import numpy as np
import pytest

from advsim_ros.io.kitti import load_kitti_tracking
from advsim_ros.ros.launcher import Launcher, NodeSpec, python_module_command, wait_for
from advsim_ros.stacks.learned.config import PACKAGED_WEIGHTS

REPO = Path(__file__).resolve().parents[3]
PROCESSES = Path(__file__).resolve().parent / "processes"
KITTI = (REPO / ".." / "shared" / "data" / "kitti_tracking_0000").resolve()
FIRST_FRAME = 20  # the van (KITTI track 0) drives about 13 m ahead of the ego here
NUM_SWEEPS = 4
STEP_NS = 100_000_000
PLAN_STEPS = 50


@pytest.fixture(scope="module")
def kitti_root() -> Path:
    if not KITTI.is_dir():
        pytest.skip(f"real KITTI data not found at {KITTI} (the shared data folder beside the repository)")
    return KITTI


def _stamp(stamp: dict) -> int:
    return int(stamp["sec"]) * 1_000_000_000 + int(stamp["nanosec"])


def _run(ros_graph: Launcher, tmp_path: Path, kitti_root: Path, stack: str, objects: bool) -> dict:
    params = REPO / "params" / f"stack_{stack}.yaml"
    ros_graph.start(
        NodeSpec(
            f"{stack}_stack",
            python_module_command(f"advsim_ros.stacks.{stack}.node"),
            params_files=(params,),
            parameters={"use_sim_time": True},
            rename_node=False,
        )
    )
    output = tmp_path / "received.json"
    command = [sys.executable, str(PROCESSES / "feed_stack.py"), str(kitti_root), str(FIRST_FRAME)]
    command += [str(NUM_SWEEPS), str(output)] + (["objects"] if objects else [])
    feeder = ros_graph.start(NodeSpec("feeder", tuple(command), rename_node=False))
    finished = wait_for(lambda: feeder.poll() is not None or bool(ros_graph.exited()), timeout=150.0)
    logs = "\n".join(f"--- {name}\n{ros_graph.log_path(name).read_text()}" for name in (f"{stack}_stack", "feeder"))
    assert finished, f"the stack did not answer {NUM_SWEEPS} sweeps within 150 s; logs:\n{logs}"
    assert feeder.returncode == 0, logs
    return json.loads(output.read_text())


def _check_plans(received: dict) -> None:
    for sent in received["sent"]:
        stamp = sent["stamp_ns"]
        plans = [plan for plan in received["plans"] if _stamp(plan["header"]["stamp"]) == stamp]
        assert plans, f"no plan stamped {stamp}"
        plan = plans[0]
        assert plan["header"]["frame_id"] == "world"
        pose_stamps = np.array([_stamp(pose["header"]["stamp"]) for pose in plan["poses"]])
        np.testing.assert_array_equal(pose_stamps, stamp + STEP_NS * np.arange(1, PLAN_STEPS + 1))
        xy = np.array([[pose["pose"]["position"]["x"], pose["pose"]["position"]["y"]] for pose in plan["poses"]])
        assert np.all(np.isfinite(xy))
        # The plan starts at the ego (the first pose is 0.1 s ahead) and moves at a plausible speed.
        assert np.linalg.norm(xy[0] - np.array(sent["ego_xy"])) < 2.0
        assert np.all(np.linalg.norm(np.diff(xy, axis=0), axis=1) <= 20.0 * 0.1)
        quaternions = np.array([[p["pose"]["orientation"][k] for k in "xyzw"] for p in plan["poses"]])
        np.testing.assert_allclose(np.linalg.norm(quaternions, axis=1), 1.0, atol=1e-6)


def test_modular_stack_process_answers_every_kitti_sweep_with_a_stamped_plan_and_detections(
    ros_graph: Launcher, tmp_path: Path, kitti_root: Path
) -> None:
    received = _run(ros_graph, tmp_path, kitti_root, "modular", objects=True)
    _check_plans(received)
    stamps = [sent["stamp_ns"] for sent in received["sent"]]
    detection_stamps = [_stamp(message["header"]["stamp"]) for message in received["detections"]]
    assert sorted(set(detection_stamps)) == stamps
    last = next(m for m in received["detections"] if _stamp(m["header"]["stamp"]) == stamps[-1])
    for track in last["tracks"]:
        assert [_stamp(state["stamp"]) for state in track["states"]] == [stamps[-1]]
    # The van ahead (KITTI track 0) is among the detected vehicles, where the labels put it.
    van = load_kitti_tracking(KITTI, "0000").actor("0")
    van_xy = van.centers[list(van.stamps_ns).index(stamps[-1]), :2]
    vehicles = [t["states"][0] for t in last["tracks"] if t["actor_class"] == "vehicle"]
    assert min(np.hypot(s["x"] - van_xy[0], s["y"] - van_xy[1]) for s in vehicles) < 1.5
    predictions = next(m for m in received["predictions"] if _stamp(m["header"]["stamp"]) == stamps[-1])
    for track in predictions["tracks"]:
        expected = stamps[-1] + STEP_NS * np.arange(1, PLAN_STEPS + 1)
        np.testing.assert_array_equal([_stamp(state["stamp"]) for state in track["states"]], expected)


def test_learned_stack_process_answers_every_kitti_sweep_with_a_stamped_plan(
    ros_graph: Launcher, tmp_path: Path, kitti_root: Path
) -> None:
    assert PACKAGED_WEIGHTS.is_file(), f"packaged weights missing: {PACKAGED_WEIGHTS} (run `advsim train-il`)"
    received = _run(ros_graph, tmp_path, kitti_root, "learned", objects=False)
    _check_plans(received)
    assert received["detections"] == []
    assert received["predictions"] == []
