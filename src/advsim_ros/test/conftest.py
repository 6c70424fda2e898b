"""Fixtures for tests that start real ROS 2 processes talking over Fast DDS (shared memory, this machine only)."""

from __future__ import annotations

import dataclasses
import json
import re
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from advsim_ros.core.curation import crop_frames
from advsim_ros.core.lidar.assets import template_surface
from advsim_ros.core.types import ActorClass, ActorTrack, Scenario, Sweep
from advsim_ros.io.bag import write_scenario_bag
from advsim_ros.io.synthetic import SyntheticConfig, SyntheticLog, generate_synthetic_log
from advsim_ros.ros.launcher import Launcher, graph_environment, reserve_domain_id

PROCESSES = Path(__file__).resolve().parent / "processes"
SIMPLE_STACK = PROCESSES / "simple_stack.py"
sys.path.insert(0, str(Path(__file__).resolve().parent))  # attack_runs: helpers the attack tests share

from attack_runs import attack_argv  # noqa: E402 - importable once the line above ran
from campaign_runs import campaign_argv, campaign_config  # noqa: E402


@pytest.fixture
def ros_graph(tmp_path: Path) -> Iterator[Launcher]:
    """A launcher for one isolated graph: its own ROS_DOMAIN_ID, shared-memory transport only."""
    with (
        reserve_domain_id() as lease,
        Launcher(graph_environment(lease.domain_id), tmp_path / "logs", lease) as launcher,
    ):
        yield launcher


@pytest.fixture(scope="session")
def zombie_shm_segments() -> Callable[[], int]:
    """Counts (and removes) Fast DDS shared-memory segments whose owner is dead, by Fast DDS's own tool."""
    from advsim_ros.ros.reaper import clean_shared_memory

    def count() -> int:
        report = clean_shared_memory()
        found = re.search(r"(\d+) zombie segments cleaned", report)
        assert found, report
        return int(found.group(1))

    return count


@pytest.fixture(scope="session")
def kitti_window_bag(kitti_scenario: Scenario, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Frames 0..59 of KITTI tracking 0000 (1 s history + 5 s future) as a scenario bag."""
    window = crop_frames(kitti_scenario, 0, 59)
    return write_scenario_bag(window, tmp_path_factory.mktemp("kitti") / "window", source="kitti_tracking/0000")


@pytest.fixture(scope="session")
def synthetic_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A synthetic street log (ray-cast LiDAR, tracks, map) as a scenario bag."""
    log = generate_synthetic_log(np.random.default_rng(3), scenario_id="synthetic_seed3")
    return write_scenario_bag(log.scenario, tmp_path_factory.mktemp("synthetic") / "log", source="synthetic/seed=3")


@pytest.fixture(scope="session")
def lead_brake_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The demo's synthetic scene (family lead_brake, seed 1): a lead car braking ahead of the ego."""
    log = generate_synthetic_log(np.random.default_rng(1), SyntheticConfig(family="lead_brake"))
    return write_scenario_bag(log.scenario, tmp_path_factory.mktemp("lead_brake") / "log", source="synthetic")


@pytest.fixture(scope="session")
def tailgated_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The lead_brake scene (seed 1) with a car following the ego closely: it drives the logged ego's path 0.3 s
    later, 2 m behind it at a standstill (4.4 m at 8 m/s), and is in every sweep."""
    log = generate_synthetic_log(np.random.default_rng(1), SyntheticConfig(family="lead_brake"))
    scenario = log.scenario
    times = (scenario.frame_stamps_ns - scenario.frame_stamps_ns[0]) * 1e-9
    logged_x, lane_y = scenario.ego.xy[:, 0], float(scenario.ego.xy[0, 1])
    size = np.array([4.6, 1.8, 1.5])
    x = np.interp(times - 0.3, times, logged_x, left=np.nan)
    x = np.where(np.isnan(x), logged_x[0] + 8.0 * (times - 0.3), x)  # before the log: cruising at 8 m/s
    x -= 2.0 + 1.25 + 0.5 * size[0]  # the ego's rear is 1.25 m behind its origin
    centres = np.column_stack([x, np.full_like(x, lane_y), np.full_like(x, 0.5 * size[2])])
    follower = ActorTrack("follower", ActorClass.VEHICLE, size, scenario.frame_stamps_ns, centres, np.zeros_like(x))
    world = dataclasses.replace(scenario, actors=(*scenario.actors, follower), sweeps=())
    surfaces = {**log.actor_surfaces, "follower": template_surface(ActorClass.VEHICLE, size, 0.3)}
    tailgated = SyntheticLog(world, log.static_surface, surfaces, log.config)
    rng = np.random.default_rng(2)
    sweeps = []
    for index, stamp in enumerate(scenario.frame_stamps_ns[:60]):
        sensor_pose = scenario.ego.poses[index] @ scenario.ego_T_sensor
        points = tailgated.render(sensor_pose, tailgated.actor_poses_at(int(stamp)), rng)
        sweeps.append(Sweep(int(stamp), scenario.sweeps[index].frame_id, points, sensor_pose))
    rendered = dataclasses.replace(world, scenario_id="synthetic_tailgated", sweeps=tuple(sweeps))
    window = crop_frames(rendered, 0, 59)  # one window (1 s + 5 s): less to build the re-simulation model from
    return write_scenario_bag(window, tmp_path_factory.mktemp("tailgated") / "log", source="synthetic")


@pytest.fixture
def simple_stack(tmp_path: Path) -> Callable[..., str]:
    """The command line of the test stack (the example stack with faults) with the given parameters."""

    def command(**parameters: int | float | str) -> str:
        values = " ".join(f"-p {key}:={value}" for key, value in parameters.items())
        return f"{sys.executable} {SIMPLE_STACK} --ros-args -p marker_dir:={tmp_path} {values}"

    return command


@pytest.fixture(scope="session")
def advsim() -> Callable[..., subprocess.CompletedProcess[str]]:
    """The `advsim` command as a user runs it."""

    def run(*args: str, timeout: float = 900.0) -> subprocess.CompletedProcess[str]:
        return subprocess.run(
            [sys.executable, "-m", "advsim_ros.cli", *args],
            capture_output=True,
            text=True,
            timeout=timeout,
            check=False,
        )

    return run


@pytest.fixture(scope="session")
def fast_parameters() -> dict[str, dict[str, int]]:
    """Parameter overrides that keep graph tests fast (small feasible sets; selection and projection are real)."""
    return {"perturber": {"num_candidates": 20_000}}


@pytest.fixture(scope="session")
def uninterrupted(kitti_window_bag: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[str, dict[str, Any]]:
    """The attack run once without disturbance: what every disturbed run must reproduce."""
    base = tmp_path_factory.mktemp("uninterrupted")
    stack = f"{sys.executable} {SIMPLE_STACK} --ros-args -p marker_dir:={base}"
    result = subprocess.run(attack_argv(kitti_window_bag, base / "out", stack), capture_output=True, text=True,
                            timeout=900, check=False)  # fmt: skip
    assert result.returncode == 0, result.stderr
    return stack, json.loads((base / "out" / "summary.json").read_text())


@pytest.fixture(scope="session")
def uninterrupted_campaign(synthetic_bag: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """campaign_runs.campaign_config's 4 attacks on synthetic_bag, run whole on a local Ray: its OUTDIR (the
    figures a campaign killed and resumed, or run on a cluster, must report)."""
    base = tmp_path_factory.mktemp("uninterrupted_campaign")
    config = campaign_config(base / "campaign.yaml", synthetic_bag)
    whole = base / "whole"
    completed = subprocess.run(
        campaign_argv(config, whole, "--workers", "2"), capture_output=True, text=True, timeout=1500, check=False
    )
    assert completed.returncode == 0, completed.stderr[-3000:]
    return whole
