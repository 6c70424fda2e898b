"""Gates across tracks (labelling.overlaps): one object labelled twice keeps one track; a person in a van goes."""

from __future__ import annotations

import numpy as np

from advsim_ros.core.types import ActorClass, ActorTrack
from advsim_ros.labelling.config import GateConfig
from advsim_ros.labelling.overlaps import gate_overlaps, share_inside
from advsim_ros.labelling.refine import LabelledTrack

FRAMES = 20
STAMPS = np.arange(FRAMES, dtype=np.int64) * 100_000_000


def _track(
    name: str, actor_class: ActorClass, xy: np.ndarray, size: tuple[float, float], detections: int
) -> LabelledTrack:
    xy = np.broadcast_to(np.asarray(xy, dtype=float), (FRAMES, 2))
    centers = np.column_stack([xy, np.full(FRAMES, 0.8)])
    track = ActorTrack(name, actor_class, np.array([*size, 1.6]), STAMPS, centers, np.full(FRAMES, 0.3))
    return LabelledTrack(track, 0.5, True, detections, FRAMES, 1.0, (), 1.6, 0.1)


def _rejections(tracks: list[LabelledTrack]) -> dict[str, tuple[str, ...]]:
    return {item.track.actor_id: item.rejected for item in gate_overlaps(tracks, GateConfig())}


def test_a_pedestrian_inside_a_van_goes_and_one_walking_past_a_car_stays() -> None:
    van = _track("van", ActorClass.VEHICLE, [10.0, 0.0], (5.5, 2.1), 18)
    inside = _track("phantom", ActorClass.PEDESTRIAN, [11.5, 0.6], (0.8, 0.8), 15)
    walk = np.column_stack([np.linspace(6.0, 16.0, FRAMES), np.full(FRAMES, 3.0)])  # beside it, 1.9 m off its side
    past = _track("walker", ActorClass.PEDESTRIAN, walk, (0.8, 0.8), 15)
    assert _rejections([van, inside, past]) == {"van": (), "phantom": ("inside_vehicle",), "walker": ()}


def test_of_two_tracks_of_one_car_the_better_observed_stays_and_touching_parked_cars_both_stay() -> None:
    car = _track("car", ActorClass.VEHICLE, [20.0, 5.0], (4.2, 1.8), 19)
    echo = _track("echo", ActorClass.VEHICLE, [20.6, 5.3], (3.9, 1.7), 8)  # the same car, fewer detections
    front = _track("front", ActorClass.VEHICLE, [20.0 + 4.3 * np.cos(0.3), 5.0 + 4.3 * np.sin(0.3)], (4.2, 1.8), 12)
    assert _rejections([echo, car, front]) == {"echo": ("duplicate",), "car": (), "front": ()}


def test_the_share_counts_the_inner_tracks_own_frames_and_tracks_that_failed_other_gates_take_no_part() -> None:
    car = _track("car", ActorClass.VEHICLE, [0.0, 0.0], (4.2, 1.8), 19)
    short = ActorTrack("brief", ActorClass.PEDESTRIAN, np.array([0.8, 0.8, 1.7]), STAMPS[:4],
                       np.zeros((4, 3)), np.zeros(4))  # fmt: skip
    assert share_inside(short, car.track, 0.3) == 1.0
    assert share_inside(car.track, short, 0.3) == 4 / FRAMES
    rejected_car = LabelledTrack(car.track, 0.1, True, 19, FRAMES, 1.0, ("min_confidence",), 1.6, 0.1)
    person = _track("person", ActorClass.PEDESTRIAN, [0.0, 0.0], (0.8, 0.8), 10)
    assert _rejections([rejected_car, person])["person"] == ()
