"""A track's per-frame points aligned onto each other: planar ICP that removes the label noise between frames.

The log's points of one actor, in its box frame, come from many frames whose labels each sit a little
off; log_points aligns them before the actor's asset (core.lidar.assets) is built from them.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from advsim_ros.core.lidar.surfels import PointSamples
from advsim_ros.core.types import FloatArray

ICP_ITERATIONS = 10
ICP_MIN_MATCHES = 30  # frames with fewer points (or matches) are not aligned
ICP_MAX_DISTANCE = 0.3  # points farther than this from the reference do not pull [m]
ICP_MAX_SHIFT = 0.5  # larger corrections are refused [m]
ICP_MAX_TURN = np.deg2rad(8.0)  # [rad]
ICP_GAIN = 0.8  # a correction must bring the mean fit error below this share of the uncorrected one
ICP_SOURCE_POINTS = 800  # a frame's points are thinned to about this many for its alignment
ICP_REFERENCE_POINTS = 30_000  # the merged reference of the second pass is thinned to about this many points


def _fit_error(points: FloatArray, tree: cKDTree, max_distance: float) -> float:
    """Mean distance [m] from points to their nearest reference point, capped at max_distance."""
    distance, _ = tree.query(points, distance_upper_bound=max_distance)
    return float(np.mean(np.minimum(distance, max_distance)))


def _planar_icp(source: FloatArray, target: FloatArray, tree: cKDTree, max_distance: float) -> FloatArray | None:
    """(4, 4) yaw-and-shift transform that best lays source (N, 3) onto target (M, 3), or None when it does not fit.

    Point-to-point ICP restricted to a turn about z and a shift, as label noise is; a
    correction beyond ICP_MAX_SHIFT / ICP_MAX_TURN is taken for a slide along a flat side
    and refused.
    """
    rotation, shift = np.eye(3), np.zeros(3)
    source = source[:: max(1, source.shape[0] // ICP_SOURCE_POINTS)]
    for _ in range(ICP_ITERATIONS):
        moved = source @ rotation.T + shift
        distance, index = tree.query(moved, distance_upper_bound=max_distance)  # few points: no threads
        matched = np.isfinite(distance)
        if np.count_nonzero(matched) < ICP_MIN_MATCHES:
            return None
        mine, theirs = moved[matched], target[index[matched]]
        mine_centre, their_centre = mine[:, :2].mean(axis=0), theirs[:, :2].mean(axis=0)
        cross = (mine[:, :2] - mine_centre).T @ (theirs[:, :2] - their_centre)
        angle = np.arctan2(cross[0, 1] - cross[1, 0], cross[0, 0] + cross[1, 1])
        turn = np.array([[np.cos(angle), -np.sin(angle), 0.0], [np.sin(angle), np.cos(angle), 0.0], [0.0, 0.0, 1.0]])
        step = np.zeros(3)
        step[:2] = their_centre - turn[:2, :2] @ mine_centre
        step[2] = float(np.mean(theirs[:, 2] - mine[:, 2]))
        rotation, shift = turn @ rotation, turn @ shift + step
        if abs(angle) < 1e-4 and float(np.linalg.norm(step)) < 1e-3:
            break  # converged
    total_turn = abs(float(np.arctan2(rotation[1, 0], rotation[0, 0])))
    if np.linalg.norm(shift) > ICP_MAX_SHIFT or total_turn > ICP_MAX_TURN:
        return None
    # Keep a correction only when it clearly fits better: partial views of one car otherwise
    # pull each other along their flat sides and blur an asset whose labels were right.
    if _fit_error(source @ rotation.T + shift, tree, max_distance) > ICP_GAIN * _fit_error(source, tree, max_distance):
        return None
    transform = np.eye(4)
    transform[:3, :3], transform[:3, 3] = rotation, shift
    return transform


def align_frames(frames: list[PointSamples]) -> list[PointSamples]:
    """The track's per-frame box-frame points, each moved onto the others (label noise removed).

    Two passes: every frame onto the frame with most points, then every frame onto the
    merged result of the first pass. Frames that do not fit stay where their label put
    them. The corrections are then re-centred (their mean undone), so that the asset sits
    in its box the way the labels place the actor on average, not the way one frame does.
    """
    if len(frames) < 2:
        return frames
    transforms = [np.eye(4) for _ in frames]
    reference = max(frames, key=lambda frame: frame.count).xyz
    for _ in range(2):
        tree = cKDTree(reference)
        for index, frame in enumerate(frames):
            if frame.count < ICP_MIN_MATCHES:
                continue
            current = frame.transformed(transforms[index])
            correction = _planar_icp(current.xyz, reference, tree, ICP_MAX_DISTANCE)
            if correction is not None:
                transforms[index] = correction @ transforms[index]
        aligned = [frame.transformed(transform) for frame, transform in zip(frames, transforms, strict=True)]
        everything = PointSamples.concatenate(aligned).xyz
        reference = everything[:: max(1, everything.shape[0] // ICP_REFERENCE_POINTS)]
    weights = np.array([frame.count for frame in frames], dtype=np.float64)
    mean_turn = float(np.average([np.arctan2(t[1, 0], t[0, 0]) for t in transforms], weights=weights))
    mean_shift = np.average([t[:3, 3] for t in transforms], axis=0, weights=weights)
    centre = np.eye(4)
    centre[:3, :3] = [
        [np.cos(mean_turn), -np.sin(mean_turn), 0.0],
        [np.sin(mean_turn), np.cos(mean_turn), 0.0],
        [0, 0, 1],
    ]
    centre[:3, 3] = mean_shift
    undo = np.linalg.inv(centre)
    return [frame.transformed(undo @ transform) for frame, transform in zip(frames, transforms, strict=True)]
