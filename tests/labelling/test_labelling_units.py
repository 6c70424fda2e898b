"""The labeller's parts on small made-up inputs whose answers are known."""

from __future__ import annotations

import numpy as np
import pytest

from advsim_ros.core.types import ActorTrack, ScenarioError
from advsim_ros.labelling.config import OfflineTrackerConfig
from advsim_ros.labelling.evaluation import evaluate_tracks
from advsim_ros.labelling.odometry import mount_from_string, trajectory_errors
from advsim_ros.labelling.refine import reanchor
from advsim_ros.labelling.tracking import associate_forwards, link_fragments, rts_smooth

TIMES = np.arange(40) * 0.1  # [s]


def _line(speed: float = 8.0) -> np.ndarray:
    return np.column_stack([speed * TIMES, np.full(TIMES.shape, 3.0)])


def test_rts_smoother_is_closer_to_the_truth_than_the_detections_and_fills_gaps() -> None:
    rng = np.random.default_rng(0)
    truth = _line()
    frames = np.array([index for index in range(40) if index not in (10, 11, 12, 25)])
    noisy = truth[frames] + rng.normal(0.0, 0.3, (frames.shape[0], 2))
    smoothed = rts_smooth(frames, noisy, TIMES, OfflineTrackerConfig())
    assert smoothed.frames.tolist() == list(range(40))
    raw_error = np.linalg.norm(noisy - truth[frames], axis=1).mean()
    smooth_error = np.linalg.norm(smoothed.states[:, :2] - truth, axis=1).mean()
    assert smooth_error < 0.6 * raw_error
    assert np.allclose(smoothed.states[5:35, 2], 8.0, atol=0.8)  # the velocity is recovered


def test_two_crossing_free_objects_stay_apart_and_a_broken_track_is_linked() -> None:
    first, second = _line(8.0), _line(-5.0) + np.array([30.0, 6.0])
    frames = np.concatenate([np.arange(40), [index for index in range(40) if not 15 <= index < 22]])
    xy = np.concatenate([first, second[[index for index in range(40) if not 15 <= index < 22]]])
    config = OfflineTrackerConfig(max_misses=2, link_gap=10)
    tracks = associate_forwards(frames, xy, TIMES, 2.5, config)
    assert len(tracks) == 3  # the second object broke during its 0.7 s gap
    linked = link_fragments(tracks, frames, xy, TIMES, config)
    assert sorted(len(track) for track in linked) == [33, 40]


def test_reanchoring_keeps_the_edge_facing_the_sensor() -> None:
    box = np.array([[10.0, 0.0, 0.0, 3.0, 1.6]])  # seen from behind: 3 m of a 5 m van
    centre = reanchor(box, np.array([[0.0, 0.0]]), length=5.0, width=1.6)
    assert centre[0, 0] == pytest.approx(11.0)  # near edge stays at 8.5 m, the box grows away
    assert centre[0, 1] == pytest.approx(0.0)


def _track(actor_id: str, offset: float = 0.0) -> ActorTrack:
    return ActorTrack(
        actor_id=actor_id, actor_class="vehicle", size=np.array([4.0, 1.8, 1.5]),
        stamps_ns=(np.arange(10) * 100_000_000).astype(np.int64),
        centers=np.column_stack([10.0 + np.arange(10) + offset, np.zeros(10), np.zeros(10)]), yaws=np.zeros(10),
    )  # fmt: skip


def test_evaluation_scores_identical_and_displaced_tracks() -> None:
    stamps = (np.arange(10) * 100_000_000).astype(np.int64)
    origin = np.zeros((10, 2))
    same = evaluate_tracks([_track("a")], [_track("b")], stamps, origin)
    assert (same.track_precision, same.track_recall, same.frame_recall) == (1.0, 1.0, 1.0)
    assert same.median_center_error == pytest.approx(0.0)
    far = evaluate_tracks([_track("a")], [_track("b", offset=2.5)], stamps, origin)  # IoU (4-2.5)/(4+2.5) < 0.5
    assert (far.track_recall, far.track_precision, far.matched_boxes) == (0.0, 0.0, 0)
    assert far.missed_truth_tracks == ("a",)
    assert far.wrong_labelled_tracks == ("b",)


def test_mount_string_and_trajectory_errors() -> None:
    mount = mount_from_string("1.0,0,1.7,0,0,1.5707963")
    assert np.allclose(mount[:3, 3], [1.0, 0.0, 1.7])
    assert mount[0, 1] == pytest.approx(-1.0)
    with pytest.raises(ScenarioError, match="six"):
        mount_from_string("1,2,3")
    poses = np.tile(np.eye(4), (101, 1, 1))
    poses[:, 0, 3] = np.arange(101.0)
    drifted = poses.copy()
    drifted[:, 1, 3] = 0.02 * np.arange(101.0)  # 2 m sideways over 100 m
    errors = trajectory_errors(drifted, poses)
    assert errors["path_length_m"] == pytest.approx(100.0)
    assert errors["end_drift_m_per_100m"] == pytest.approx(2.0)
    assert errors["drift_m_per_100m"] == pytest.approx(2.0, rel=0.05)
