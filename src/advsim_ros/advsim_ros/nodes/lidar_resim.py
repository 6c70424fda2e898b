"""lidar_resim: turns each logged sweep into the sweep of the query's perturbed world.

It builds (or loads from the cache) the log's re-simulation model once, keeps the perturbed
tracks of each query, and for every logged sweep the player sends (on the sim clock) it looks
up the query and log time through the shared episode clock, takes the sensor pose from the
ego odometry of the same stamp, re-simulates, and publishes the result on the LiDAR topic with
the logged sweep's header. Messages of the three inputs are matched by stamp, in any order.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from advsim_ros.core.lidar.config import ResimConfig
from advsim_ros.core.lidar.resim import ResimModel
from advsim_ros.core.types import ActorTrack, Sweep
from advsim_ros.io.bag import ODOMETRY, POINTCLOUD2, cloud_msg, pose_matrix
from advsim_ros.io.cache import cache_root
from advsim_ros.io.pointcloud import cloud_to_points
from advsim_ros.ros import qos, topics
from advsim_ros.ros.graph_node import GraphNode, run_node
from advsim_ros.ros.params import declare_config
from advsim_ros.ros.wire import ACTOR_TRACK_ARRAY, header_stamp_ns, tracks_from_msg


@dataclass(frozen=True)
class ResimNodeConfig:
    """/lidar_resim parameters besides the re-simulation settings (params/lidar_resim.yaml)."""

    seed: int = 0  # ray-drop sampling: the generator of (query, frame) is seeded from (seed, query, frame)
    cache_dir: str = ""  # where the background and assets are cached; "" = <advsim cache>/resim


class LidarResim(GraphNode):
    def __init__(self) -> None:
        super().__init__("lidar_resim")
        self.node_config = declare_config(self, ResimNodeConfig)
        resim_config = declare_config(self, ResimConfig, "resim.")
        self.scenario, self.clock = self.load_scenario(load_sweeps=True)
        cache = Path(self.node_config.cache_dir) if self.node_config.cache_dir else cache_root() / "resim"
        self.get_logger().info(f"loading or building the re-simulation model (cache {cache})")
        self.model = ResimModel.build(self.scenario, cache_dir=cache, config=resim_config)
        self.publish_sweep = self.raw_publisher(POINTCLOUD2, topics.LIDAR, qos.LIDAR_OUT)
        self.perturbed: dict[int, tuple[ActorTrack, ...]] = {}
        self.clouds: dict[int, bytes] = {}  # sim stamp -> logged sweep waiting for its pose or tracks
        self.poses: dict[int, Any] = {}  # sim stamp -> T_world_ego
        self.raw_subscription(ACTOR_TRACK_ARRAY, topics.PERTURBED_TRACKS, qos.LATCHED, self._on_tracks)
        self.raw_subscription(POINTCLOUD2, topics.ORIGINAL_POINTS, qos.STREAM, self._on_cloud, decode=False)
        self.raw_subscription(ODOMETRY, topics.ODOM, qos.STREAM, self._on_odometry)
        self.get_logger().info("ready")

    def _on_tracks(self, message: Any) -> None:
        self.perturbed[int(message.query_id)] = tracks_from_msg(message)
        self._process_ready()

    def _on_cloud(self, raw: bytes) -> None:
        self.clouds[header_stamp_ns(raw)] = raw
        self._process_ready()

    def _on_odometry(self, message: Any) -> None:
        stamp = int(message.header.stamp.sec) * 1_000_000_000 + int(message.header.stamp.nanosec)
        self.poses[stamp] = pose_matrix(message.pose.pose.position, message.pose.pose.orientation, "ego odometry")
        self._process_ready()

    def _process_ready(self) -> None:
        for sim_stamp in sorted(self.clouds):
            query_id = self.clock.locate(sim_stamp).query_id
            if sim_stamp in self.poses and query_id in self.perturbed:
                self._resimulate(sim_stamp, self.clouds.pop(sim_stamp), self.poses.pop(sim_stamp))
        # queries strictly follow each other: what belongs to finished queries will never be needed
        if self.clouds:
            oldest = self.clock.locate(min(self.clouds)).query_id
            self.perturbed = {q: t for q, t in self.perturbed.items() if q >= oldest}

    def _resimulate(self, sim_stamp: int, raw: bytes, ego_pose: Any) -> None:
        located = self.clock.locate(sim_stamp)
        cloud = self.wire.decode(raw, POINTCLOUD2)
        logged = Sweep(
            stamp_ns=located.log_time_ns,
            frame_id=cloud.header.frame_id,
            points=cloud_to_points(cloud),
            sensor_pose=ego_pose @ self.scenario.ego_T_sensor,
        )
        moved = {track.actor_id: track for track in self.perturbed[located.query_id]}
        world = [moved.get(actor.actor_id, actor) for actor in self.scenario.actors]
        rng = np.random.default_rng([self.node_config.seed, located.query_id, located.offset_ns])
        points = self.model.resimulate(logged, self.scenario.actors, world, rng=rng) if moved else logged.points
        out = Sweep(stamp_ns=sim_stamp, frame_id=logged.frame_id, points=points, sensor_pose=logged.sensor_pose)
        self.publish_sweep(cloud_msg(self.wire.store, out))


def main() -> None:
    run_node(LidarResim)


if __name__ == "__main__":
    main()
