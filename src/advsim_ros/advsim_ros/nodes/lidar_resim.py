"""lidar_resim: answers each FrameRequest with the sweep of the query's perturbed world.

It loads (or builds and caches) the log's re-simulation model once, keeps each query's perturbed
tracks, and renders a requested frame (core.lidar.query) as soon as both the request and the
query's tracks are there, in whatever order they arrive. The sweep keeps the logged sweep's
frame and fields, carries the request's sim stamp and goes to the player (/advsim/rendered_points),
which hands it to the stack when the stack is ready for it: frames are rendered ahead while the
stack plans.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from advsim_ros.contract import topics
from advsim_ros.contract.protocol import FrameRequestRecord, frame_request_from_msg
from advsim_ros.contract.scenario import cloud_msg
from advsim_ros.contract.tracks import track_array_from_msg
from advsim_ros.core.lidar.config import ResimConfig
from advsim_ros.core.lidar.query import query_sweep
from advsim_ros.core.lidar.resim import ResimModel
from advsim_ros.core.types import ActorTrack, ScenarioError, Sweep
from advsim_ros.io.cache import cache_root
from advsim_ros.nodes.scenario_node import ScenarioNode
from advsim_ros.ros.graph_node import run_node
from advsim_ros.ros.params import declare_config


@dataclass(frozen=True)
class ResimNodeConfig:
    """/lidar_resim parameters besides the re-simulation settings (params/lidar_resim.yaml)."""

    seed: int = 0  # ray-drop sampling: seeded from (seed, frame, the perturbed tracks' content)
    cache_dir: str = ""  # where the background and assets are cached; "" = <advsim cache>/resim
    build_model: bool = True  # build the model at start-up (off for `advsim replay`: nothing moves there)


class LidarResim(ScenarioNode):
    def __init__(self) -> None:
        super().__init__("lidar_resim")
        self.config = declare_config(self, ResimNodeConfig)
        resim_config = declare_config(self, ResimConfig, "resim.")
        self.scenario, self.clock = self.load_scenario(load_sweeps=True)
        self.sweeps = {sweep.stamp_ns: sweep for sweep in self.scenario.sweeps}
        frames = self.window.frame_indices(self.scenario.num_frames)[: self.window.history_frames]
        missing = [i for i in frames if int(self.scenario.frame_stamps_ns[i]) not in self.sweeps]
        if missing:
            raise ScenarioError(f"scenario {self.scenario.scenario_id}: no LiDAR sweep at history frames {missing}")
        self.model: ResimModel | None = None
        if self.config.build_model:
            cache = Path(self.config.cache_dir) if self.config.cache_dir else cache_root() / "resim"
            self.get_logger().info(f"loading or building the re-simulation model (cache {cache})")
            self.model = ResimModel.build(self.scenario, cache_dir=cache, config=resim_config)
        self.publish_sweep = self.publisher(topics.RENDERED)
        self.tracks: dict[int, tuple[ActorTrack, ...]] = {}
        self.waiting: list[FrameRequestRecord] = []
        self.subscribe(topics.PERTURBED_TRACKS, self._on_tracks)
        self.subscribe(topics.FRAME_REQUEST, self._on_request)
        self.get_logger().info("ready")

    def _on_tracks(self, message: Any) -> None:
        record = track_array_from_msg(message)
        self.tracks = {q: t for q, t in self.tracks.items() if q >= record.query_id - 1}  # queries follow each other
        self.tracks[record.query_id] = record.actor_tracks()
        self._answer()

    def _on_request(self, message: Any) -> None:
        request = frame_request_from_msg(message)
        self.trace("request_received", request.query_id, request.frame_index)
        self.waiting.append(request)
        self._answer()

    def _answer(self) -> None:
        ready = [request for request in self.waiting if request.query_id in self.tracks]
        self.waiting = [request for request in self.waiting if request.query_id not in self.tracks]
        for request in ready:
            logged = self.sweeps[int(self.scenario.frame_stamps_ns[request.log_frame])]
            moved = self.tracks[request.query_id]
            points = query_sweep(self.model, self.scenario, logged, request.world_T_ego, moved, self.config.seed)
            out = Sweep(request.sim_stamp_ns, logged.frame_id, points, logged.sensor_pose)
            self.publish_sweep(cloud_msg(out))
            self.trace("rendered", request.query_id, request.frame_index)


def main() -> None:
    run_node(LidarResim)


if __name__ == "__main__":
    main()
