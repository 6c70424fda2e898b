"""The episode protocol's lock-step replay of one query, as the scenario player runs it.

The player asks lidar_resim for the sweeps of the next frames ahead (FrameRequest; the answers come back
on /advsim/rendered_points), so re-simulation overlaps the stack's planning. For every history frame, in
order: /clock, the ego pose (/tf, /ego/odom) and the frame's sweep on the LiDAR topic; then, when
configured, wait until the stack's plan for it came back before the next frame. No frame is skipped: the
replay runs as fast as its slowest participant. A stack that is gone (its plan publisher vanished or was
replaced) or silent past the timeout ends the query early. Everything the stack was sent and answered is
digested in log time, so runs and re-runs of the same query can be compared.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field

from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.topic_endpoint_info import TopicEndpointInfo

from advsim_ros.contract import codec, names, topics
from advsim_ros.contract.codec import Msg
from advsim_ros.contract.digests import InputDigest, PlanDigest
from advsim_ros.contract.enums import Outcome, Phase
from advsim_ros.contract.plan import plan_from_path
from advsim_ros.contract.protocol import EpisodeRecord, FrameRequestRecord
from advsim_ros.contract.tracks import TrackRecord
from advsim_ros.core.closed_loop import VehicleState
from advsim_ros.core.episode import EpisodeClock
from advsim_ros.core.types import ActorTrack, FloatArray, ScenarioError
from advsim_ros.ros.closed_loop import LOOPS, ClosedLoopSetup, LoopCounts, LoopFrame, close_loop
from advsim_ros.ros.identity import ForeignEndpoint, Membership

POLL = 0.2  # how often a wait re-checks that the stack is still there [s]
KEPT = 50  # messages remembered per stamped stream
RELAY_WAIT = 5.0  # longest wait for stack_adapter to pass a frame's inputs on to a timer-driven stack [s]


class StampedArrivals:
    """CDR messages of one topic by header stamp, with a wait that wakes on arrival (no busy waiting)."""

    def __init__(self) -> None:
        self._messages: dict[int, bytes] = {}
        self._condition = threading.Condition()

    def add(self, raw: bytes) -> None:
        with self._condition:
            self._messages[codec.header_stamp_ns(raw)] = raw
            while len(self._messages) > KEPT:
                del self._messages[min(self._messages)]
            self._condition.notify_all()

    def take(self, stamp_ns: int) -> bytes | None:
        with self._condition:
            return self._messages.pop(stamp_ns, None)

    def wait(self, stamp_ns: int, timeout: float, give_up: Callable[[], bool]) -> bytes | None:
        """The message stamped stamp_ns once it arrived, or None after the timeout or when give_up() says so."""
        deadline = time.monotonic() + timeout
        with self._condition:
            while stamp_ns not in self._messages:
                remaining = deadline - time.monotonic()
                if remaining <= 0 or give_up():
                    return None
                self._condition.wait(min(remaining, POLL))
            return self._messages.pop(stamp_ns)


@dataclass(frozen=True)
class StackNames:
    """The names under which the stack's own endpoints of the contract topics are found.

    The contract's names, unless the stack keeps names of its own and stack_adapter bridges them
    (``advsim attack --remap CONTRACT:=STACK``): then the stack is looked for under its names.
    """

    graph_nodes: frozenset[str]  # the attack graph's node names: every other node on the domain is the stack's
    renamed: Mapping[str, str] = field(default_factory=dict)  # contract topic -> the stack's topic

    @staticmethod
    def from_pairs(graph_nodes: frozenset[str], pairs: Iterable[str]) -> StackNames:
        """From "CONTRACT:=STACK" strings (the player's stack_topics parameter)."""
        renamed = {}
        for pair in pairs:
            contract, separator, stack = pair.partition(":=")
            if not separator or not contract or not stack:
                raise ScenarioError(f"/scenario_player stack_topics: expected CONTRACT:=STACK, got {pair!r}")
            renamed[contract] = stack
        return StackNames(graph_nodes, renamed)

    def __call__(self, topic: topics.TopicSpec) -> str:
        return self.renamed.get(topic.name, topic.name)


def stack_endpoints(node: Node, topic: str, publishers: bool, names: StackNames) -> list[TopicEndpointInfo]:
    """Endpoints of the stack (every node not of the attack graph) on a topic."""
    infos = node.get_publishers_info_by_topic(topic) if publishers else node.get_subscriptions_info_by_topic(topic)
    return [info for info in infos if info.node_name not in names.graph_nodes]


def stack_publishes(node: Node, topic: topics.TopicSpec, names: StackNames) -> bool:
    return bool(stack_endpoints(node, names(topic), True, names))


# Topics the player and the stack exchange: every endpoint of them must be matched before a query.
TO_STACK = (topics.LIDAR, topics.ODOM, topics.TF, topics.CLOCK)
FROM_STACK = (topics.PLAN,)
# Every topic the stack reads or answers on: only the attack's processes may publish on them.
STACK_TOPICS = (
    *TO_STACK, topics.TF_STATIC, topics.SCENARIO_INFO, topics.MAP, topics.PLAN, topics.DETECTIONS, topics.PREDICTIONS,
)  # fmt: skip


def _stack_gids(node: Node, names: StackNames) -> frozenset[bytes]:
    lidar = stack_endpoints(node, names(topics.LIDAR), False, names)
    endpoints = lidar + stack_endpoints(node, names(topics.PLAN), True, names)
    return frozenset(bytes(info.endpoint_gid) for info in endpoints)


def connected(node: Node, latched: Iterable[Publisher], names: StackNames) -> bool:
    """The stack listens to the LiDAR and publishes plans, lidar_resim answers requests, and every
    endpoint the player shares with them (latched topics included) is matched on the player's side."""
    stack = bool(stack_endpoints(node, names(topics.LIDAR), False, names)) and stack_publishes(node, topics.PLAN, names)
    resim = node.count_subscribers(topics.FRAME_REQUEST.name) >= 1 and node.count_publishers(topics.RENDERED.name) >= 1
    to_stack = {topic.name for topic in TO_STACK}
    from_stack = {topic.name for topic in FROM_STACK}
    writers = [*latched, *(p for p in node.publishers if p.topic_name in to_stack)]
    readers = [s for s in node.subscriptions if s.topic_name in from_stack]
    matched = all(p.get_subscription_count() >= node.count_subscribers(p.topic_name) for p in writers) and all(
        s.get_publisher_count() >= node.count_publishers(s.topic_name) for s in readers
    )
    return stack and resim and matched


class Readiness:
    """Waits before a query until the stack and lidar_resim are connected (``connected``).

    The player sees matches on its own side only; the stack's readers match the player's writers
    when the stack's process has discovered them, a moment later, and a volatile reader that
    matches after a message was written never gets it (its first sweep or odometry would be
    lost). So after the stack's endpoints change (its start, a restart) the connection must hold
    for ``settle`` seconds before the first frame is sent.
    """

    def __init__(self, node: Node, latched: Iterable[Publisher], settle: float, names: StackNames) -> None:
        self._node = node
        self._latched = list(latched)
        self._settle = settle
        self._names = names
        self._settled: frozenset[bytes] = frozenset()

    def wait(self, timeout: float, stop: threading.Event) -> bool:
        """True once connected and settled; False after ``timeout`` seconds or on stop."""
        deadline = time.monotonic() + timeout
        since: tuple[float, frozenset[bytes]] | None = None  # when the current set of endpoints connected
        while True:
            now = time.monotonic()
            gids = _stack_gids(self._node, self._names)
            if not connected(self._node, self._latched, self._names):
                since = None
            elif gids == self._settled:
                return True
            elif since is None or since[1] != gids:
                since = (now, gids)
            elif now - since[0] >= self._settle:
                self._settled = gids
                return True
            if now >= deadline or stop.wait(min(POLL, self._settle / 4)):
                return False


class StackLiveness:
    """Whether the stack the query talks to is still the one it began with, and only it.

    Lost: the stack's plan publisher changed since the query began (exit, crash, restart). A
    process that crashed stays in the DDS graph until its lease expires, but a restarted one
    brings a new publisher: no publisher, or one that was not there when the query began, counts
    (an old one expiring does not), and is remembered for the rest of the query.

    Foreign: a process the attack did not start publishes on one of the stack's topics, inputs or
    outputs, under the contract's names or the stack's own (ros.identity); its messages could
    reach the stack or the score, so the query cannot be trusted. Remembered for the query too.
    """

    def __init__(self, node: Node, names: StackNames, membership: Membership | None = None) -> None:
        self._node = node
        self._names = names
        self._membership = membership
        self._watched = [name for topic in STACK_TOPICS for name in (topic.name, names(topic))]
        self._at_start: frozenset[bytes] = frozenset()
        self.lost = False
        self.foreign: dict[ForeignEndpoint, None] = {}  # in the order they were seen

    def _publishers(self) -> frozenset[bytes]:
        endpoints = stack_endpoints(self._node, self._names(topics.PLAN), True, self._names)
        return frozenset(bytes(info.endpoint_gid) for info in endpoints)

    def begin(self) -> None:
        self._at_start = self._publishers()
        self.lost = False
        self.foreign = {}
        self._check_foreign()

    def _check_foreign(self) -> None:
        if self._membership is not None:
            self.foreign.update(dict.fromkeys(self._membership.foreign_publishers(self._node, self._watched)))

    def check(self) -> bool:
        """True once the stack was lost or a foreign publisher was seen (the query can end)."""
        current = self._publishers()
        if not current or current - self._at_start:
            self.lost = True
        self._check_foreign()
        return self.lost or bool(self.foreign)

    def outcome(self, complete: bool) -> tuple[Outcome, str]:
        """How the query ended, with what went wrong; ``complete``: every frame and awaited plan went through."""
        if self.foreign:
            return Outcome.FOREIGN_PUBLISHER, "; ".join(endpoint.describe() for endpoint in self.foreign)
        if self.lost:
            return Outcome.STACK_LOST, ""
        return (Outcome.COMPLETE, "") if complete else (Outcome.PLANS_MISSING, "")


@dataclass(frozen=True, eq=False)
class HistoryFrame:
    """One frame of the window's history as the player replays it."""

    log_frame: int  # index in the log
    log_stamp_ns: int
    odometry: bytes  # CDR of nav_msgs/Odometry at the log stamp
    world_T_ego: FloatArray  # (4, 4)


@dataclass(frozen=True)
class PlayerConfig:
    """/scenario_player parameters (params/scenario_player.yaml)."""

    plan_timeout: float = 10.0  # longest wait for the stack's plan of one frame [s, wall clock]
    sweep_timeout: float = 30.0  # longest wait for the re-simulated sweep of one frame [s, wall clock]
    ready_timeout: float = 600.0  # longest wait, per query, for the stack and lidar_resim to be connected [s]
    wait_for_every_plan: bool = True  # wait for a plan at every frame (stacks planning per sweep), else only the last
    prefetch_frames: int = 3  # frames lidar_resim renders ahead of the one the stack is planning from
    settle_time: float = 1.0  # how long a new connection to the stack must hold before a query starts [s]
    stack_topics: tuple[str, ...] = ()  # CONTRACT:=STACK: topics the stack keeps its own names for (stack_adapter)
    loop: str = "open"  # open: the decision plan is scored (the paper); closed: the ego drives the plans (closed_loop)
    reactive_actors: bool = False  # closed loop: moving vehicles react to the ego (IDM along paths; core.reactive)
    clock_step: float = 0.0  # > 0: a stack planning on its own timer; /clock advances in these steps [s]
    real_time_factor: float = 1.0  # clock_step > 0: simulated seconds per wall-clock second while stepping
    await_relay: bool = False  # clock_step > 0: /clock reaches a frame once stack_adapter passed its inputs on

    def __post_init__(self) -> None:
        for name in ("plan_timeout", "sweep_timeout", "ready_timeout", "settle_time", "real_time_factor"):
            if not getattr(self, name) > 0.0:
                raise ScenarioError(f"/scenario_player {name}: must be positive, got {getattr(self, name)}")
        if self.clock_step < 0.0:
            raise ScenarioError(f"/scenario_player clock_step: must be >= 0, got {self.clock_step}")
        if self.loop not in LOOPS:
            raise ScenarioError(f"/scenario_player loop: one of {', '.join(LOOPS)}, got {self.loop!r}")
        if self.reactive_actors and self.loop != "closed":
            raise ScenarioError("/scenario_player reactive_actors: only with loop closed (open loop drives nothing)")
        if self.prefetch_frames < 1:
            raise ScenarioError(f"/scenario_player prefetch_frames: must be >= 1, got {self.prefetch_frames}")
        StackNames.from_pairs(frozenset(), self.stack_topics)  # refused here, with the pair named, when malformed


@dataclass
class Outputs:
    """Where the replay sends things (publish functions of the player node)."""

    clock: Callable[[Msg], None]
    tf: Callable[[Msg], None]
    odometry: Callable[[Msg | bytes], None]
    lidar: Callable[[bytes], None]
    frame_request: Callable[[FrameRequestRecord], None]
    episode: Callable[[EpisodeRecord, Msg | None, Msg | None], None]  # record, detections, predictions (or None)
    tf_message: Callable[[int, FloatArray], Msg]  # sim stamp, world_T_ego -> tf2_msgs/TFMessage
    trace: Callable[[str, int, int], None]  # event, query, frame (ros.trace)
    odometry_of: Callable[[int, FloatArray, VehicleState], bytes] | None = None  # closed loop: the simulated ego's


@dataclass
class Inputs:
    """What the replay waits for (filled by the player's subscriptions)."""

    sweeps: StampedArrivals  # rendered by lidar_resim, to be sent
    plans: StampedArrivals
    detections: StampedArrivals
    predictions: StampedArrivals
    relayed: StampedArrivals = field(default_factory=StampedArrivals)  # stack_adapter's acknowledgements


def replay_query(
    query_id: int,
    frames: Iterable[HistoryFrame],
    clock: EpisodeClock,
    config: PlayerConfig,
    outputs: Outputs,
    inputs: Inputs,
    liveness: StackLiveness,
    stack_outputs: tuple[bool, bool],
    stop: threading.Event,
    closed_loop: ClosedLoopSetup | None = None,
    moved: Sequence[ActorTrack] = (),
) -> EpisodeRecord:
    """Replay one query's history in lock-step; returns (and publishes) its Episode DONE.

    With ``closed_loop`` (and a decision plan), the ego then drives the stack's plans for the
    horizon (ros.closed_loop): the Episode DONE also carries what it drove, and with reactive
    actors the drives of those that reacted (``moved``: the query's perturbed tracks, log time).

    ``stack_outputs``: whether the stack publishes detections and predictions; then those of
    the decision frame are awaited too, so whether a query has them never depends on timing.
    """
    history = list(frames)
    count = len(history)
    segment = clock.segment(query_id)
    outputs.trace("query_start", query_id, -1)
    outputs.episode(EpisodeRecord(query_id, Phase.START, 0, count, segment), None, None)
    inputs_digest, plans_digest = InputDigest(), PlanDigest()
    delivered = received = awaited = 0
    plans_flowing = True
    decision_plan: Msg | None = None  # nav_msgs/Path
    answers: dict[str, Msg | None] = {"detections": None, "predictions": None}
    liveness.begin()

    def watch_stack() -> bool:  # while waiting for a sweep: note whether the stack is gone, give up only on stop
        liveness.check()
        return stop.is_set()

    def stack_gone() -> bool:
        return liveness.check() or stop.is_set()

    def request(index: int) -> None:
        if index < count:
            frame = history[index]
            sim = clock.to_sim(query_id, frame.log_stamp_ns)
            outputs.frame_request(FrameRequestRecord(query_id, index, frame.log_frame, sim, frame.world_T_ego))

    for index in range(config.prefetch_frames):
        request(index)
    for index, frame in enumerate(history):
        sim = clock.to_sim(query_id, frame.log_stamp_ns)
        decision = index == count - 1
        sweep = inputs.sweeps.wait(sim, config.sweep_timeout, watch_stack)
        request(index + config.prefetch_frames)
        stepping = config.clock_step > 0.0
        if not stepping:
            outputs.clock(codec.clock_cdr(sim))
        outputs.tf(outputs.tf_message(sim, frame.world_T_ego))
        outputs.odometry(codec.restamp(frame.odometry, sim))
        inputs_digest.frame(frame.log_stamp_ns, frame.odometry, frame.world_T_ego)
        if sweep is not None:
            outputs.lidar(sweep)
            outputs.trace("sweep_sent", query_id, index)
            delivered += 1
            inputs_digest.sweep(sweep)
        if stepping:  # a timer fires when /clock reaches it: the frame's inputs must be there first
            if config.await_relay:
                inputs.relayed.wait(sim, RELAY_WAIT, stack_gone)
            outputs.clock(codec.clock_cdr(sim))
        if stepping and not decision:  # a timer-driven stack: time passes between sweeps as on the road
            until = clock.to_sim(query_id, history[index + 1].log_stamp_ns)
            _step_clock(sim, until, config, outputs, stop)
        if decision or (config.wait_for_every_plan and plans_flowing and not stepping):
            awaited += 1
            if stepping:
                plan = _stepped_wait(inputs.plans, sim, config, outputs, stack_gone)
            else:
                plan = inputs.plans.wait(sim, config.plan_timeout, stack_gone)
            liveness.check()  # whoever published what just arrived is still in the graph: is it the stack?
            if plan is None:
                plans_flowing = False  # do not wait at every frame for a stack that has stopped answering
            else:
                outputs.trace("plan_seen", query_id, index)
                received += 1
                decoded = codec.decode(plan, names.PATH)
                plans_digest.plan(decoded, sim - frame.log_stamp_ns)
                if decision:
                    decision_plan = decoded
                    for (kind, arrivals), expected in zip(
                        (("detections", inputs.detections), ("predictions", inputs.predictions)),
                        stack_outputs,
                        strict=True,
                    ):
                        found = arrivals.wait(sim, config.plan_timeout, stack_gone) if expected else None
                        answers[kind] = None if found is None else codec.decode(found, names.ACTOR_TRACK_ARRAY)
        phase = Phase.DECISION if decision else Phase.REPLAY
        outputs.episode(EpisodeRecord(query_id, phase, index, count, segment, delivered, received), None, None)
    executed: TrackRecord | None = None
    reacted: tuple[TrackRecord, ...] = ()
    if closed_loop is not None and decision_plan is not None and not liveness.check() and not stop.is_set():
        executed, reacted, loop_counts = _drive(
            query_id, count, closed_loop, decision_plan, history[-1], clock, config, outputs, inputs, stack_gone,
            (inputs_digest, plans_digest), stop, moved,
        )  # fmt: skip
        delivered, received, awaited = (
            delivered + loop_counts.delivered,
            received + loop_counts.received,
            awaited + loop_counts.awaited,
        )
        count += len(closed_loop.frames)
    liveness.check()
    outcome, detail = liveness.outcome(received >= awaited and delivered >= count)
    done = EpisodeRecord(
        query_id, Phase.DONE, count - 1, count, segment, delivered, received, outcome,
        inputs_digest.hexdigest(), plans_digest.hexdigest(), decision_plan, executed=executed, reacted_actors=reacted,
        outcome_detail=detail,
    )  # fmt: skip
    outputs.episode(done, answers["detections"], answers["predictions"])
    outputs.trace("done_sent", query_id, -1)
    return done


def _step_clock(start_ns: int, until_ns: int, config: PlayerConfig, outputs: Outputs, stop: threading.Event) -> None:
    """Publish /clock from start + one step up to (not including) until, one step per step/real_time_factor s."""
    step_ns = round(config.clock_step * 1e9)
    pace = config.clock_step / config.real_time_factor
    now = start_ns + step_ns
    while now < until_ns and not stop.wait(pace):
        outputs.clock(codec.clock_cdr(now))
        now += step_ns


def _stepped_wait(
    plans: StampedArrivals, sweep_ns: int, config: PlayerConfig, outputs: Outputs, give_up: Callable[[], bool]
) -> bytes | None:
    """The plan for the sweep stamped sweep_ns, stepping /clock on until it comes (stack_adapter answers
    a timer-driven stack's sweep once the decision delay has passed on the sim clock) or plan_timeout passes."""
    step_ns = round(config.clock_step * 1e9)
    pace = config.clock_step / config.real_time_factor
    deadline = time.monotonic() + config.plan_timeout
    now = sweep_ns
    while time.monotonic() < deadline:
        plan = plans.wait(sweep_ns, pace, give_up)
        if plan is not None:
            return plan
        if give_up():
            return None
        now += step_ns
        outputs.clock(codec.clock_cdr(now))
    return None


def _drive(
    query_id: int,
    history_count: int,
    setup: ClosedLoopSetup,
    decision_plan: Msg,
    decision: HistoryFrame,
    clock: EpisodeClock,
    config: PlayerConfig,
    outputs: Outputs,
    inputs: Inputs,
    stack_gone: Callable[[], bool],
    digests: tuple[InputDigest, PlanDigest],
    stop: threading.Event,
    moved: Sequence[ActorTrack],
) -> tuple[TrackRecord, tuple[TrackRecord, ...], LoopCounts]:
    """The closed loop after the decision: each frame's sweep from the simulated pose (and the reacted actors'),
    the plan back. Returns what the ego drove and the reacted actors' drives (sim time)."""
    inputs_digest, plans_digest = digests
    odometry_of = outputs.odometry_of
    if odometry_of is None:
        raise ScenarioError("closed loop: the player has no odometry builder for the simulated ego")

    def exchange(
        frame_index: int,
        sim: int,
        frame: LoopFrame,
        world_T_ego: FloatArray,
        state: VehicleState,
        off_track: tuple[ActorTrack, ...],
    ) -> tuple[bool, bytes | None]:
        reacted = tuple(TrackRecord.from_actor_track(track).shifted(sim - frame.log_stamp_ns) for track in off_track)
        outputs.frame_request(FrameRequestRecord(query_id, frame_index, frame.log_frame, sim, world_T_ego, reacted))
        sweep = inputs.sweeps.wait(sim, config.sweep_timeout, stop.is_set)
        odometry = odometry_of(sim, world_T_ego, state)
        outputs.clock(codec.clock_cdr(sim))
        outputs.tf(outputs.tf_message(sim, world_T_ego))
        outputs.odometry(odometry)
        inputs_digest.frame(frame.log_stamp_ns, codec.restamp(odometry, frame.log_stamp_ns), world_T_ego)
        if sweep is None:
            return False, None
        outputs.lidar(sweep)
        outputs.trace("sweep_sent", query_id, frame_index)
        inputs_digest.sweep(sweep)
        plan = inputs.plans.wait(sim, config.plan_timeout, stack_gone)
        if plan is not None:
            outputs.trace("plan_seen", query_id, frame_index)
            plans_digest.plan(codec.decode(plan, names.PATH), sim - frame.log_stamp_ns)
        return True, plan

    offset = clock.to_sim(query_id, decision.log_stamp_ns) - decision.log_stamp_ns
    plan = plan_from_path(decision_plan, offset)
    executed, counts, drives = close_loop(query_id, history_count, setup, plan, clock, exchange, moved)
    track = TrackRecord.from_executed(executed, setup.ego_size, setup.controller.wheelbase, offset)
    return track, tuple(TrackRecord.from_actor_track(drive).shifted(offset) for drive in drives), counts
