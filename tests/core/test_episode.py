"""The episode clock gives every query its own segment of a monotonic sim clock."""

import itertools

import pytest

from advsim_ros.core.episode import EpisodeClock
from advsim_ros.core.types import ScenarioError

SECOND = 1_000_000_000


def test_segments_follow_each_other_without_overlap() -> None:
    clock = EpisodeClock(window_start_ns=50 * SECOND, window_duration_ns=6 * SECOND, gap_ns=SECOND)
    segments = [clock.segment(query) for query in range(5)]
    assert segments[0] == (50 * SECOND, 57 * SECOND)
    for (_, end), (start, _) in itertools.pairwise(segments):
        assert start == end


def test_sim_stamp_maps_back_to_its_query_and_log_time() -> None:
    clock = EpisodeClock(window_start_ns=10 * SECOND, window_duration_ns=6 * SECOND, gap_ns=SECOND // 2)
    log_time = 10 * SECOND + 900_000_000
    for query in (0, 1, 7, 75):
        sim = clock.to_sim(query, log_time)
        located = clock.locate(sim)
        assert (located.query_id, located.log_time_ns) == (query, log_time)
        assert located.offset_ns == 900_000_000


def test_sim_time_of_later_queries_is_always_later() -> None:
    clock = EpisodeClock(window_start_ns=0, window_duration_ns=6 * SECOND)
    last_frame_of_query_3 = clock.to_sim(3, 6 * SECOND - 1)
    first_frame_of_query_4 = clock.to_sim(4, 0)
    assert first_frame_of_query_4 > last_frame_of_query_3


def test_log_time_outside_the_window_is_rejected() -> None:
    clock = EpisodeClock(window_start_ns=SECOND, window_duration_ns=6 * SECOND, gap_ns=0)
    with pytest.raises(ScenarioError, match="outside the window"):
        clock.to_sim(0, 7 * SECOND)
    with pytest.raises(ScenarioError, match="precedes"):
        clock.locate(0)
