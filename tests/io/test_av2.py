"""Argoverse 2 import: frames checked against AV2's own point counts and map, and bad input."""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.feather as feather
import pytest
import shapely

from advsim_ros.core.types import ActorClass
from advsim_ros.io.av2 import Av2Error, lane_centerline, load_av2_log

Box = tuple[np.ndarray, float, np.ndarray]


def test_every_log_gives_tracks_ego_poses_and_a_map_without_the_ego_among_the_actors(av2_logs: list[Path]) -> None:
    for log in av2_logs:
        scenario = load_av2_log(log)
        assert scenario.num_frames >= 150  # 15.5 s at 10 Hz
        assert len(scenario.actors) >= 100
        assert {ActorClass.VEHICLE, ActorClass.OTHER} <= {actor.actor_class for actor in scenario.actors}
        assert scenario.road_map is not None
        assert len(scenario.road_map.drivable_areas) >= 5
        assert len(scenario.road_map.lane_centerlines) >= 100
        ego_xy = scenario.ego.xy
        for actor in scenario.actors:  # nothing labelled sits on the ego itself
            frames = np.searchsorted(scenario.frame_stamps_ns, actor.stamps_ns)
            assert np.min(np.linalg.norm(actor.centers[:, :2] - ego_xy[frames], axis=1)) > 1.0, actor.actor_id


def test_the_ego_size_comes_from_the_ego_vehicle_label_where_there_is_one(av2_logs: list[Path]) -> None:
    with_ego = [log for log in av2_logs if (log / "annotations_with_ego.feather").is_file()]
    assert with_ego
    for log in with_ego:
        table = feather.read_table(log / "annotations_with_ego.feather")
        ego_rows = [i for i, category in enumerate(table["category"].to_pylist()) if category == "EGO_VEHICLE"]
        names = ("length_m", "width_m", "height_m")
        labelled = [np.median(np.take(table[name].to_numpy(), ego_rows)) for name in names]
        np.testing.assert_allclose(load_av2_log(log).ego_geometry.size, labelled)


def test_the_ego_drives_inside_the_drivable_area_along_lane_centrelines(av2_logs: list[Path]) -> None:
    for log in av2_logs:
        scenario = load_av2_log(log)
        assert scenario.road_map is not None
        drivable = shapely.union_all([shapely.Polygon(area) for area in scenario.road_map.drivable_areas])
        inside = shapely.contains_xy(drivable, scenario.ego.xy[:, 0], scenario.ego.xy[:, 1])
        assert inside.mean() > 0.95
        lanes = shapely.MultiLineString([lane.tolist() for lane in scenario.road_map.lane_centerlines])
        gaps = shapely.distance(lanes, shapely.points(scenario.ego.xy))
        assert np.median(gaps) < 1.0  # the ego keeps near a lane centre


def test_boxes_in_the_city_frame_hold_the_points_av2_counted_in_them(
    av2_logs: list[Path], points_in_boxes: Callable[[np.ndarray, list[Box]], list[int]]
) -> None:
    checked = 0
    for log in av2_logs:
        if not (log / "sensors").is_dir():
            continue
        scenario = load_av2_log(log)
        table = feather.read_table(log / "annotations.feather")
        expected = {
            (int(stamp), str(uuid)): int(count)
            for stamp, uuid, count in zip(
                table["timestamp_ns"].to_pylist(),
                table["track_uuid"].to_pylist(),
                table["num_interior_pts"].to_pylist(),
                strict=True,
            )
        }
        for sweep in scenario.sweeps:
            world = np.einsum("ij,nj->ni", sweep.sensor_pose[:3, :3], sweep.xyz) + sweep.sensor_pose[:3, 3]
            boxes, counts = [], []
            for actor in scenario.actors:
                index = np.flatnonzero(actor.stamps_ns == sweep.stamp_ns)
                if index.size:
                    boxes.append((actor.centers[index[0]], float(actor.yaws[index[0]]), actor.size))
                    counts.append(expected[(sweep.stamp_ns, actor.actor_id)])
            ours = np.array(points_in_boxes(world, boxes))
            theirs = np.array(counts)
            assert abs(ours.sum() / theirs.sum() - 1.0) < 0.03  # yaw-only boxes in a tilted city frame: ~1 %
            assert np.all(ours[theirs >= 20] > 0)
            checked += 1
    assert checked >= 2


def test_sweeps_keep_every_av2_field_with_coordinates_widened_to_float32(av2_logs: list[Path]) -> None:
    log = next(log for log in av2_logs if (log / "sensors").is_dir())
    scenario = load_av2_log(log)
    sweep = scenario.sweeps[0]
    assert sweep.points.dtype.names == ("x", "y", "z", "intensity", "laser_number", "offset_ns")
    assert sweep.points.dtype["x"] == np.float32
    path = log / "sensors" / "lidar" / f"{sweep.stamp_ns}.feather"
    np.testing.assert_array_equal(sweep.points["x"], feather.read_table(path)["x"].to_numpy().astype(np.float32))
    assert sweep.frame_id == "egovehicle"
    np.testing.assert_array_equal(scenario.ego_T_sensor, np.eye(4))


def test_a_lane_centreline_is_the_midline_of_its_boundaries() -> None:
    left = np.array([[0.0, 2.0], [10.0, 2.0]])
    right = np.array([[0.0, -1.0], [5.0, -1.0], [10.0, -1.0]])
    centre = lane_centerline(left, right)
    np.testing.assert_allclose(centre[:, 1], 0.5)
    np.testing.assert_allclose(centre[[0, -1], 0], [0.0, 10.0])
    assert np.all(np.diff(centre[:, 0]) > 0)  # in driving direction
    assert np.all(np.diff(centre[:, 0]) <= 1.0 + 1e-9)  # about 1 m apart


# --------------------------------------------------------------------------- bad input


def _copy_log(av2_logs: list[Path], tmp_path: Path) -> Path:
    source = next(log for log in av2_logs if (log / "annotations_with_ego.feather").is_file())
    return Path(shutil.copytree(source, tmp_path / source.name))


def _rewrite(path: Path, edit: Callable[[dict[str, list[object]]], None]) -> None:
    columns = feather.read_table(path).to_pydict()
    edit(columns)
    feather.write_feather(pa.table(columns), path)


def test_a_nan_ego_pose_is_rejected_naming_the_row(av2_logs: list[Path], tmp_path: Path) -> None:
    log = _copy_log(av2_logs, tmp_path)

    def poison(columns: dict[str, list[object]]) -> None:
        columns["tx_m"][3] = float("nan")

    _rewrite(log / "city_SE3_egovehicle.feather", poison)
    with pytest.raises(Av2Error, match=r"city_SE3_egovehicle\.feather: row 3 has a NaN or infinite pose"):
        load_av2_log(log)


def test_an_annotated_time_without_an_ego_pose_is_rejected(av2_logs: list[Path], tmp_path: Path) -> None:
    log = _copy_log(av2_logs, tmp_path)
    first_frame = min(feather.read_table(log / "annotations_with_ego.feather")["timestamp_ns"].to_pylist())

    def drop(columns: dict[str, list[object]]) -> None:
        keep = [i for i, stamp in enumerate(columns["timestamp_ns"]) if stamp != first_frame]
        for name in columns:
            columns[name] = [columns[name][i] for i in keep]

    _rewrite(log / "city_SE3_egovehicle.feather", drop)
    with pytest.raises(Av2Error, match=f"no ego pose at annotated LiDAR time {first_frame} ns"):
        load_av2_log(log)


def test_missing_annotations_and_a_broken_map_are_named(av2_logs: list[Path], tmp_path: Path) -> None:
    log = _copy_log(av2_logs, tmp_path)
    (next((log / "map").glob("log_map_archive_*.json"))).write_text("{not json")
    with pytest.raises(Av2Error, match="not a readable JSON map"):
        load_av2_log(log)
    (log / "annotations_with_ego.feather").unlink()
    with pytest.raises(Av2Error, match=r"no annotations\.feather or annotations_with_ego\.feather"):
        load_av2_log(log)


def test_a_map_lane_with_one_boundary_point_is_rejected(av2_logs: list[Path], tmp_path: Path) -> None:
    log = _copy_log(av2_logs, tmp_path)
    path = next((log / "map").glob("log_map_archive_*.json"))
    data = json.loads(path.read_text())
    lane_id, lane = next((key, lane) for key, lane in data["lane_segments"].items() if lane["lane_type"] == "VEHICLE")
    lane["left_lane_boundary"] = lane["left_lane_boundary"][:1]
    path.write_text(json.dumps(data))
    with pytest.raises(Av2Error, match=f"lane segment {lane_id} has a boundary with fewer than 2 points"):
        load_av2_log(log)
