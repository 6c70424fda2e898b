"""Two processes exchange every advsim_msgs type over Fast DDS on loopback; every field arrives intact."""

import json
import sys
from pathlib import Path

from advsim_ros.ros.launcher import Launcher, NodeSpec, wait_for

PROCESSES = Path(__file__).resolve().parent / "processes"
MSG_DIR = Path(__file__).resolve().parents[3] / "msg_defs" / "advsim_msgs" / "msg"


def _state(seconds: int, x: float) -> dict:
    return {
        "stamp": {"sec": seconds, "nanosec": 100_000_000},
        "x": x,
        "y": -2.5,
        "z": 0.875,
        "yaw": 1.25,
        "velocity": 7.5,
        "curvature": -0.0625,
        "acceleration": 1.5,
    }


def _track(actor_id: str) -> dict:
    return {
        "actor_id": actor_id,
        "actor_class": "cyclist",
        "length": 1.75,
        "width": 0.625,
        "height": 1.5,
        "confidence": 0.75,
        "states": [_state(10, 1.0), _state(11, 2.0)],
    }


HEADER = {"stamp": {"sec": 42, "nanosec": 7}, "frame_id": "world"}

# Every field differs from its default, so a field that is dropped or mangled on the way shows up.
SAMPLES: dict[str, list[dict]] = {
    "advsim_msgs/msg/ActorSelection": [
        {
            "header": HEADER,
            "run_id": 2**63 + 5,
            "scenario_id": "kitti_0000",
            "actor_ids": ["4", "11"],
            "dimension": 24,
            "delta_names": ["dx0", "dy0"],
            "logged_tracks": [_track("4")],
            "feasible_candidates": [1200, 350],
        }
    ],
    "advsim_msgs/msg/ActorState": [_state(3, 12.25)],
    "advsim_msgs/msg/ActorTrack": [_track("car:7")],
    "advsim_msgs/msg/ActorTrackArray": [
        {"header": HEADER, "run_id": 77, "query_id": 9, "tracks": [_track("a"), _track("b")]}
    ],
    "advsim_msgs/msg/Perturbation": [
        {
            "run_id": 12345678901234,
            "query_id": 3,
            "scenario_id": "kitti_0000/w40",
            "actor_ids": ["4", "11"],
            "delta": [0.5, -1.0, 0.25, 1.0],
            "algorithm": "bo",
        }
    ],
    "advsim_msgs/msg/QueryScore": [
        {
            "run_id": 3,
            "query_id": 5,
            "status": 2,
            "message": "stack exited with code 1",
            "adversarial_loss": 3.5,
            "imitation_loss": 1.25,
            "collision_loss": 2.0,
            "comfort_loss": 0.25,
            "collision_3s": 1.0,
            "collision_5s": 1.0,
            "l2_human_3s": 0.5,
            "l2_human_5s": 1.75,
            "lateral_acceleration": 2.25,
            "jerk": 4.5,
            "wall_time": 0.875,
            "sweeps_delivered": 9,
            "plans_received": 8,
            "input_digest": "0f1e2d3c4b5a69788796a5b4c3d2e1f0",
            "plan_digest": "00112233445566778899aabbccddeeff",
            "detection_ap": 0.625,
            "prediction_l2_3s": 1.125,
            "prediction_l2_5s": 2.375,
            "loop": "closed",
            "open_loop_adversarial_loss": 6.25,
            "open_loop_collision_5s": 1.0,
            "min_distance": 0.375,
            "min_time_to_collision": 1.5,
            "progress": 31.25,
        }
    ],
    "advsim_msgs/msg/Episode": [
        {
            "run_id": 99,
            "query_id": 5,
            "phase": 2,
            "frame_index": 10,
            "num_frames": 60,
            "segment_start": {"sec": 100, "nanosec": 0},
            "segment_end": {"sec": 107, "nanosec": 500},
            "sweeps_delivered": 10,
            "plans_received": 9,
            "outcome": 1,
            "outcome_detail": "the stack answered 9 of 10 frames",
            "input_digest": "ab",
            "plan_digest": "cd",
            "has_plan": True,
            "decision_plan": {
                "header": HEADER,
                "poses": [
                    {
                        "header": HEADER,
                        "pose": {
                            "position": {"x": 1.5, "y": 2.5, "z": 0.25},
                            "orientation": {"x": 0.0, "y": 0.0, "z": 0.6, "w": 0.8},
                        },
                    }
                ],
            },
            "has_detections": True,
            "detections": {"header": HEADER, "run_id": 0, "query_id": 0, "tracks": [_track("d")]},
            "has_predictions": True,
            "predictions": {"header": HEADER, "run_id": 0, "query_id": 0, "tracks": [_track("p")]},
            "has_executed": True,
            "executed": _track("ego"),
            "reacted_actors": [_track("7")],
        }
    ],
    "advsim_msgs/msg/FrameRequest": [
        {
            "header": HEADER,
            "run_id": 11,
            "query_id": 4,
            "frame_index": 3,
            "log_frame": 23,
            "ego_pose": {
                "position": {"x": 10.5, "y": -3.25, "z": 0.125},
                "orientation": {"x": 0.0, "y": 0.0, "z": 0.6, "w": 0.8},
            },
            "reacted_actors": [_track("7")],
        }
    ],
    "advsim_msgs/msg/SearchStatus": [{"run_id": 5, "queries_asked": 78, "finished": True}],
    "advsim_msgs/msg/Polyline": [{"x": [1.0, 2.0, 3.5], "y": [-1.0, 0.5, 4.0]}],
    "advsim_msgs/msg/RoadMap": [
        {
            "header": HEADER,
            "drivable_areas": [{"x": [0.0, 10.0, 10.0], "y": [0.0, 0.0, 5.0]}],
            "lane_centerlines": [{"x": [4200.125, 4210.5], "y": [-1500.25, -1490.0]}],
        }
    ],
    "advsim_msgs/msg/ScenarioInfo": [
        {
            "scenario_id": "synthetic/3",
            "source": "synthetic/seed=3",
            "world_frame": "map",
            "ego_frame": "base_link",
            "sensor_frame": "lidar",
            "ego_to_sensor": {
                "translation": {"x": 1.5, "y": 0.0, "z": 1.75},
                "rotation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0},
            },
            "ego_length": 4.5,
            "ego_width": 1.875,
            "ego_height": 1.625,
            "ego_forward_offset": 1.25,
            "has_sensor_model": True,
            "beam_elevations": [0.03125, -0.0625, -0.375],
            "azimuth_resolution": 0.00625,
            "min_range": 1.0,
            "max_range": 120.0,
        }
    ],
}


def test_samples_cover_every_advsim_msgs_type() -> None:
    defined = {f"advsim_msgs/msg/{path.stem}" for path in MSG_DIR.glob("*.msg")}
    assert defined == set(SAMPLES)


def test_every_advsim_msgs_type_crosses_processes_over_dds_unchanged(ros_graph: Launcher, tmp_path: Path) -> None:
    samples_file = tmp_path / "samples.json"
    samples_file.write_text(json.dumps(SAMPLES))
    expected_file = tmp_path / "expected.json"
    expected_file.write_text(json.dumps({name: len(items) for name, items in SAMPLES.items()}))
    received_file = tmp_path / "received.json"

    receiver = ros_graph.start(
        NodeSpec(
            "receiver",
            (sys.executable, str(PROCESSES / "receive_messages.py"), str(expected_file), str(received_file)),
            rename_node=False,
        )
    )
    ros_graph.start(
        NodeSpec(
            "publisher", (sys.executable, str(PROCESSES / "publish_messages.py"), str(samples_file)), rename_node=False
        )
    )
    finished = wait_for(lambda: receiver.poll() is not None, timeout=90.0)
    log = ros_graph.log_path("receiver").read_text()
    assert finished, f"receiver did not get every message type within 90 s; its log:\n{log}"
    assert receiver.returncode == 0, log
    assert json.loads(received_file.read_text()) == SAMPLES
