"""Fixtures of the labelling tests: 70 KITTI 0000 frames with their labels hidden, labelled once."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path

import pytest

from advsim_ros.core.types import Scenario
from advsim_ros.io.bag import BagConfig, write_scenario_bag
from advsim_ros.labelling.command import LabelReport, label_bag

FEW_FRAMES = (84, 70)  # first frame, count: the last 7 s (parked cars and the vans), one 6 s curation window
# A bag "straight off the vehicle": the recorder's odometry and tf go to topics the labeller does not read.
NO_POSES = BagConfig(odom_topic="/recorded/odom", tf_topic="/recorded/tf", info_topic="/recorded/info")


def frames_of(scenario: Scenario, count: int, start: int = 0) -> Scenario:
    """``count`` frames of the scenario from ``start``: sweeps, ego poses and the labels of those frames."""
    keep = scenario.frame_stamps_ns[start : start + count]
    actors = []
    for actor in scenario.actors:
        mask = (actor.stamps_ns >= keep[0]) & (actor.stamps_ns <= keep[-1])
        if mask.any():
            actors.append(
                dataclasses.replace(
                    actor, stamps_ns=actor.stamps_ns[mask], centers=actor.centers[mask], yaws=actor.yaws[mask]
                )
            )
    return dataclasses.replace(
        scenario,
        frame_stamps_ns=keep,
        ego=dataclasses.replace(scenario.ego, stamps_ns=keep, poses=scenario.ego.poses[start : start + count]),
        actors=tuple(actors),
        sweeps=scenario.sweeps[start : start + count],
    )


@pytest.fixture(scope="session")
def crop_frames() -> Callable[..., Scenario]:
    """frames_of, for tests that need other frames."""
    return frames_of


@pytest.fixture(scope="session")
def no_poses_config() -> BagConfig:
    return NO_POSES


@pytest.fixture(scope="session")
def kitti_few(kitti_scenario: Scenario) -> Scenario:
    return frames_of(kitti_scenario, FEW_FRAMES[1], FEW_FRAMES[0])


@pytest.fixture(scope="session")
def kitti_unlabelled_bag(kitti_few: Scenario, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The first KITTI frames with ego poses and mount but no tracks."""
    path = tmp_path_factory.mktemp("label") / "unlabelled"
    return write_scenario_bag(dataclasses.replace(kitti_few, actors=()), path, source="test: labels hidden")


@pytest.fixture(scope="session")
def kitti_labelled(kitti_unlabelled_bag: Path) -> LabelReport:
    """``advsim label`` on that bag (the bag's own ego poses)."""
    return label_bag(kitti_unlabelled_bag, kitti_unlabelled_bag.with_name("labelled"))
