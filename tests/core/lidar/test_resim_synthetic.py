"""Re-simulation against exact ground truth: a synthetic log re-rendered from its meshes with actors moved."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from advsim_ros.core.lidar.boxes import invert_rigid, rays_hit_region, removal_region, track_pose_at, yaw_pose
from advsim_ros.core.lidar.render import grid_rays
from advsim_ros.core.lidar.resim import ResimError, ResimModel
from advsim_ros.core.lidar.sensor import RangeImage
from advsim_ros.core.types import ActorTrack
from advsim_ros.io.synthetic import SyntheticLog

WITHIN = 0.1  # a re-simulated ray matches the direct render when both miss or their ranges differ by at most this [m]


def _moved(tracks: tuple[ActorTrack, ...], actor_id: str, dx: float, dy: float, dyaw: float) -> tuple[ActorTrack, ...]:
    def move(track: ActorTrack) -> ActorTrack:
        if track.actor_id != actor_id:
            return track
        centers = track.centers + np.array([dx, dy, 0.0])
        return ActorTrack(track.actor_id, track.actor_class, track.size, track.stamps_ns, centers, track.yaws + dyaw)

    return tuple(move(track) for track in tracks)


def _nearest_parked_car(log: SyntheticLog, frame: int) -> str:
    """The id of the parked car nearest to the sensor at a frame."""
    sensor = log.scenario.sweeps[frame].sensor_pose[:2, 3]
    parked = [track for track in log.scenario.actors if track.actor_id.startswith("parked")]
    return min(parked, key=lambda track: float(np.linalg.norm(track.centers[frame, :2] - sensor))).actor_id


def _agreement(model: ResimModel, truth: np.ndarray, resimulated: np.ndarray, rays: np.ndarray) -> float:
    """Share of the given cells (B, A) where both sweeps miss or their ranges agree within WITHIN."""
    expected = RangeImage.from_points(truth, model.beam_rows).ranges
    got = RangeImage.from_points(resimulated, model.beam_rows).ranges
    with np.errstate(invalid="ignore"):
        same = (np.isinf(expected) & np.isinf(got)) | (np.abs(expected - got) <= WITHIN)
    return float(np.mean(same[rays]))


@pytest.mark.slow
@pytest.mark.parametrize("frame", [10, 40])
def test_moving_an_actor_matches_rendering_the_moved_world_directly(
    synthetic_log: SyntheticLog, synthetic_model: ResimModel, frame: int
) -> None:
    """Acceptance: the A sweep re-simulated with the actor moved to B equals the direct B render on >= 95 % of rays."""
    scenario = synthetic_log.scenario
    sweep = scenario.sweeps[frame]
    perturbed = _moved(scenario.actors, "lead", 3.0, 1.5, 0.3)
    poses = {track.actor_id: yaw_pose(track.centers[frame], float(track.yaws[frame])) for track in perturbed}
    truth = synthetic_log.render(sweep.sensor_pose, poses, np.random.default_rng(1))
    resimulated = synthetic_model.resimulate(sweep, scenario.actors, perturbed, rng=np.random.default_rng(0))
    # The rays that can tell: every cell whose ray meets the actor's box at pose A or at pose B.
    directions, _, _ = grid_rays(synthetic_model.sensor)
    sensor_from_world = invert_rigid(sweep.sensor_pose)
    lead = scenario.actor("lead")
    box = removal_region(lead.size, 0.0)
    old_pose = track_pose_at(lead, sweep.stamp_ns)
    assert old_pose is not None
    touched = rays_hit_region(np.zeros(3), directions, sensor_from_world @ old_pose, box)
    touched |= rays_hit_region(np.zeros(3), directions, sensor_from_world @ poses["lead"], box)
    touched = touched.reshape(synthetic_model.sensor.num_beams, synthetic_model.sensor.num_azimuths)
    assert np.count_nonzero(touched) > 500
    logged = _agreement(synthetic_model, truth, sweep.points, touched)
    assert logged < 0.5  # without re-simulation these rays would be wrong
    assert _agreement(synthetic_model, truth, resimulated, touched) >= 0.95
    assert _agreement(synthetic_model, truth, resimulated, np.ones_like(touched)) >= 0.995


def test_a_sweep_whose_actors_did_not_move_comes_back_unchanged(
    short_log: SyntheticLog, short_model: ResimModel
) -> None:
    sweep = short_log.scenario.sweeps[20]
    tracks = short_log.scenario.actors
    points = short_model.resimulate(sweep, tracks, tracks, rng=np.random.default_rng(0))
    assert np.array_equal(points, sweep.points)


def test_re_simulated_points_keep_the_sweep_layout_and_their_beams(
    short_log: SyntheticLog, short_model: ResimModel
) -> None:
    sweep = short_log.scenario.sweeps[20]
    parked = _nearest_parked_car(short_log, 20)
    perturbed = _moved(short_log.scenario.actors, parked, -2.0, -1.0, 0.2)
    points, stats = short_model.resimulate_with_stats(
        sweep, short_log.scenario.actors, perturbed, rng=np.random.default_rng(0)
    )
    assert points.dtype == sweep.points.dtype
    assert stats.actors[parked].removed_points > 100
    assert stats.actors[parked].inserted_returns > 100
    # Every point keeps (or, when new, copies) the ring of the beam that measured it.
    rows = short_model.beam_rows.nearest_rows(np.column_stack([points["x"], points["y"], points["z"]]).astype(float))
    assert np.mean(rows == points["ring"]) > 0.999
    unchanged = np.isin(sweep.points, points)
    assert np.mean(unchanged) > 0.95  # only the rays near the moved car changed


def test_removing_an_actor_leaves_only_ground_inside_its_box(short_log: SyntheticLog, short_model: ResimModel) -> None:
    sweep = short_log.scenario.sweeps[20]
    removed = _nearest_parked_car(short_log, 20)
    remaining = tuple(track for track in short_log.scenario.actors if track.actor_id != removed)
    points, stats = short_model.resimulate_with_stats(
        sweep, short_log.scenario.actors, remaining, rng=np.random.default_rng(0)
    )
    parked = short_log.scenario.actor(removed)
    pose = track_pose_at(parked, sweep.stamp_ns)
    assert pose is not None
    local = (
        np.column_stack([points["x"], points["y"], points["z"]]) - (invert_rigid(sweep.sensor_pose) @ pose)[:3, 3]
    ) @ (invert_rigid(sweep.sensor_pose) @ pose)[:3, :3]
    in_box = np.all(np.abs(local) <= 0.5 * parked.size, axis=1)
    assert np.count_nonzero(in_box) > 0
    assert np.all(local[in_box, 2] <= -0.5 * parked.size[2] + 0.2)  # road and curb under it, nothing of the car
    assert stats.fill_fraction > 0.9


def test_the_same_generator_state_gives_the_same_sweep(short_log: SyntheticLog, short_model: ResimModel) -> None:
    sweep = short_log.scenario.sweeps[15]
    perturbed = _moved(short_log.scenario.actors, "oncoming", 0.0, 1.0, 0.1)
    first = short_model.resimulate(sweep, short_log.scenario.actors, perturbed, rng=np.random.default_rng(4))
    second = short_model.resimulate(sweep, short_log.scenario.actors, perturbed, rng=np.random.default_rng(4))
    assert np.array_equal(first, second)


def test_only_actors_of_the_log_can_be_inserted(short_log: SyntheticLog, short_model: ResimModel) -> None:
    sweep = short_log.scenario.sweeps[0]
    lead = short_log.scenario.actor("lead")
    stranger = ActorTrack("stranger", lead.actor_class, lead.size, lead.stamps_ns, lead.centers, lead.yaws)
    with pytest.raises(ResimError, match="stranger"):
        short_model.resimulate(
            sweep,
            short_log.scenario.actors,
            (*short_log.scenario.actors, stranger),
            rng=np.random.default_rng(0),
        )


def test_a_built_model_is_read_back_from_the_cache(
    short_log: SyntheticLog, short_model: ResimModel, short_cache: Path
) -> None:
    assert len(list(short_cache.glob("resim-*.npz"))) == 1
    again = ResimModel.build(short_log.scenario, short_cache)  # read, not built: the same arrays
    assert np.array_equal(short_model.background.surfels.centers, again.background.surfels.centers)
    assert again.assets.keys() == short_model.assets.keys()
    sweep = short_log.scenario.sweeps[25]
    perturbed = _moved(short_log.scenario.actors, "lead", 1.0, 0.0, 0.0)
    assert np.array_equal(
        short_model.resimulate(sweep, short_log.scenario.actors, perturbed, rng=np.random.default_rng(1)),
        again.resimulate(sweep, short_log.scenario.actors, perturbed, rng=np.random.default_rng(1)),
    )
