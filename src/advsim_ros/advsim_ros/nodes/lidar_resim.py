"""lidar_resim: answers each FrameRequest with the sweep of the query's perturbed world.

It loads (or builds and caches) the log's re-simulation model once, keeps each query's perturbed
tracks, and renders a requested frame (core.lidar.query) as soon as both the request and the
query's tracks are there, in whatever order they arrive. The sweep keeps the logged sweep's
frame and fields, carries the request's sim stamp and goes to the player (/advsim/rendered_points),
which hands it to the stack when the stack is ready for it: frames are rendered ahead while the
stack plans. In closed loop a request may place the ego away from where it was logged: beyond
render_distance / render_yaw the sweep is rendered from the model at that pose (core.lidar.novel_view)
instead of re-simulated from the logged sweep (both in core.lidar.query.frame_sweep). With reactive
actors a request names the actors that left their tracks and where they are: they are placed there.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from advsim_ros import graph
from advsim_ros.contract import topics
from advsim_ros.contract.codec import Msg
from advsim_ros.contract.protocol import FrameRequestRecord, frame_request_from_msg
from advsim_ros.contract.scenario import cloud_msg
from advsim_ros.contract.tracks import track_array_from_msg
from advsim_ros.core.lidar.config import ResimConfig, ResimNodeConfig
from advsim_ros.core.lidar.query import frame_sweep
from advsim_ros.core.lidar.resim import ResimModel
from advsim_ros.core.memory import release_freed_memory
from advsim_ros.core.reactive import with_overrides
from advsim_ros.core.types import ActorTrack, ScenarioError
from advsim_ros.io.cache import cache_root
from advsim_ros.nodes.scenario_node import ScenarioNode
from advsim_ros.ros.graph_node import run_node


class LidarResim(ScenarioNode):
    def __init__(self) -> None:
        super().__init__(graph.LIDAR_RESIM)
        self.config = self.declare_section("", ResimNodeConfig)
        resim_config = self.declare_section("resim", ResimConfig)
        log, self.clock = self.load_scenario(load_sweeps=True)
        scenario = self.window.crop(log)  # the model and the sweeps of the window's frames only: requests are
        del log  # numbered in the log, the cropped scenario from the window's first frame (self.first_frame)
        self.first_frame = self.window.window_start_frame
        history = range(self.window.history_frames)
        logged = {sweep.stamp_ns for sweep in scenario.sweeps}
        # open loop asks for the history frames only; closed loop may re-simulate any frame of the
        # window, and renders with a calibration taken from the window's sweeps (novel_view): all are kept
        stamps = {int(scenario.frame_stamps_ns[i]) for i in history} if self.config.history_sweeps_only else logged
        missing = [self.first_frame + i for i in history if int(scenario.frame_stamps_ns[i]) not in logged]
        if missing:
            raise ScenarioError(f"scenario {scenario.scenario_id}: no LiDAR sweep at history frames {missing}")
        model: ResimModel | None = None
        if self.config.build_model:
            cache = Path(self.config.cache_dir) if self.config.cache_dir else cache_root() / "resim"
            self.get_logger().info(f"loading or building the re-simulation model (cache {cache})")
            model = ResimModel.build(scenario, cache_dir=cache, config=resim_config)
        # The sweeps not needed are dropped before the model's ray-casting structures are built
        # (a 6 s KITTI window: 60 sweeps, 120 MB, of which open loop replays 10).
        self.scenario = dataclasses.replace(
            scenario, sweeps=tuple(sweep for sweep in scenario.sweeps if sweep.stamp_ns in stamps)
        )
        self.get_logger().info(f"keeping {len(self.scenario.sweeps)} of {len(scenario.sweeps)} sweeps")
        del scenario
        release_freed_memory()  # the dropped sweeps' pages, before the structures are built on top
        self.sweeps = {sweep.stamp_ns: sweep for sweep in self.scenario.sweeps}
        self.model = model.prepare() if model is not None else None
        release_freed_memory()  # the triangles Embree copied
        self.publish_sweep = self.publisher(topics.RENDERED)
        self.tracks: dict[int, tuple[ActorTrack, ...]] = {}
        self.waiting: list[FrameRequestRecord] = []
        self.subscribe(topics.PERTURBED_TRACKS, self._on_tracks)
        self.subscribe(topics.FRAME_REQUEST, self._on_request)
        self.get_logger().info("ready")

    def _on_tracks(self, message: Msg) -> None:
        record = track_array_from_msg(message)
        self.tracks = {q: t for q, t in self.tracks.items() if q >= record.query_id - 1}  # queries follow each other
        self.tracks[record.query_id] = record.actor_tracks()
        self._answer()

    def _on_request(self, message: Msg) -> None:
        request = frame_request_from_msg(message)
        self.trace("request_received", request.query_id, request.frame_index)
        self.waiting.append(request)
        self._answer()

    def _answer(self) -> None:
        ready = [request for request in self.waiting if request.query_id in self.tracks]
        self.waiting = [request for request in self.waiting if request.query_id not in self.tracks]
        for request in ready:
            frame = request.log_frame - self.first_frame  # in the window's own numbering
            moved = self.tracks[request.query_id]
            if request.reacted_actors:  # reactive actors away from their tracks: one state each, at this frame
                stamp = int(self.scenario.frame_stamps_ns[frame])
                reacted = (track.shifted(stamp - request.sim_stamp_ns) for track in request.reacted_actors)
                moved = with_overrides(moved, tuple(track.to_actor_track() for track in reacted))
            out = frame_sweep(
                self.model, self.scenario, self.sweeps, frame, request.sim_stamp_ns, request.world_T_ego,
                moved, self.config,
            )  # fmt: skip
            self.publish_sweep(cloud_msg(out))
            self.trace("rendered", request.query_id, request.frame_index)


def main() -> None:
    run_node(LidarResim)


if __name__ == "__main__":
    main()
