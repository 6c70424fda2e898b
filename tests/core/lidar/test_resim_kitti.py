"""Re-simulation on real KITTI tracking 0000: re-inserting every actor where it was, and removing actors.

The actor's points are the ones the model itself calls the actor's: inside its box grown
by box_margin, more than 0.15 m above the box's bottom (KITTI labels are a little loose
and sit on the road, whose points are not the actor's).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest
from scipy.spatial import cKDTree

from advsim_ros.core.lidar.boxes import actor_region, inside, invert_rigid, removal_region, to_box_frame, track_pose_at
from advsim_ros.core.lidar.resim import ResimModel
from advsim_ros.core.lidar.sensor import xyz_of
from advsim_ros.core.types import Scenario

FRAMES = range(0, 154, 7)  # 22 sweeps spread over the log
ACTOR_CLEARANCE = 0.15  # [m]


def _chamfer(a: np.ndarray, b: np.ndarray) -> float:
    """Symmetric mean nearest-neighbour distance between two point sets [m]."""
    return 0.5 * float(cKDTree(b).query(a)[0].mean() + cKDTree(a).query(b)[0].mean())


@pytest.mark.slow
def test_reinserting_every_actor_where_it_was_keeps_its_points(
    kitti_scenario: Scenario, kitti_model: ResimModel, record_property: Callable[[str, object], None]
) -> None:
    """Acceptance: point count within +-25 % per actor, median Chamfer distance of actor points <= 0.15 m."""
    counts: dict[str, list[int]] = {}
    chamfers: list[float] = []
    rng = np.random.default_rng(0)
    for frame in FRAMES:
        sweep = kitti_scenario.sweeps[frame]
        present = [track for track in kitti_scenario.actors if track_pose_at(track, sweep.stamp_ns) is not None]
        points = kitti_model.resimulate(
            sweep, kitti_scenario.actors, kitti_scenario.actors, rng=rng, moved=[track.actor_id for track in present]
        )
        before_all, after_all = xyz_of(sweep.points), xyz_of(points)
        for track in present:
            pose = track_pose_at(track, sweep.stamp_ns)
            assert pose is not None
            in_sensor = invert_rigid(sweep.sensor_pose) @ pose
            region = actor_region(track.size, kitti_model.config.box_margin, ACTOR_CLEARANCE)
            before = before_all[inside(to_box_frame(before_all, in_sensor), region)]
            after = after_all[inside(to_box_frame(after_all, in_sensor), region)]
            total = counts.setdefault(track.actor_id, [0, 0])
            total[0] += before.shape[0]
            total[1] += after.shape[0]
            if before.shape[0] >= 10 and after.shape[0] >= 10:
                chamfers.append(_chamfer(before, after))
    ratios = {actor_id: after / before for actor_id, (before, after) in counts.items() if before > 0}
    record_property("count_ratio_per_actor", {key: round(value, 3) for key, value in ratios.items()})
    record_property("median_chamfer_m", round(float(np.median(chamfers)), 4))
    assert len(ratios) == len(kitti_scenario.actors)
    assert all(0.75 <= ratio <= 1.25 for ratio in ratios.values()), ratios
    assert float(np.median(chamfers)) <= 0.15


@pytest.mark.slow
def test_removing_an_actor_leaves_none_of_its_points_and_fills_the_freed_rays(
    kitti_scenario: Scenario, kitti_model: ResimModel, record_property: Callable[[str, object], None]
) -> None:
    freed = filled = removed_actors = 0
    for frame in FRAMES[::2]:
        sweep = kitti_scenario.sweeps[frame]
        sensor_from_world = invert_rigid(sweep.sensor_pose)
        for track in kitti_scenario.actors:
            pose = track_pose_at(track, sweep.stamp_ns)
            if pose is None:
                continue
            others = [other for other in kitti_scenario.actors if other.actor_id != track.actor_id]
            points, stats = kitti_model.resimulate_with_stats(
                sweep, kitti_scenario.actors, others, rng=np.random.default_rng(frame)
            )
            box = removal_region(track.size, 0.0)
            in_box = inside(to_box_frame(xyz_of(sweep.points), sensor_from_world @ pose), box)
            # Every logged point in the box was cut out (its ray re-cast), and what the re-cast rays
            # found in the box is the road under the actor, never the actor: nothing above the ground.
            assert stats.actors[track.actor_id].removed_points >= np.count_nonzero(in_box)
            local = to_box_frame(xyz_of(points), sensor_from_world @ pose)
            after_in_box = local[inside(local, box)]
            assert np.all(after_in_box[:, 2] <= -0.5 * track.size[2] + 0.3), "a point above the road is left in the box"
            freed += stats.actors[track.actor_id].freed_rays
            filled += stats.actors[track.actor_id].filled_rays
            removed_actors += 1
    record_property("removed_actors", removed_actors)
    record_property("fill_fraction", round(filled / freed, 4))
    assert removed_actors > 30
    assert filled / freed > 0.8
