"""``sensor_msgs_py.point_cloud2`` as stacks import it; the functions are advsim_ros.ros.point_cloud2's."""

from advsim_ros.ros.point_cloud2 import (
    create_cloud,
    create_cloud_xyz32,
    dtype_from_fields,
    fields_from_dtype,
    read_points,
    read_points_list,
    read_points_numpy,
)

__all__ = [
    "create_cloud",
    "create_cloud_xyz32",
    "dtype_from_fields",
    "fields_from_dtype",
    "read_points",
    "read_points_list",
    "read_points_numpy",
]
