"""The episode protocol's clock: one segment of a monotonic simulated clock per query.

Every node of the attack graph derives the same mapping between simulated time and the log's
time from the same few parameters, so none of them depends on the order in which messages of
different topics arrive: a sweep stamped at sim time t belongs to query `locate(t).query_id`,
log time `locate(t).log_time_ns`. Query q's segment starts `q * segment_ns` after the window's
first log stamp and is long enough to hold the window's history and the plan's horizon, so
plans of one query never overlap the next query's stamps and simulated time never goes back.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from advsim_ros.core.curation import crop_frames
from advsim_ros.core.types import Scenario, ScenarioError


@dataclass(frozen=True)
class SimTime:
    """Where a simulated stamp falls: which query, and which log time it replays."""

    query_id: int
    offset_ns: int  # time since the start of the query's segment [ns]
    log_time_ns: int  # the log time this stamp replays [ns]


@dataclass(frozen=True)
class EpisodeClock:
    """Simulated-time segments for the queries of one attack on one scenario window."""

    window_start_ns: int  # log stamp of the window's first frame [ns]; also query 0's segment start
    window_duration_ns: int  # from the first history frame to the end of the plan horizon [ns]
    gap_ns: int = 1_000_000_000  # idle sim time between two queries' windows [ns]

    def __post_init__(self) -> None:
        if self.window_duration_ns <= 0:
            raise ScenarioError(f"EpisodeClock: window_duration_ns must be positive, got {self.window_duration_ns}")
        if self.gap_ns < 0:
            raise ScenarioError(f"EpisodeClock: gap_ns must be non-negative, got {self.gap_ns}")

    @property
    def segment_ns(self) -> int:
        """Length of one query's segment [ns]."""
        return self.window_duration_ns + self.gap_ns

    def segment(self, query_id: int) -> tuple[int, int]:
        """(start, end) sim stamps of the query's segment [ns], end exclusive."""
        if query_id < 0:
            raise ScenarioError(f"EpisodeClock: query ids are non-negative, got {query_id}")
        start = self.window_start_ns + query_id * self.segment_ns
        return start, start + self.segment_ns

    def to_sim(self, query_id: int, log_time_ns: int) -> int:
        """The sim stamp at which query `query_id` replays log time `log_time_ns`."""
        offset = log_time_ns - self.window_start_ns
        if not 0 <= offset < self.segment_ns:
            raise ScenarioError(f"EpisodeClock: log time {log_time_ns} ns is outside the window")
        return self.segment(query_id)[0] + offset

    def locate(self, sim_time_ns: int) -> SimTime:
        """Which query and log time a sim stamp belongs to."""
        elapsed = sim_time_ns - self.window_start_ns
        if elapsed < 0:
            raise ScenarioError(f"EpisodeClock: sim time {sim_time_ns} ns precedes the first segment")
        query_id, offset = divmod(elapsed, self.segment_ns)
        return SimTime(query_id=int(query_id), offset_ns=int(offset), log_time_ns=self.window_start_ns + int(offset))


@dataclass(frozen=True)
class WindowConfig:
    """Which part of which log one attack replays; every node of the graph gets the same values."""

    scenario_bag: str = ""  # path of the scenario bag (rosbag2 folder)
    window_start_frame: int = 0  # index of the window's first frame in the log
    history_frames: int = 10  # frames of LiDAR the stack sees before it plans (1 s at 10 Hz)
    future_frames: int = 50  # frames the plan is scored over (5 s at 10 Hz)
    frame_period: float = 0.1  # spacing of the log's frames [s]
    gap: float = 1.0  # idle sim time between two queries' windows [s]

    def __post_init__(self) -> None:
        if self.window_start_frame < 0:
            raise ScenarioError(f"window_start_frame: must be >= 0, got {self.window_start_frame}")
        if self.history_frames < 1 or self.future_frames < 1:
            raise ScenarioError("history_frames and future_frames: must be >= 1")
        if not 0.0 < self.frame_period <= 1.0:
            raise ScenarioError(f"frame_period: must be in (0, 1] s, got {self.frame_period}")
        if self.gap < 0.0:
            raise ScenarioError(f"gap: must be >= 0 s, got {self.gap}")

    @property
    def num_frames(self) -> int:
        """Frames of the whole window: history and the plan's horizon."""
        return self.history_frames + self.future_frames

    @property
    def decision_index(self) -> int:
        """Index within the window of the last sweep the stack sees: it plans from there."""
        return self.history_frames - 1

    def frame_indices(self, num_log_frames: int) -> range:
        """Log frame indices of the window; ScenarioError if the log is too short."""
        end = self.window_start_frame + self.num_frames
        if end > num_log_frames:
            raise ScenarioError(
                f"window frames {self.window_start_frame}..{end - 1} need {end} frames, the log has {num_log_frames}"
            )
        return range(self.window_start_frame, end)

    def crop(self, scenario: Scenario) -> Scenario:
        """The window's frames of a log, renumbered from 0: what an attack on the window's own bag reads.

        The re-simulation model is built from these (its sweeps, its tracks), so an attack on a window
        of a whole log scores as an attack on that window cut out into a bag of its own, and costs as much.
        """
        frames = self.frame_indices(scenario.num_frames)
        return crop_frames(scenario, frames.start, frames.stop - 1)

    def clock(self, frame_stamps_ns: Sequence[int]) -> EpisodeClock:
        """The episode clock of this window over a log with these frame stamps [ns]."""
        frames = self.frame_indices(len(frame_stamps_ns))
        start = int(frame_stamps_ns[frames.start])
        duration = int(frame_stamps_ns[frames.stop - 1]) - start + round(self.frame_period * 1e9)
        return EpisodeClock(start, duration, round(self.gap * 1e9))
