"""The attack journal keeps every complete query line: a torn tail is dropped, a damaged line is set aside and said."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import pytest

from advsim_ros.core.journal import CORRUPT_SUFFIX, Fingerprint, Journal, JournalError, QueryRecord, read_records

FINGERPRINT = Fingerprint({"bag": "log", "seed": 0})


def _record(query_id: int) -> QueryRecord:
    return QueryRecord(query_id, "random", ("7",), (0.5, -0.25), {"status": "ok", "adversarial_loss": float(query_id)})


def _journal(path: Path, count: int) -> None:
    journal = Journal.open(path, FINGERPRINT)
    for query_id in range(count):
        journal.append(_record(query_id))


def test_a_line_cut_short_by_a_kill_is_dropped_and_the_next_append_starts_clean(tmp_path: Path) -> None:
    path = tmp_path / "queries.jsonl"
    _journal(path, 3)
    torn = json.dumps(_record(3).as_json())[:40]
    path.write_bytes(path.read_bytes() + torn.encode())  # no newline: the write was under way
    journal = Journal.open(path, FINGERPRINT)
    assert [record.query_id for record in journal.records] == [0, 1, 2]
    assert not (tmp_path / f"queries.jsonl{CORRUPT_SUFFIX}").exists()
    journal.append(_record(3))
    assert [record.query_id for record in read_records(path)] == [0, 1, 2, 3]


def test_a_damaged_line_in_the_middle_is_kept_aside_and_said_and_the_lines_after_it_stand(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    path = tmp_path / "queries.jsonl"
    _journal(path, 5)
    lines = path.read_bytes().split(b"\n")
    damaged = lines[2][:25] + b"\x00garbage" + lines[2][25:]  # query 1's line, bytes overwritten in place
    path.write_bytes(b"\n".join([*lines[:2], damaged, *lines[3:]]))
    with caplog.at_level(logging.WARNING):
        journal = Journal.open(path, FINGERPRINT)
    assert [record.query_id for record in journal.records] == [0, 2, 3, 4]  # query 1 runs again, nothing else
    aside = tmp_path / f"queries.jsonl{CORRUPT_SUFFIX}"
    assert aside.read_bytes() == damaged + b"\n"  # as it was
    assert "line(s) 3 damaged" in caplog.text
    assert str(aside) in caplog.text
    reopened = Journal.open(path, FINGERPRINT)  # the journal itself is clean now: nothing more to say
    assert [record.query_id for record in reopened.records] == [0, 2, 3, 4]
    assert aside.read_bytes() == damaged + b"\n"


def test_a_journal_of_simba_under_its_old_name_rs_resumes_as_simba(tmp_path: Path) -> None:
    path = tmp_path / "queries.jsonl"
    old = QueryRecord(0, "rs", ("7",), (0.5,), {"status": "ok", "adversarial_loss": 1.0})
    header = {"journal_version": 1, "fingerprint": {"bag": "log", "algorithm": "rs"}}
    path.write_text(json.dumps(header) + "\n" + json.dumps(old.as_json()) + "\n", encoding="utf-8")
    journal = Journal.open(path, Fingerprint({"bag": "log", "algorithm": "simba"}))
    assert [record.algorithm for record in journal.records] == ["simba"]
    assert [record.algorithm for record in read_records(path)] == ["simba"]
    with pytest.raises(JournalError, match="algorithm: 'simba' there, 'bo' now"):
        Journal.open(path, Fingerprint({"bag": "log", "algorithm": "bo"}))


def test_a_journal_that_named_its_bag_by_path_resumes_when_the_bag_is_named_by_content_and_lies_there(
    tmp_path: Path,
) -> None:
    path = tmp_path / "queries.jsonl"
    header = {"journal_version": 1, "fingerprint": {"bag": "/logs/drive", "seed": 0}}
    path.write_text(json.dumps(header) + "\n", encoding="utf-8")
    now = Fingerprint({"bag": "content:abc", "seed": 0}, former={"bag": "/logs/drive"})
    assert Journal.open(path, now).records == []
    with pytest.raises(JournalError, match="bag: '/logs/drive' there, 'content:abc' now"):
        Journal.open(path, Fingerprint({"bag": "content:abc", "seed": 0}, former={"bag": "/elsewhere/drive"}))
    path.unlink()  # a journal of now: the same content anywhere resumes, other content does not
    Journal.open(path, Fingerprint({"bag": "content:abc", "seed": 0}, former={"bag": "/logs/drive"}))
    assert Journal.open(path, Fingerprint({"bag": "content:abc", "seed": 0}, former={"bag": "/cache/x"})).records == []
    with pytest.raises(JournalError, match="bag: 'content:abc' there, 'content:def' now"):
        Journal.open(path, Fingerprint({"bag": "content:def", "seed": 0}, former={"bag": "/logs/drive"}))
