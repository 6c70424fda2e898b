"""The rules that make auto-labels attackable (issue 33), each on a small made-up input whose answer is known.

No pedestrian inside a vehicle's box; two tracks of one object merged into one; a truck or a tanker up
to 18 m labelled as one vehicle; no track from candidates with fewer returns than the documented
minimum (``tracker.min_points``, ``tracker.min_small_points``); no vehicle from a hedge seen over parked
cars (``gates.max_ground_lift``); a parked car's track over the sweeps that show only pieces of it
(``tracker.extend_static``); path-length ratio of an odometry.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from advsim_ros.core.types import ActorClass, ActorTrack
from advsim_ros.labelling.config import GateConfig, LabellingConfig, load_labelling_config
from advsim_ros.labelling.detection import Candidates, concatenate, detect_sweep
from advsim_ros.labelling.evaluation import duplicate_tracks, small_inside_vehicles
from advsim_ros.labelling.odometry import trajectory_errors
from advsim_ros.labelling.overlaps import gate_overlaps
from advsim_ros.labelling.pipeline import LabellingResult, label_candidates
from advsim_ros.labelling.refine import LabelledTrack
from advsim_ros.stacks.modular.detector import CLASS_ORDER

FRAMES = 40
STAMPS = np.arange(FRAMES, dtype=np.int64) * 100_000_000 + 1_000_000_000
POSES = np.tile(np.eye(4), (FRAMES, 1, 1))  # the ego stands at the world origin


def _candidates(
    actor_class: ActorClass, frames: list[int], xy: np.ndarray, size: tuple[float, float], points: int
) -> Candidates:
    count = len(frames)
    height = 1.6 if actor_class is ActorClass.VEHICLE else 1.7
    return Candidates(
        frames=np.asarray(frames, dtype=np.int64),
        boxes=np.column_stack([xy, np.zeros(count), np.full(count, size[0]), np.full(count, size[1])]),
        z=np.full(count, height / 2),
        heights=np.full(count, height),
        classes=np.full(count, CLASS_ORDER.index(actor_class), dtype=np.int64),
        confidences=np.full(count, points / (points + 60.0)),
        num_points=np.full(count, points, dtype=np.int64),
        sensor_xy=np.zeros((count, 2)),
        lifts=np.zeros(count),
    )


def _label(*parts: Candidates) -> LabellingResult:
    return label_candidates(concatenate(list(parts)), STAMPS, POSES, LabellingConfig())


def _accepted(result: LabellingResult, actor_class: ActorClass) -> list[ActorTrack]:
    return [actor for actor in result.actors if actor.actor_class is actor_class]


@pytest.mark.parametrize(("points", "tracks"), [(9, 0), (10, 1)])
def test_no_track_is_built_from_candidates_with_fewer_returns_than_the_minimum(points: int, tracks: int) -> None:
    """A walker's candidates score above the confidence gate at 9 returns too: only min_small_points stops them."""
    frames = list(range(FRAMES))
    walk = np.column_stack([8.0 + 0.14 * np.arange(FRAMES), np.full(FRAMES, 4.0)])  # 1.4 m/s
    result = _label(_candidates(ActorClass.PEDESTRIAN, frames, walk, (0.6, 0.6), points))
    assert LabellingConfig().tracker.min_small_points == 10
    assert len(result.tracks) == tracks  # not even a rejected track
    assert len(_accepted(result, ActorClass.PEDESTRIAN)) == tracks


def test_two_tracks_of_one_car_that_overlap_for_a_while_are_merged_into_one() -> None:
    """The detector boxes one car twice at frames 12-19, then only 1 m further ahead: two tracks, one object."""
    path = np.column_stack([5.0 + 0.5 * np.arange(FRAMES), np.full(FRAMES, 6.0)])  # 5 m/s along x
    early = list(range(20))
    late = list(range(12, FRAMES))
    first = _candidates(ActorClass.VEHICLE, early, path[early], (4.2, 1.8), 200)
    second = _candidates(ActorClass.VEHICLE, late, path[late] + [1.0, 0.0], (4.2, 1.8), 120)
    result = _label(first, second)
    assert len(result.tracks) == 2  # the tracker made two; each alone passes every gate
    vehicles = _accepted(result, ActorClass.VEHICLE)
    assert len(vehicles) == 1
    assert vehicles[0].stamps_ns.tolist() == STAMPS.tolist()  # the merged track spans both
    assert [item.rejected for item in result.tracks if not item.accepted] == [("duplicate",)]
    assert duplicate_tracks(result.actors) == 0


def _track(name: str, actor_class: ActorClass, xy: np.ndarray, size: tuple[float, float]) -> LabelledTrack:
    count = xy.shape[0]
    centers = np.column_stack([xy, np.full(count, 0.8)])
    track = ActorTrack(name, actor_class, np.array([*size, 1.6]), STAMPS[:count], centers, np.zeros(count))
    return LabelledTrack(track, 0.5, False, count, count, 1.0, (), 1.6, 0.1)


@pytest.mark.parametrize(("inside", "kept_frames"), [(5, 15), (15, None)])
def test_a_pedestrian_never_stays_inside_a_vehicle_box(inside: int, kept_frames: int | None) -> None:
    """A "pedestrian" whose last frames lie in a parked van: cut to the frames outside, or dropped if too few."""
    van = _track("van", ActorClass.VEHICLE, np.tile([10.0, 0.0], (20, 1)), (5.5, 2.1))
    walk = np.column_stack([np.full(20, 10.0), np.linspace(5.0, 2.5, 20)])  # towards the van's side
    walk[20 - inside :] = [10.0, 0.4]  # then inside it
    walker = _track("walker", ActorClass.PEDESTRIAN, walk, (0.6, 0.6))
    before = [item.track for item in (van, walker)]
    assert small_inside_vehicles(before) == 1
    gated = {item.track.actor_id: item for item in gate_overlaps([van, walker], GateConfig())}
    assert gated["van"].accepted
    if kept_frames is None:
        assert gated["walker"].rejected == ("inside_vehicle",)
    else:
        assert gated["walker"].accepted
        assert gated["walker"].track.stamps_ns.shape[0] == kept_frames
    assert small_inside_vehicles([item.track for item in gated.values() if item.accepted]) == 0


def _box_surface(centre: tuple[float, float], size: tuple[float, float, float], step: float = 0.1) -> np.ndarray:
    """Returns of a parked box's two faces that a sensor at the origin sees (its -y side and its -x end) [m]."""
    x0, y0 = centre[0] - size[0] / 2, centre[1] + size[1] / 2
    z = np.arange(0.5, size[2], step)
    along = np.arange(0.0, size[0], step)
    across = np.arange(0.0, size[1], step)
    side = np.array([[x0 + a, centre[1] - size[1] / 2, h] for a in along for h in z])
    end = np.array([[x0, y0 - c, h] for c in across for h in z])
    return np.vstack([side, end])


@pytest.mark.parametrize("length", [12.0, 17.5])
def test_a_truck_or_tanker_up_to_18_m_is_labelled_as_one_vehicle(length: float) -> None:
    """Sweeps of a parked 2.5 m wide, 3.5 m tall box of that length beside the ego: one vehicle of its length."""
    config = LabellingConfig()
    ground = np.array([[x, y, 0.0] for x in np.arange(-30.0, 40.0, 0.4) for y in np.arange(-20.0, 20.0, 0.4)])
    truck = _box_surface((8.0 + length / 2, 6.0), (length, 2.5, 3.5))
    sensor = np.eye(4)
    sensor[2, 3] = 1.7  # the LiDAR 1.7 m above the ground
    points = np.vstack([ground, truck]) - [0.0, 0.0, 1.7]
    parts = [detect_sweep(points, POSES[frame], sensor, frame, config) for frame in range(10)]
    result = label_candidates(concatenate(parts), STAMPS[:10], POSES[:10], config)
    vehicles = _accepted(result, ActorClass.VEHICLE)
    assert len(vehicles) == 1
    assert vehicles[0].length == pytest.approx(length, abs=0.4)
    assert vehicles[0].centers[0, :2] == pytest.approx([8.0 + length / 2, 6.0], abs=0.3)


def _hedge_behind_a_parked_car() -> np.ndarray:
    """A sweep (sensor frame, LiDAR 1.7 m up) of a parked car at y = 7 m and, 4 m behind it, a 2.8 m hedge.

    The road is seen up to y = 8.6 m; beyond, the cars hide the ground and the hedge's lower metre, so
    the only returns in the hedge's 2 m ground cell are the hedge's own, from 1 m up.
    """
    road = np.array([[x, y, 0.0] for x in np.arange(-30.0, 40.0, 0.4) for y in np.arange(-20.0, 8.6, 0.4)])
    car = _box_surface((12.0, 7.0), (4.2, 1.8, 1.5))
    hedge = np.array([[x, 11.0, z] for x in np.arange(16.0, 20.0, 0.1) for z in np.arange(1.0, 2.8, 0.1)])
    result: np.ndarray = np.vstack([road, car, hedge]) - [0.0, 0.0, 1.7]
    return result


@pytest.mark.parametrize("max_ground_lift", [0.6, 100.0])
def test_a_hedge_seen_over_parked_cars_is_no_vehicle(max_ground_lift: float) -> None:
    """Its cluster is car-sized and 1.8 m tall above its own (too high) ground: only its ground lift shows it.

    With the gate (0.6 m) the hedge is dropped and the car kept; without it (100 m: the old labeller) both
    are vehicles.
    """
    config = LabellingConfig()
    config = dataclasses.replace(config, gates=dataclasses.replace(config.gates, max_ground_lift=max_ground_lift))
    sensor = np.eye(4)
    sensor[2, 3] = 1.7
    points = _hedge_behind_a_parked_car()
    parts = [detect_sweep(points, POSES[frame], sensor, frame, config) for frame in range(10)]
    result = label_candidates(concatenate(parts), STAMPS[:10], POSES[:10], config)
    vehicles = sorted(actor.centers[0, 1] for actor in _accepted(result, ActorClass.VEHICLE))
    hedge = [item for item in result.tracks if item.track.centers[0, 1] > 10.0]
    assert len(hedge) == 1
    assert hedge[0].lift == pytest.approx(1.0, abs=0.15)
    assert hedge[0].height < config.gates.vehicle_height[1]  # passes the height gate on its own ground
    if max_ground_lift < 1.0:
        assert vehicles == [pytest.approx(7.0, abs=0.5)]
        assert hedge[0].rejected == ("max_ground_lift",)
    else:
        assert len(vehicles) == 2


@pytest.mark.parametrize("extend", [True, False])
def test_a_parked_car_is_labelled_from_the_first_sweep_that_shows_pieces_of_it(extend: bool) -> None:
    """Far away the car is two 10-return pieces a sweep (classed pedestrian, other); close, a car from frame 20.

    Extended, its track starts at frame 2 (pieces at frames 5-19 with a gap of 3 sweeps, and a lone 30-return
    piece at frame 2: gaps within max_misses); without (the old labeller) at frame 20.
    """
    config = LabellingConfig()
    config = dataclasses.replace(config, tracker=dataclasses.replace(config.tracker, extend_static=extend))
    centre = np.array([[20.0, 6.0]])
    car = _candidates(ActorClass.VEHICLE, list(range(20, FRAMES)), np.repeat(centre, 20, axis=0), (4.0, 1.7), 120)
    early = [frame for frame in range(5, 20) if frame not in (10, 11, 12)]
    front = _candidates(ActorClass.PEDESTRIAN, early, np.tile([21.2, 6.3], (len(early), 1)), (0.6, 0.6), 10)
    back = _candidates(ActorClass.OTHER, early, np.tile([18.7, 5.8], (len(early), 1)), (0.5, 0.5), 10)
    lone = _candidates(ActorClass.OTHER, [2], centre, (0.5, 0.5), 30)  # 2 sweeps before the first pieces
    result = label_candidates(concatenate([car, front, back, lone]), STAMPS, POSES, config)
    vehicles = _accepted(result, ActorClass.VEHICLE)
    assert len(vehicles) == 1
    first = int(np.searchsorted(STAMPS, vehicles[0].stamps_ns[0]))
    assert first == (2 if extend else 20)
    assert vehicles[0].stamps_ns[-1] == STAMPS[-1]
    assert np.ptp(vehicles[0].centers[:, :2], axis=0) == pytest.approx([0.0, 0.0])


def test_path_length_ratio_measures_the_scale_of_an_odometry() -> None:
    reference = np.tile(np.eye(4), (30, 1, 1))
    reference[:, 0, 3] = 0.5 * np.arange(30)
    reference[:, 1, 3] = 0.02 * np.arange(30) ** 2
    short = reference.copy()
    short[:, :3, 3] *= 0.95  # an odometry 5 % short
    assert trajectory_errors(reference, reference)["path_length_ratio"] == pytest.approx(1.0)
    assert trajectory_errors(short, reference)["path_length_ratio"] == pytest.approx(0.95)


def test_params_file_documents_the_defaults_and_a_partial_detector_section_keeps_the_labellers(
    tmp_path: Path,
) -> None:
    params = Path(__file__).resolve().parents[2] / "params" / "labelling.yaml"
    assert load_labelling_config(params) == LabellingConfig()
    partial = tmp_path / "labelling.yaml"
    partial.write_text("/advsim_label:\n  ros__parameters:\n    detector:\n      min_points: 7\n", encoding="utf-8")
    detector = load_labelling_config(partial).detector
    assert detector.min_points == 7
    assert detector.vehicle_length == (2.4, 18.0)  # not the stack's 7.5 m


def test_a_parked_cars_track_is_not_extended_over_a_pedestrian_inside_its_box() -> None:
    """A walker crosses the car's spot at frames 6-10 (before the car is seen whole): the track stops after."""
    centre = np.array([[20.0, 6.0]])
    car = _candidates(ActorClass.VEHICLE, list(range(20, FRAMES)), np.repeat(centre, 20, axis=0), (4.0, 1.7), 120)
    pieces = _candidates(ActorClass.OTHER, list(range(2, 20)), np.tile([18.7, 5.8], (18, 1)), (0.5, 0.5), 20)
    walk = np.column_stack([np.full(14, 20.5), 2.0 + 0.5 * np.arange(14)])  # 5 m/s across y = 6 at frame 8
    walker = _candidates(ActorClass.PEDESTRIAN, list(range(0, 14)), walk, (0.6, 0.6), 30)
    result = _label(car, pieces, walker)
    assert len(_accepted(result, ActorClass.PEDESTRIAN)) == 1
    vehicles = _accepted(result, ActorClass.VEHICLE)
    assert len(vehicles) == 1
    assert int(np.searchsorted(STAMPS, vehicles[0].stamps_ns[0])) == 11  # after the walker's last frame inside (10)
    assert small_inside_vehicles(result.actors) == 0
