"""The logged ego route of a scenario bag, as a planner that follows a route reads it (`advsim export route`).

A planner planning along a route (a CSV of waypoints, a nav_msgs/Path, a GeoJSON line) needs the
route the log's driver took, from the attack's window on, in the frame the planner works in. That
frame is the one its stack profile gives its plans in (`outputs.plan.frame_origin`): the bag's
world frame, a fixed pose in it, east-north-up at a datum, or the frame anchored at the stack's
first GNSS fix, which is the ego's position at the window's first frame (the adapter sends the
first fix there; adapters.plans.frame_transform). Without a profile the route is in the world
frame. GeoJSON is longitude/latitude (RFC 7946), from the profile's datum of the world frame.

Formats by the output's name: ``.csv`` (x, y, yaw, speed per row, a header line), ``.geojson``
(one LineString feature), anything else a rosbag2 folder with one nav_msgs/Path on ``/route``.
"""

from __future__ import annotations

import csv
import io
import json
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from advsim_ros.adapters.plans import PlanarTransform, frame_transform, geodetic_of
from advsim_ros.adapters.profile import StackProfile
from advsim_ros.core.geometry import wrap_angle
from advsim_ros.core.metrics import to_ego_frame
from advsim_ros.core.types import FloatArray, IntArray, Plan, Scenario, ScenarioError

if TYPE_CHECKING:
    from advsim_ros.io.bag import BagConfig

ROUTE_TOPIC = "/route"
FORMATS = {".csv": "csv", ".geojson": "geojson"}  # any other name: a rosbag2 folder


@dataclass(frozen=True)
class Route:
    """The ego's logged poses from the window's first frame to the log's end, in one frame."""

    frame_id: str
    stamps_ns: IntArray  # (N,) the log's frame stamps
    xy: FloatArray  # (N, 2) [m]
    yaws: FloatArray  # (N,) [rad]
    speeds: FloatArray  # (N,) along the route [m/s]
    world_xy: FloatArray  # (N, 2) the same points in the world frame (GeoJSON's source)

    @property
    def length(self) -> float:
        return float(np.sum(np.hypot(*np.diff(self.xy, axis=0).T)))


def route_of(scenario: Scenario, window_start: int, profile: StackProfile | None, world_frame: str) -> Route:
    """The route from frame window_start on, in the frame the profile's plans are in (world without one)."""
    ego = scenario.ego
    if not 0 <= window_start < ego.stamps_ns.shape[0] - 1:
        raise ScenarioError(f"--window-start {window_start}: the log has frames 0..{ego.stamps_ns.shape[0] - 1}")
    stamps, world_xy, world_yaws = ego.stamps_ns[window_start:], ego.xy[window_start:], ego.yaws[window_start:]
    steps = np.hypot(*np.diff(world_xy, axis=0).T) / (np.diff(stamps) / 1e9)
    speeds = np.concatenate([steps, steps[-1:]])  # the last pose keeps the speed it was reached at
    transform, frame_id = PlanarTransform(), world_frame
    if profile is not None:
        plan = profile.outputs.plan
        if plan.frame_origin == "tf":
            raise ScenarioError("the profile's plans are in a frame known at run time only (/tf): export without it")
        transform = frame_transform(plan, profile.inputs.pose.datum, world_xy[0])
        frame_id = plan.frame_id or world_frame
    xy = to_ego_frame(world_xy, np.array([transform.x, transform.y]), transform.yaw)  # world_T_frame inverted
    yaws = np.asarray(wrap_angle(world_yaws - transform.yaw), dtype=np.float64)
    return Route(frame_id, stamps, xy, yaws, speeds, world_xy)


def format_of(output: Path) -> str:
    return FORMATS.get(output.suffix.lower(), "bag")


def route_csv(route: Route) -> str:
    text = io.StringIO()
    writer = csv.writer(text, lineterminator="\n")
    writer.writerow(["x", "y", "yaw", "speed"])
    for (x, y), yaw, speed in zip(route.xy.tolist(), route.yaws.tolist(), route.speeds.tolist(), strict=True):
        writer.writerow([f"{x:.4f}", f"{y:.4f}", f"{yaw:.6f}", f"{speed:.4f}"])
    return text.getvalue()


def route_geojson(route: Route, profile: StackProfile | None) -> str:
    datum = None if profile is None else profile.inputs.pose.datum
    if datum is None:
        raise ScenarioError("GeoJSON needs the world frame's datum: give a --stack-profile with inputs.pose.datum")
    coordinates = []
    for x, y in route.world_xy.tolist():
        latitude, longitude, _ = geodetic_of(datum, x, y, 0.0)
        coordinates.append([round(longitude, 9), round(latitude, 9)])
    feature = {
        "type": "Feature",
        "geometry": {"type": "LineString", "coordinates": coordinates},
        "properties": {"name": "logged ego route", "length_m": round(route.length, 3)},
    }
    return json.dumps({"type": "FeatureCollection", "features": [feature]}, indent=1) + "\n"


def write_route_bag(route: Route, output: Path, overwrite: bool) -> None:
    """One nav_msgs/Path on /route, stamped at the route's first pose, each pose at its log time."""
    from advsim_ros.contract import codec, names
    from advsim_ros.contract.plan import path_msg
    from advsim_ros.io.bag.write import write_messages_bag

    plan = Plan(stamps_ns=route.stamps_ns, xy=route.xy, yaws=route.yaws)
    raw = codec.encode(path_msg(plan, int(route.stamps_ns[0]), route.frame_id))
    write_messages_bag(output, [(ROUTE_TOPIC, names.PATH, int(route.stamps_ns[0]), raw)], overwrite)


def export_route(
    bag: Path,
    output: Path,
    window_start: int,
    profile_file: Path | None,
    overwrite: bool,
    bag_config: BagConfig | None = None,
) -> str:
    """Write the route (format by output's name) atomically; returns one line saying what was written.

    ``bag_config`` is the bag's layout (--bag-params; default the contract's): its poses, its world frame."""
    from advsim_ros.adapters.profile import load_profile
    from advsim_ros.core.atomic import atomic_file
    from advsim_ros.io.bag import BagConfig, read_scenario_bag

    kind = format_of(output)
    if output.exists() and not overwrite:
        raise ScenarioError(f"{output} exists (pass --overwrite to replace it)")
    profile = None if profile_file is None else load_profile(profile_file)
    config = bag_config or BagConfig()
    scenario = read_scenario_bag(bag, config=config, load_sweeps=False)
    route = route_of(scenario, window_start, profile, config.world_frame)
    if kind == "bag":
        write_route_bag(route, output, overwrite)
    else:
        text = route_csv(route) if kind == "csv" else route_geojson(route, profile)
        with atomic_file(output, "w") as stream:
            stream.write(text)
    where = "longitude/latitude" if kind == "geojson" else f"frame {route.frame_id}"
    return f"route: {route.xy.shape[0]} poses, {route.length:.1f} m from frame {window_start} ({where}) -> {output}" + (
        f" ({ROUTE_TOPIC}, nav_msgs/Path)" if kind == "bag" else ""
    )
