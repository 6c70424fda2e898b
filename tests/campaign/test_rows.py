"""The typed records of a campaign: results.csv and transfer.csv rows read back as the rows they were written from,
a malformed cell refused naming its column, and summary.json read back as the attack wrote it.

Rows are made as a campaign makes them: an attack's summary from its journaled queries (attack.summary,
attack.controls), its row from that summary (results.attack_row), a failed attack's with failed_row.
"""

from __future__ import annotations

import csv
import io
import math
import typing
from pathlib import Path

import pytest

from advsim_ros.attack.controls import controls, finding
from advsim_ros.attack.summary import attack_summary
from advsim_ros.campaign.config import AttackPlan, CampaignError
from advsim_ros.campaign.results import (
    COLUMNS,
    METRICS,
    TRANSFER_COLUMNS,
    ResultsRow,
    ScoreColumns,
    TransferRow,
    attack_row,
    failed_row,
    identity_of,
    parse_results_row,
    read_results_csv,
    read_transfer_csv,
    to_csv,
)
from advsim_ros.core.atomic import write_json_atomically
from advsim_ros.core.attack_summary import AttackSummary
from advsim_ros.core.errors import UserError
from advsim_ros.core.journal import QueryRecord
from advsim_ros.viz.attack_view import load_summary


def _score(loss: float | None, collided: bool, status: str = "ok") -> dict[str, str | float | None]:
    return {"status": status, "message": "", "adversarial_loss": loss, "collision_3s": float(collided),
            "collision_5s": float(collided), "l2_human_3s": 0.75, "l2_human_5s": 2.5, "lateral_acceleration": 1.25,
            "jerk": 3.5, "detection_ap": None, "prediction_l2_3s": None, "prediction_l2_5s": 1.5,
            "input_digest": "in", "plan_digest": "plan"}  # fmt: skip


def _summary(collided: bool) -> AttackSummary:
    """An attack's summary from its queries: the original twice, the identity control, a search, a re-run."""
    records = [
        QueryRecord(0, "original", (), (), _score(0.5, False)),
        QueryRecord(1, "original", (), (), _score(0.5, False)),
        QueryRecord(2, "identity", ("car_1",), (0.0, 0.0), _score(0.625, False)),
        QueryRecord(3, "bo", ("car_1",), (0.5, -0.25), _score(None, False, "stack_timeout")),
        QueryRecord(4, "bo", ("car_1",), (0.25, 0.5), _score(6.0 if collided else 1.0, collided)),
        QueryRecord(5, "rerun", ("car_1",), (0.25, 0.5), _score(6.0 if collided else 1.0, collided)),
    ]
    analysis = attack_summary(records)
    analysis["controls"] = controls(records, 0)
    best = analysis["best"]
    analysis["finding"] = finding(analysis, analysis["controls"], best["reproduction"] if best else None)
    summary: AttackSummary = {
        "scenario": {"bag": "/data/kitti_0000_bag", "scenario_id": "kitti_0000", "window_start_frame": 20,
                     "history_frames": 10, "future_frames": 50, "bag_params": None},
        "stack": {"name": "modular", "command": ["advsim-stack", "modular"]},
        "search": {"algorithm": "bo", "queries": 2, "seed": 3, "reruns": 1, "rerun_top": 1, "lanes": 1},
        **analysis,
        "verdict": {"ok": True, "reason": "", "dominant_status": "stack_timeout"},
        "stack_crashes": [{"query_id": 3, "exit_code": -9}],
        "wall_time_s": 61.5,
        "resources": {"processes": {"stack": {"peak_rss_mb": 120.0, "cpu_s": 4.0}}, "graph_peak_rss_mb": 120.0,
                      "graph_cpu_s": 4.0, "orchestrator_peak_rss_mb": 80.0},
        "ros_domain_id": 17,
        "outputs": {"journal": "/out/queries.jsonl", "bev": "/out/bev.png"},
    }  # fmt: skip
    summary["perturbed_actors"] = ["car_1"]
    return summary


def _plan(key: str, stack: str, seed: int) -> AttackPlan:
    return AttackPlan(key=key, scenario="kitti_0000", bag="/data/kitti_0000_bag", window_start=20, stack=stack,
                      stack_entry=stack, algorithm="bo", budget=2, actors=1, objective="M0", seed=seed, reruns=1,
                      plan_timeout=5.0)  # fmt: skip


def _rows() -> list[ResultsRow]:
    cost = {"wall_s": 61.5, "cpu_s": 130.25, "peak_rss_mb": 200.0}
    return [
        attack_row(identity_of(_plan("a-collides", "modular", 0)), _summary(True), cost, "attacks/a-collides"),
        attack_row(identity_of(_plan("a-safe", "learned", 1)), _summary(False), cost, "attacks/a-safe"),
        failed_row(identity_of(_plan("a-failed", "modular", 2)), "the stack died\ntraceback", "attacks/a-failed"),
    ]


def _same(got: object, expected: object) -> bool:
    if isinstance(expected, float) and math.isnan(expected):
        return isinstance(got, float) and math.isnan(got)
    return type(got) is type(expected) and got == expected


def _typed(row: typing.Mapping[str, object], record: type) -> None:
    """Every value of the row has the type its TypedDict declares for it."""
    for column, hint in typing.get_type_hints(record).items():
        value = row[column]
        assert isinstance(value, hint), (column, value, hint)
        assert hint is not int or not isinstance(value, bool), (column, value)  # a bool is an int, but not here


def test_the_row_types_name_exactly_the_csv_columns() -> None:
    assert set(typing.get_type_hints(ResultsRow)) == set(COLUMNS)
    assert set(typing.get_type_hints(ScoreColumns)) == {
        f"{p}_{m}" for p in ("original", "adversarial") for m in METRICS
    }
    assert set(typing.get_type_hints(TransferRow)) == set(TRANSFER_COLUMNS)


def test_results_csv_rows_read_back_as_the_rows_written_each_value_of_its_type() -> None:
    rows = _rows()
    assert rows[0]["adversarial_collision_5s"] == 1.0
    assert rows[0]["original_flaky"] is False
    assert rows[2]["status"] == "failed"
    assert rows[2]["sim_dominated"] == ""
    read = read_results_csv(to_csv(rows, COLUMNS))
    assert len(read) == len(rows)
    for got, row in zip(read, rows, strict=True):
        _typed(got, ResultsRow)
        assert [column for column in COLUMNS if not _same(got[column], row[column])] == []
    assert to_csv(read, COLUMNS) == to_csv(rows, COLUMNS)  # and write the same bytes again


def test_transfer_csv_rows_read_back_with_not_scored_as_none() -> None:
    rows: list[TransferRow] = [
        {"attack": "a-collides", "source_stack": "modular", "target_stack": "learned", "collision_5s": 1.0,
         "adversarial_loss": 4.5, "status": "ok", "out_dir": "transfer/a-collides--on--learned"},
        {"attack": "a-safe", "source_stack": "learned", "target_stack": "modular", "collision_5s": None,
         "adversarial_loss": None, "status": "stack_timeout", "out_dir": "transfer/a-safe--on--modular"},
    ]  # fmt: skip
    read = read_transfer_csv(to_csv(rows, TRANSFER_COLUMNS))
    assert read == rows
    for got in read:
        _typed(got, TransferRow)


@pytest.mark.parametrize(
    ("column", "cell", "expected"),
    [("budget", "fifty", "an integer"), ("flaky", "maybe", "True or False"),
     ("adversarial_collision_5s", "yes", "a number"), ("sim_dominated", "1", "True, False or empty")],
)  # fmt: skip
def test_a_malformed_cell_is_refused_naming_its_column_and_line(column: str, cell: str, expected: str) -> None:
    text = to_csv(_rows(), COLUMNS)
    lines = text.splitlines()
    cells = lines[2].split(",")
    cells[COLUMNS.index(column)] = cell
    lines[2] = ",".join(cells)
    with pytest.raises(CampaignError, match=rf"results.csv line 3: {column} is '{cell}', expected {expected}"):
        read_results_csv("\n".join(lines) + "\n")


def test_a_row_without_a_column_is_refused_naming_it() -> None:
    cells = next(csv.DictReader(io.StringIO(to_csv(_rows(), COLUMNS))))
    del cells["out_dir"]
    with pytest.raises(UserError, match=r"results\.csv: no out_dir column"):  # the user-error family: one line
        parse_results_row(cells)


def test_summary_json_reads_back_as_the_attack_wrote_it(tmp_path: Path) -> None:
    summary = _summary(True)
    assert summary["finding"] is not None
    assert summary["finding"]["reproduced"] is True
    write_json_atomically(tmp_path / "summary.json", summary)
    read = load_summary(tmp_path / "summary.json")
    assert read == summary
    assert read["best"] is not None
    assert read["best"]["reproduction"] is not None
    assert read["verdict"]["ok"] is True
    assert read["stack_crashes"][0]["exit_code"] == -9
