"""Ego poses of users' bags: a static transform through the /tf_static tree, poses at the sweeps' stamps."""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from advsim_ros.core.types import FloatArray, IntArray
from advsim_ros.io.bag.config import BagError


def static_transform(static: dict[tuple[str, str], FloatArray], parent: str, child: str) -> FloatArray | None:
    """T_parent_child through the static transform tree (either direction of each edge), or None."""
    if parent == child:
        return np.eye(4)
    edges: dict[str, list[tuple[str, FloatArray]]] = defaultdict(list)
    for (a, b), matrix in static.items():
        edges[a].append((b, matrix))
        inverse = np.asarray(np.linalg.inv(matrix), dtype=np.float64)
        edges[b].append((a, inverse))
    frontier: list[tuple[str, FloatArray]] = [(parent, np.eye(4))]
    seen = {parent}
    while frontier:
        frame, transform = frontier.pop()
        for neighbour, step in edges[frame]:
            if neighbour in seen:
                continue
            composed: FloatArray = transform @ step
            if neighbour == child:
                return composed
            seen.add(neighbour)
            frontier.append((neighbour, composed))
    return None


def interpolate_poses(stamps: IntArray, poses: FloatArray, targets: IntArray, path: Path) -> FloatArray:
    """Poses at the target stamps: linear in position, slerp in rotation; BagError outside the covered span."""
    order = np.argsort(stamps, kind="stable")
    stamps, poses = stamps[order], poses[order]
    unique = np.concatenate([[True], np.diff(stamps) > 0])
    stamps, poses = stamps[unique], poses[unique]
    outside = (targets < stamps[0]) | (targets > stamps[-1])
    if np.any(outside):
        first = int(targets[np.flatnonzero(outside)[0]])
        raise BagError(
            f"bag {path}: no ego pose covers the sweep at {first} ns (poses span {stamps[0]}..{stamps[-1]} ns)"
        )
    if stamps.shape[0] == 1:
        return np.repeat(poses, targets.shape[0], axis=0)
    times = (stamps - stamps[0]).astype(np.float64)
    query = (targets - stamps[0]).astype(np.float64)
    result = np.tile(np.eye(4), (targets.shape[0], 1, 1))
    for axis in range(3):
        result[:, axis, 3] = np.interp(query, times, poses[:, axis, 3])
    result[:, :3, :3] = Slerp(times, Rotation.from_matrix(poses[:, :3, :3]))(query).as_matrix()
    return result
