"""Scenario messages: LiDAR sweeps (PointCloud2), the road map, the drivable-area grid, ScenarioInfo."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from advsim_ros.contract import names
from advsim_ros.contract.codec import ContractError, Msg, header_msg, message, stamp_ns
from advsim_ros.contract.pointcloud import cloud_to_points, points_are_bigendian, points_to_cloud_fields
from advsim_ros.contract.spatial import pose_matrix, pose_msg, transform_msg
from advsim_ros.core.types import (
    SOURCE_LOG,
    DrivableArea,
    EgoGeometry,
    FloatArray,
    RoadMap,
    Scenario,
    SensorModel,
    Sweep,
)

# nav_msgs/OccupancyGrid cell values: 0 free (drivable), 100 occupied (not drivable)
_FREE, _OCCUPIED = 0, 100


def cloud_msg(sweep: Sweep) -> Msg:
    """sensor_msgs/PointCloud2 of a sweep (sensor frame), the points' field layout kept byte for byte."""
    points = np.ascontiguousarray(sweep.points)
    fields, point_step = points_to_cloud_fields(points)
    xyz_finite = bool(np.all(np.isfinite(sweep.xyz))) if points.shape[0] else True
    return message(
        names.POINTCLOUD2,
        header=header_msg(sweep.stamp_ns, sweep.frame_id),
        height=1,
        width=int(points.shape[0]),
        fields=[
            message(names.POINT_FIELD, name=f.name, offset=f.offset, datatype=f.datatype, count=f.count) for f in fields
        ],
        is_bigendian=points_are_bigendian(points),
        point_step=point_step,
        row_step=point_step * int(points.shape[0]),
        data=points.view(np.uint8).reshape(-1),
        is_dense=xyz_finite,
    )


def sweep_from_cloud(cloud: Msg, sensor_pose: FloatArray, stamp_ns_override: int | None = None) -> Sweep:
    """A Sweep from a PointCloud2 (any field layout) and the sensor pose at its stamp."""
    stamp = stamp_ns(cloud.header.stamp) if stamp_ns_override is None else stamp_ns_override
    return Sweep(
        stamp_ns=stamp, frame_id=str(cloud.header.frame_id), points=cloud_to_points(cloud), sensor_pose=sensor_pose
    )


def _polyline(points: FloatArray) -> Msg:
    return message(
        names.POLYLINE,
        x=np.ascontiguousarray(points[:, 0], dtype=np.float64),
        y=np.ascontiguousarray(points[:, 1], dtype=np.float64),
    )


def road_map_msg(road_map: RoadMap, stamp: int, world_frame: str) -> Msg:
    return message(
        names.ROAD_MAP,
        header=header_msg(stamp, world_frame),
        drivable_areas=[_polyline(area) for area in road_map.drivable_areas],
        lane_centerlines=[_polyline(lane) for lane in road_map.lane_centerlines],
    )


def road_map_from_msg(road_map: Msg) -> RoadMap | None:
    """An advsim_msgs/RoadMap as a core RoadMap; None when it carries nothing."""

    def outline(polyline: Msg) -> FloatArray:
        return np.stack([np.asarray(polyline.x, dtype=np.float64), np.asarray(polyline.y, dtype=np.float64)], axis=-1)

    areas = tuple(outline(area) for area in road_map.drivable_areas)
    lanes = tuple(outline(lane) for lane in road_map.lane_centerlines)
    if not areas and not lanes:
        return None
    return RoadMap(drivable_areas=areas, lane_centerlines=lanes)


def drivable_grid_msg(area: DrivableArea, stamp: int, world_frame: str) -> Msg:
    """The drivable raster as nav_msgs/OccupancyGrid (free = drivable), viewable in RViz and Foxglove."""
    resolution = np.float32(area.resolution)
    if float(resolution) != area.resolution:
        raise ContractError(f"drivable raster resolution {area.resolution} m is not exact in float32")
    height, width = area.shape
    origin = np.eye(4)
    origin[:2, 3] = area.origin
    info = message(
        "nav_msgs/msg/MapMetaData",
        map_load_time=header_msg(stamp, world_frame).stamp,
        resolution=float(resolution),
        width=width,
        height=height,
        origin=pose_msg(origin),
    )
    data = np.where(area.mask, _FREE, _OCCUPIED).astype(np.int8).reshape(-1)
    return message(names.OCCUPANCY_GRID, header=header_msg(stamp, world_frame), info=info, data=data)


def drivable_area_from_grid(grid: Msg) -> DrivableArea:
    """An OccupancyGrid written by drivable_grid_msg (axis-aligned) as a DrivableArea."""
    info = grid.info
    origin = pose_matrix(info.origin.position, info.origin.orientation, "drivable grid origin")
    if not np.allclose(origin[:3, :3], np.eye(3)):
        raise ContractError("drivable grid: only axis-aligned grids (identity origin orientation) are supported")
    data = np.asarray(grid.data, dtype=np.int8)
    if data.shape[0] != int(info.width) * int(info.height):
        raise ContractError(f"drivable grid: {data.shape[0]} cells for {info.width} x {info.height}")
    mask = (data == _FREE).reshape(int(info.height), int(info.width))
    return DrivableArea(origin[:2, 3], float(info.resolution), mask, SOURCE_LOG)


@dataclass(frozen=True, eq=False)
class ScenarioInfoRecord:
    """What advsim_msgs/ScenarioInfo carries."""

    scenario_id: str
    source: str  # where the log came from
    world_frame: str
    ego_frame: str
    sensor_frame: str
    ego_T_sensor: FloatArray  # (4, 4)
    ego_geometry: EgoGeometry
    sensor: SensorModel | None


def scenario_info_msg(scenario: Scenario, world_frame: str, ego_frame: str, sensor_frame: str, source: str) -> Msg:
    sensor = scenario.sensor
    return message(
        names.SCENARIO_INFO,
        scenario_id=scenario.scenario_id,
        source=source,
        world_frame=world_frame,
        ego_frame=ego_frame,
        sensor_frame=sensor_frame,
        ego_to_sensor=transform_msg(scenario.ego_T_sensor),
        ego_length=float(scenario.ego_geometry.size[0]),
        ego_width=float(scenario.ego_geometry.size[1]),
        ego_height=float(scenario.ego_geometry.size[2]),
        ego_forward_offset=float(scenario.ego_geometry.forward_offset),
        has_sensor_model=sensor is not None,
        beam_elevations=np.array(sensor.beam_elevations if sensor else [], dtype=np.float64),
        azimuth_resolution=float(sensor.azimuth_resolution) if sensor else 0.0,
        min_range=float(sensor.min_range) if sensor else 0.0,
        max_range=float(sensor.max_range) if sensor else 0.0,
    )


def scenario_info_from_msg(info: Msg, what: str) -> ScenarioInfoRecord:
    sensor = None
    if info.has_sensor_model:
        sensor = SensorModel(
            beam_elevations=np.array(info.beam_elevations, dtype=np.float64),
            azimuth_resolution=float(info.azimuth_resolution),
            min_range=float(info.min_range),
            max_range=float(info.max_range),
        )
    return ScenarioInfoRecord(
        scenario_id=str(info.scenario_id),
        source=str(info.source),
        world_frame=str(info.world_frame),
        ego_frame=str(info.ego_frame),
        sensor_frame=str(info.sensor_frame),
        ego_T_sensor=pose_matrix(info.ego_to_sensor.translation, info.ego_to_sensor.rotation, what),
        ego_geometry=EgoGeometry(
            np.array([info.ego_length, info.ego_width, info.ego_height], dtype=np.float64),
            float(getattr(info, "ego_forward_offset", 1.0)),  # bags written before the field existed: 1 m
        ),
        sensor=sensor,
    )
