"""Reactive actors: an IDM follower brakes behind a braking ego; an actor the ego does not bother keeps its track."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from advsim_ros.core.closed_loop import NS_PER_S, ControllerConfig, VehicleState, drive_closed_loop
from advsim_ros.core.futures import actor_futures_at
from advsim_ros.core.geometry import box_distance, boxes_overlap
from advsim_ros.core.journal import QueryRecord
from advsim_ros.core.lidar.boxes import yaw_pose
from advsim_ros.core.params import config_from_mapping, load_node_params
from advsim_ros.core.reactive import IdmConfig, ReactiveTraffic, with_overrides, with_reactions
from advsim_ros.core.types import ActorClass, ActorTrack, EgoGeometry, EgoTrajectory, Plan, ScenarioError

EGO = EgoGeometry()  # its box: 4.5 m long, centre 1 m ahead of the ego's origin, so its rear 1.25 m behind it
PERIOD = 0.02  # the closed loop's control period [s]
STEPS = 250  # 5 s
TIMES = np.arange(81) * 0.1  # the tracks: 8 s at 10 Hz [s]
STAMPS = np.round(TIMES * NS_PER_S).astype(np.int64)
SPEED = 8.0  # [m/s]
CAR = np.array([4.5, 1.8, 1.5])


def _track(actor_id: str, x: np.ndarray, y: float = 0.0, actor_class: ActorClass = ActorClass.VEHICLE) -> ActorTrack:
    centres = np.column_stack([x, np.full_like(x, y), np.full_like(x, 0.75)])
    return ActorTrack(actor_id, actor_class, CAR, STAMPS, centres, np.zeros_like(x))


def _follower(gap: float, y: float = 0.0) -> ActorTrack:
    """A car at SPEED, ``gap`` behind the rear of an ego that starts at x = 0 at SPEED (bumper to bumper) [m]."""
    return _track("follower", -1.25 - gap - 0.5 * CAR[0] + SPEED * TIMES, y)


def _ego_drive(brake_at: float | None, decel: float = 8.0) -> list[VehicleState]:
    """The ego along y = 0 from x = 0 at SPEED, braking at ``decel`` from ``brake_at`` to a stop (None: never)."""
    states, x, speed = [], 0.0, SPEED
    for step in range(STEPS + 1):
        accel = -decel if brake_at is not None and step * PERIOD >= brake_at and speed > 0.0 else 0.0
        states.append(VehicleState(x, 0.0, 0.0, speed, accel, 0.0))
        following = max(speed + accel * PERIOD, 0.0)
        x += 0.5 * (speed + following) * PERIOD
        speed = following
    return states


def _logged_ego(states: list[VehicleState]) -> EgoTrajectory:
    stamps = np.round(np.arange(len(states)) * PERIOD * NS_PER_S).astype(np.int64)
    return EgoTrajectory(stamps, np.stack([yaw_pose([s.x, s.y, 0.0], s.yaw) for s in states]))


def _run(
    tracks: list[ActorTrack],
    ego: list[VehicleState],
    config: IdmConfig | None = None,
    logged: EgoTrajectory | None = None,
) -> ReactiveTraffic:
    traffic = ReactiveTraffic(tracks, 0, PERIOD, EGO, config, logged)
    for step in range(STEPS):
        traffic.step(round(step * PERIOD * NS_PER_S), ego[step])
    return traffic


def _on_track(track: ActorTrack, stamps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Box centres (with z) and headings of the track at these stamps, as non-reactive actors are placed."""
    states = actor_futures_at([track], stamps).states[0]
    return np.column_stack([states[:, :2], np.full(len(stamps), 0.75)]), states[:, 2]


def _gaps(drive: ActorTrack, ego: list[VehicleState]) -> tuple[np.ndarray, bool]:
    """Box gaps between the actor's drive and the ego at every step [m], and whether they ever overlap."""
    ego_boxes = EGO.boxes(np.array([[s.x, s.y] for s in ego]), np.array([s.yaw for s in ego]))
    boxes = np.column_stack(
        [drive.centers[:, :2], drive.yaws, np.full(len(drive.yaws), CAR[0]), np.full(len(drive.yaws), CAR[1])]
    )
    return box_distance(boxes, ego_boxes), bool(boxes_overlap(boxes, ego_boxes).any())


@pytest.mark.parametrize("gap", [15.0, 8.0, 4.0])
def test_a_follower_brakes_behind_a_braking_ego_keeping_its_minimum_gap(gap: float) -> None:
    ego = _ego_drive(brake_at=1.0)  # a full brake from 8 m/s after 1 s
    follower = _follower(gap)
    config = IdmConfig()
    # as logged (non-reactive), the follower drives on at its speed: through the ego
    stamps = np.round(np.arange(STEPS + 1) * PERIOD * NS_PER_S).astype(np.int64)
    as_logged = ActorTrack("follower", ActorClass.VEHICLE, CAR, stamps, *_on_track(follower, stamps))
    logged_gaps, logged_overlap = _gaps(as_logged, ego)
    assert logged_gaps[0] == pytest.approx(gap)
    assert logged_overlap
    (drive,) = _run([follower], ego, config).drives()
    gaps, overlap = _gaps(drive, ego)
    assert not overlap
    assert gaps.min() >= config.min_gap - 0.15  # IDM's s0, up to the discrete step and the braking limit
    assert np.all(np.diff(drive.centers[:, 0]) >= -1e-12)  # along its path, never backwards
    assert np.all(drive.centers[:, 0] <= as_logged.centers[:, 0] + 1e-9)  # never ahead of its track
    assert drive.centers[-1, 0] < ego[-1].x  # standing behind the ego


def test_an_actor_the_ego_does_not_bother_drives_its_track_exactly() -> None:
    ego = _ego_drive(brake_at=1.0)
    beside = _follower(4.0, y=3.5)  # the next lane: never in its corridor
    far_behind = _track("far", -100.0 + SPEED * TIMES)  # same lane, never closer than IDM wants to the stopped ego
    ahead = _track("ahead", 30.0 + SPEED * TIMES)  # the ego is behind it
    traffic = _run([beside, far_behind, ahead], ego)
    assert traffic.reactive_ids == ("follower", "far", "ahead")
    assert traffic.drives() == ()
    assert traffic.off_track() == ()
    stamps = np.round(np.arange(STEPS + 1) * PERIOD * NS_PER_S).astype(np.int64)
    for drive, track in zip(traffic.drives(reacted_only=False), (beside, far_behind, ahead), strict=True):
        np.testing.assert_array_equal(drive.stamps_ns, stamps)
        expected = actor_futures_at([track], stamps).states[0]
        np.testing.assert_array_equal(drive.centers[:, :2], expected[:, :2])
        np.testing.assert_array_equal(drive.yaws, expected[:, 2])
    # and the world with reactions spliced in is the non-reactive one
    assert with_reactions((beside, far_behind, ahead), traffic.drives()) == (beside, far_behind, ahead)


def test_a_reacting_actor_ends_where_its_track_ends() -> None:
    ego = _ego_drive(brake_at=1.0)
    full = _follower(8.0)
    ends = 31  # labelled up to 3.0 s: the drive must not hold it (or run it on) past that
    short = ActorTrack("follower", ActorClass.VEHICLE, CAR, STAMPS[:ends], full.centers[:ends], full.yaws[:ends])
    traffic = _run([short], ego)
    (drive,) = traffic.drives()  # it reacted (the ego brakes at 1 s)
    assert drive.stamps_ns[-1] == STAMPS[ends - 1]
    assert traffic.off_track() == ()  # at 5 s it is gone, reacting or not
    spliced = with_reactions([short], [drive])[0]
    assert spliced.stamps_ns[-1] == STAMPS[ends - 1]
    assert not actor_futures_at([spliced], np.array([STAMPS[ends - 1] + NS_PER_S])).present.any()


def test_the_same_drive_gives_the_same_reactions() -> None:
    ego = _ego_drive(brake_at=0.5, decel=6.0)
    first = _run([_follower(6.0)], ego).drives()
    second = _run([_follower(6.0)], ego).drives()
    assert len(first) == len(second) == 1
    np.testing.assert_array_equal(first[0].centers, second[0].centers)
    np.testing.assert_array_equal(first[0].yaws, second[0].yaws)


def test_a_car_that_tailgated_in_the_log_keeps_its_gap_while_the_ego_drives_as_logged() -> None:
    cruising = _ego_drive(brake_at=None)
    tailgater = _follower(4.0)  # 0.5 s behind the ego: closer than IDM's 2 m + 1.6 s
    assert _run([tailgater], cruising, logged=_logged_ego(cruising)).drives() == ()
    assert len(_run([tailgater], cruising, IdmConfig(accept_logged_gaps=False)).drives()) == 1  # pure IDM brakes
    # when the ego brakes where the logged one cruised, the tailgater reacts and stops behind it
    braking = _ego_drive(brake_at=1.0)
    (drive,) = _run([tailgater], braking, logged=_logged_ego(cruising)).drives()
    gaps, overlap = _gaps(drive, braking)
    assert not overlap
    assert gaps.min() > 0.5


def test_pedestrians_and_standing_vehicles_keep_their_tracks() -> None:
    ego = _ego_drive(brake_at=0.0)
    walker = _track("walker", -8.0 + 1.4 * TIMES, actor_class=ActorClass.PEDESTRIAN)
    parked = _track("parked", np.full(TIMES.shape, -8.0))
    traffic = _run([walker, parked], ego)
    assert traffic.reactive_ids == ()
    assert traffic.drives(reacted_only=False) == ()


def test_reactive_actors_step_with_the_ego_in_the_closed_loop() -> None:
    """drive_closed_loop steps the traffic each control period; the planner sees it at its own stamp."""
    start_ns = 0
    traffic = ReactiveTraffic([_follower(6.0)], start_ns, PERIOD, EGO)
    seen: list[tuple[int, int]] = []

    def planner(now_ns: int, state: VehicleState) -> Plan:
        seen.append((now_ns, traffic.now_ns))
        times = np.arange(1, 51) * 0.1
        stop = np.minimum(times, SPEED / 6.0)
        xy = np.column_stack([state.x + SPEED * stop - 3.0 * stop**2, np.zeros(50)])  # brake at 6 m/s^2
        return Plan(now_ns + np.round(times * NS_PER_S).astype(np.int64), xy, np.zeros(50))

    start = VehicleState(0.0, 0.0, 0.0, SPEED, 0.0, 0.0)
    executed = drive_closed_loop(start, planner, start_ns, 5.0, 0.1, ControllerConfig(), traffic)
    assert all(now == at for now, at in seen)
    assert len(seen) == 50
    (drive,) = traffic.drives()
    np.testing.assert_array_equal(drive.stamps_ns, executed.stamps_ns)
    ego = [VehicleState(*row) for row in executed.states]
    gaps, overlap = _gaps(drive, ego)
    assert not overlap
    assert gaps.min() > 1.5
    (now,) = traffic.off_track()
    np.testing.assert_array_equal(now.centers[0], drive.centers[-1])


def test_splicing_reactions_and_frame_overrides() -> None:
    follower, other = _follower(4.0), _track("other", 50.0 + SPEED * TIMES, y=3.5)
    drive = ActorTrack("follower", ActorClass.VEHICLE, CAR, STAMPS[10:12], np.zeros((2, 3)), np.zeros(2))
    spliced, unchanged = with_reactions((follower, other), (drive,))
    assert unchanged is other
    np.testing.assert_array_equal(spliced.stamps_ns, STAMPS[:12])
    np.testing.assert_array_equal(spliced.centers[:10], follower.centers[:10])
    np.testing.assert_array_equal(spliced.centers[10:], 0.0)
    assert with_overrides((follower, other), (drive,)) == (other, drive)


def test_idm_parameters_must_make_sense() -> None:
    with pytest.raises(ScenarioError, match="time_headway"):
        IdmConfig(time_headway=0.0)
    with pytest.raises(ScenarioError, match="corridor_margin"):
        IdmConfig(corridor_margin=-1.0)
    assert IdmConfig(corridor_margin=0.0).corridor_margin == 0.0


def test_the_journal_keeps_the_reacted_drives() -> None:
    (drive,) = _run([_follower(6.0)], _ego_drive(brake_at=0.5)).drives()
    record = QueryRecord(1, "random", ("lead",), (0.5,), {"status": "ok"}, reacted=(drive,))
    line = json.loads(json.dumps(record.as_json()))
    (back,) = QueryRecord.from_json(line).reacted
    assert back.actor_id == "follower"
    np.testing.assert_array_equal(back.stamps_ns, drive.stamps_ns)
    np.testing.assert_array_equal(back.centers, drive.centers)
    # a query without reactions is journaled as before, and lines of before read back without any
    plain = QueryRecord(2, "random", (), (), {"status": "ok"}).as_json()
    assert "reacted" not in plain
    assert QueryRecord.from_json(plain).reacted == ()


def test_the_players_parameter_file_holds_the_defaults() -> None:
    path = Path(__file__).resolve().parents[2] / "params" / "scenario_player.yaml"
    params = load_node_params(path, "scenario_player")
    assert params["reactive_actors"] is False
    assert config_from_mapping(IdmConfig, params["reactive"], "reactive") == IdmConfig()
