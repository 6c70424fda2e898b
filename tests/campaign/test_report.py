"""campaign.report: the paper's tables from results rows, and the files it writes (atomically, self-contained).

Rows are made the way a campaign makes them: results.attack_row from an attack's summary (scores with
the QueryScore field names, a query history) and what the attack cost; failed ones with failed_row.
"""

from __future__ import annotations

import csv
import math
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from PIL import Image

from advsim_ros.campaign import report as report_module
from advsim_ros.campaign.report import bootstrap_mean, median_curves, table1, write_report
from advsim_ros.campaign.results import COLUMNS, METRICS, attack_row, best_curve, failed_row


def _score(rng: np.random.Generator, collided: bool, perception: bool) -> dict[str, Any]:
    l2_3 = float(rng.uniform(0.3, 2.5))
    return {
        "status": "ok",
        "adversarial_loss": float(rng.uniform(-3.0, 2.0)) + (5.0 if collided else 0.0),
        "collision_3s": 1.0 if collided and rng.random() < 0.7 else 0.0,
        "collision_5s": 1.0 if collided else 0.0,
        "l2_human_3s": l2_3,
        "l2_human_5s": l2_3 * float(rng.uniform(1.5, 2.5)),
        "lateral_acceleration": float(rng.uniform(0.2, 3.0)),
        "jerk": float(rng.uniform(0.5, 8.0)),
        "detection_ap": float(rng.uniform(0.6, 0.95)) if perception else None,
        "prediction_l2_3s": float(rng.uniform(0.5, 2.0)) if perception else None,
        "prediction_l2_5s": float(rng.uniform(1.0, 4.0)) if perception else None,
    }


def _summary(rng: np.random.Generator, collided: bool, queries: int, perception: bool = True) -> dict[str, Any]:
    history = [{"query_id": 0, "algorithm": "original", "score": _score(rng, False, perception)}]
    history += [{"query_id": i, "algorithm": "bo", "score": _score(rng, False, perception)} for i in range(1, queries)]
    adversarial = _score(rng, collided, perception)
    history.append({"query_id": queries, "algorithm": "bo", "score": adversarial})
    history.append({"query_id": queries + 1, "algorithm": "rerun", "score": adversarial})
    return {"original": history[0]["score"], "adversarial": adversarial, "queries": history,
            "failed_queries": 0, "flaky": []}  # fmt: skip


def _identity(attack: str, stack: str, algorithm: str = "bo", budget: int = 50, actors: int = 1,
              objective: str = "M0", seed: int = 0) -> dict[str, Any]:  # fmt: skip
    return {"attack": attack, "scenario": "kitti_0000", "window_start": 20, "stack": stack, "algorithm": algorithm,
            "budget": budget, "actors": actors, "objective": objective, "seed": seed,
            "bag": "/data/kitti_0000_bag"}  # fmt: skip


def _row(rng: np.random.Generator, attack: str, collided: bool, **identity: Any) -> dict[str, Any]:
    summary = _summary(rng, collided, queries=int(identity.get("budget", 50)) // 10)
    cost = {"wall_s": float(rng.uniform(600, 1800)), "cpu_s": float(rng.uniform(1200, 7200)), "peak_rss_mb": 900.0}
    return attack_row(_identity(attack, **identity), summary, cost, f"attacks/{attack}")


def _campaign(rng: np.random.Generator) -> tuple[list[dict[str, Any]], dict[str, list[float]]]:
    """2 stacks x 2 algorithms (different budgets) x 1 or 2 actors, one objective, and one failed attack."""
    rows, curves = [], {}
    for s, stack in enumerate(("modular", "learned")):
        for algorithm, budget in (("bo", 50), ("ga", 100)):
            for actors in (1, 2):
                for seed in range(3):
                    key = f"{stack}-{algorithm}-{actors}-{seed}"
                    summary = _summary(rng, collided=(seed + s) % 2 == 0, queries=budget // 10)
                    cost = {"wall_s": 900.0, "cpu_s": 3600.0, "peak_rss_mb": 800.0}
                    identity = _identity(key, stack, algorithm, budget, actors, seed=seed)
                    rows.append(attack_row(identity, summary, cost, f"attacks/{key}"))
                    curves[key] = best_curve(summary)
    rows.append(failed_row(_identity("modular-bo-1-9", "modular", seed=9), "stack died\ntraceback", "attacks/x"))
    return rows, curves


def _png(path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.new("RGB", (64, 48), (200, 40, 40)).save(path)
    return path


@pytest.fixture
def campaign(tmp_path: Path) -> tuple[Path, dict[str, Path], list[dict[str, Any]]]:
    rows, curves = _campaign(np.random.default_rng(7))
    transfers = [
        {"attack": r["attack"], "source_stack": r["stack"], "target_stack": other, "collision_5s": c,
         "adversarial_loss": 1.0, "status": "ok", "out_dir": f"transfer/{r['attack']}"}
        for r in rows if r["status"] == "ok" and r["adversarial_collision_5s"] == 1.0
        for other, c in ((("learned" if r["stack"] == "modular" else "modular"), float(r["seed"] == 0)),)
    ]  # fmt: skip
    out = tmp_path / "campaign"
    gallery = []
    for r in [r for r in rows if r["status"] == "ok" and r["adversarial_collision_5s"] == 1.0][:2]:
        (out / r["out_dir"] / "adversarial_bag").mkdir(parents=True)
        gallery.append({"attack": r["attack"], "bev_png": _png(out / r["out_dir"] / "bev.png"),
                        "bag": f"{r['out_dir']}/adversarial_bag", "title": f"{r['stack']} collides"})  # fmt: skip
    return out, write_report(out, rows, transfers, curves, gallery, seed=3), rows


def test_the_bootstrap_interval_holds_the_mean_is_the_value_for_one_and_is_seeded() -> None:
    values = np.random.default_rng(0).normal(2.0, 1.0, size=40)
    estimate = bootstrap_mean(values, seed=5)
    assert estimate.n == 40
    assert estimate.mean == pytest.approx(values.mean())
    assert estimate.low < estimate.mean < estimate.high
    assert estimate.high - estimate.low == pytest.approx(2 * 1.96 / math.sqrt(40), rel=0.3)  # about ±1.96 σ/√n
    assert bootstrap_mean(values, seed=5) == estimate
    assert bootstrap_mean(values, seed=6) != estimate
    assert bootstrap_mean([1.25], seed=5) == (1.25, 1.25, 1.25, 1)
    assert bootstrap_mean([math.nan, 3.0, None, ""]) == (3.0, 3.0, 3.0, 1)  # NaN, None and a CSV's '' left out
    empty = bootstrap_mean([math.nan])
    assert empty.n == 0
    assert math.isnan(empty.mean)


def test_collision_rates_are_the_mean_of_the_flags_in_percent() -> None:
    rng = np.random.default_rng(1)
    rows = [_row(rng, f"a{i}", collided=i < 3, stack="modular") for i in range(4)]
    rows[0]["original_collision_5s"] = 1.0
    table, rates = table1(rows, ["modular"], seed=0)
    assert rates[("modular", "adversarial", "5s")][0] == pytest.approx(75.0)
    assert rates[("modular", "original", "5s")] == (25.0, *rates[("modular", "original", "5s")][1:])
    low, high = rates[("modular", "adversarial", "5s")][1:]
    assert 0.0 <= low <= 75.0 <= high <= 100.0
    original, adversarial = table.rows
    assert original[:3] == ("modular", "original", "4")
    assert adversarial[table.header.index("collision ≤5 s [%]")].startswith("75.0 [")


def test_nan_metrics_are_left_out_of_their_cell(tmp_path: Path) -> None:
    rng = np.random.default_rng(2)
    rows = [_row(rng, f"a{i}", collided=True, stack="planner-only") for i in range(3)]
    for row in rows:
        row.update({f"{p}_{m}": math.nan for p in ("original", "adversarial") for m in METRICS[-3:]})
    rows[1]["adversarial_jerk"] = math.nan
    table, _ = table1(rows, ["planner-only"], seed=0)
    adversarial = dict(zip(table.header, table.rows[1], strict=True))
    assert adversarial["det. AP"] == adversarial["pred. L2 5 s [m]"] == "–"
    jerk = bootstrap_mean([rows[0]["adversarial_jerk"], rows[2]["adversarial_jerk"]], seed=0)
    assert adversarial["jerk [m/s³]"].startswith(f"{jerk.mean:.3g} [")
    text = (write_report(tmp_path, rows, [], {}, [])["markdown"]).read_text()
    assert "nan" not in text.lower()


def test_tables_appear_only_for_the_dimensions_the_campaign_varies(campaign: Any, tmp_path: Path) -> None:
    _, written, _ = campaign
    markdown = written["markdown"].read_text()
    for title in ("Table 1:", "Table 2:", "Table 3:", "Table 4:", "Table 5:", "Failed attacks", "Found failures"):
        assert title in markdown
    # Table 2: the standard stack (learned) first, the other one paired with it scene by scene; per family too
    assert re.search(r"\| learned \| 12 \| .* \| – \|\n\| modular \| 12 \| .* pp \(n=12\) \|", markdown)
    assert "## Table 2 per scene family" in markdown
    assert "Table 6:" not in markdown  # one objective
    assert "| stack | actors | n |" in markdown  # two stacks: grouped per stack too
    assert "| learned | ga | 100 |" in markdown
    rng = np.random.default_rng(3)
    plain = [_row(rng, f"a{i}", collided=i % 2 == 0, stack="modular", objective=o) for i, o in enumerate("ABAB")]
    written = write_report(tmp_path / "plain", plain, [], {}, [])
    markdown = written["markdown"].read_text()
    assert "Table 1:" in markdown
    assert "Table 6:" in markdown
    assert not re.search(r"Table [2345]:|Failed attacks|Found failures|Search progress", markdown)
    assert set(written) == {"results", "markdown", "html", "collision_plot"}  # no transfer.csv, no curves


def test_closed_loop_attacks_are_their_stacks_own_rows_with_the_open_loop_rates_beside(tmp_path: Path) -> None:
    rng = np.random.default_rng(5)
    rows = [_row(rng, f"o{i}", collided=i % 2 == 0, stack="modular") for i in range(4)]
    for index in range(4):
        row = _row(rng, f"c{index}", collided=index == 0, stack="modular")
        row.update(loop="closed", adversarial_open_loop_collision_5s=1.0, adversarial_min_distance=0.5 * index)
        rows.append(row)
    markdown = write_report(tmp_path / "loops", rows, [], {}, [])["markdown"].read_text()
    assert "| modular (closed loop) | adversarial | 4 |" in markdown.split("## Table 1")[1].split("##")[0]
    loops = markdown.split("## Closed loop against open loop")[1].split("##")[0]
    # what the ego drove collided in 1 of 4 adversarial scenarios, the plans it made at the decision in all 4
    assert "| modular (closed loop) | adversarial | 4 | 25.0 [" in loops
    assert "| 100.0 [100.0, 100.0] | 0.75 [" in loops


def test_the_transfer_matrix(campaign: Any) -> None:
    _, written, rows = campaign
    matrix = written["markdown"].read_text().split("## Table 3")[1].split("##")[0]
    assert "| source \\ target | learned | modular |" in matrix
    # each source's found scenarios: those with seed 0 collide on the other stack
    found = {
        s: [r for r in rows if r["stack"] == s and r["adversarial_collision_5s"] == 1.0] for s in ("modular", "learned")
    }
    rate = {s: 100.0 * np.mean([r["seed"] == 0 for r in found[s]]) for s in found}
    assert f"| modular | {rate['modular']:.1f} (n={len(found['modular'])}) | 100.0 (n={len(found['modular'])}) |" \
        in matrix  # fmt: skip
    assert f"| learned | 100.0 (n={len(found['learned'])}) | {rate['learned']:.1f} (n={len(found['learned'])}) |" \
        in matrix  # fmt: skip


def test_median_curves_per_algorithm_take_curves_of_any_length() -> None:
    rows = [{"attack": k, "algorithm": a} for k, a in (("a", "bo"), ("b", "bo"), ("c", "bo"), ("d", "ga"))]
    medians = median_curves(rows, {"a": [1.0, 2.0], "b": [math.nan, 4.0, 5.0], "c": [3.0, 3.0], "d": [0.5],
                                   "unknown": [9.0]})  # fmt: skip
    assert list(medians) == ["bo", "ga"]
    np.testing.assert_allclose(medians["bo"][0], [2.0, 3.0, 5.0])
    assert medians["bo"][1] == 3


def test_results_csv_round_trips(campaign: Any) -> None:
    out, written, rows = campaign
    with written["results"].open(newline="") as stream:
        reader = csv.DictReader(stream)
        assert tuple(reader.fieldnames or ()) == COLUMNS
        read = list(reader)
    assert len(read) == len(rows)
    for got, row in zip(read, rows, strict=True):
        for key in COLUMNS:
            value = row[key]
            if isinstance(value, float) and math.isnan(value):
                assert got[key] == ""
            elif isinstance(value, float):
                assert float(got[key]) == value
            else:
                assert got[key] == str(value)
    assert read[-1]["status"] == "failed"
    assert read[-1]["error"] == "stack died"
    assert (out / "transfer.csv").read_text().startswith("attack,source_stack,target_stack,")


def test_the_header_counts_attacks_and_hours(campaign: Any) -> None:
    _, written, rows = campaign
    markdown = written["markdown"].read_text()
    assert f"attacks: {len(rows) - 1} done, 1 failed ({len(rows)} in all); 0 flaky" in markdown
    assert f"{len(rows[:-1]) * 0.25:.2f} wall-hours, {len(rows[:-1]) * 1.0:.2f} CPU-hours" in markdown


def test_every_file_is_written_atomically_and_links_exist(campaign: Any, monkeypatch: pytest.MonkeyPatch) -> None:
    out, written, rows = campaign
    assert set(written) == {"results", "transfer", "markdown", "html", "collision_plot", "curve_plot"}
    assert all(path.parent == out and path.is_file() for path in written.values())
    assert not [p for p in out.iterdir() if p.name.startswith(".")]  # no temporary file left
    markdown = written["markdown"].read_text()
    for target in re.findall(r"\]\(([^)]+)\)", markdown):
        assert (out / target).exists(), target
    before = written["html"].read_bytes()

    def broken(*_: Any) -> str:
        raise RuntimeError("disk full")

    monkeypatch.setattr(report_module, "render_html", broken)
    with pytest.raises(RuntimeError):
        write_report(out, rows[:3], [], {}, [])
    assert written["html"].read_bytes() == before  # the old page stays whole
    assert not [p for p in out.iterdir() if p.name.startswith(".")]


def test_the_html_is_self_contained(campaign: Any) -> None:
    _, written, _ = campaign
    text = written["html"].read_text()
    assert not re.search(r"""(src|href)\s*=\s*["']?(https?:)?//""", text)
    assert "<script" not in text
    assert '<link rel="stylesheet"' not in text
    assert text.count('src="data:image/png;base64,') == 4  # 2 figures, 2 gallery pictures
    assert 'href="attacks/modular-bo-1-0/adversarial_bag"' in text


def test_a_campaign_without_finished_attacks_still_gets_its_report(tmp_path: Path) -> None:
    failed = [failed_row(_identity(f"a{i}", "modular", algorithm=a), "no stack", f"attacks/a{i}")
              for i, a in enumerate(("bo", "ga"))]  # fmt: skip
    for rows in ([], failed):
        written = write_report(tmp_path / str(len(rows)), rows, [], {}, [])
        assert set(written) == {"results", "markdown", "html"}
        markdown = written["markdown"].read_text()
        assert f"attacks: 0 done, {len(rows)} failed" in markdown
        assert "Table 1:" not in markdown
        assert ("Table 5:" in markdown) == bool(rows)  # the campaign varies the algorithm: its levels show '–'
        assert len(written["results"].read_text().splitlines()) == 1 + len(rows)


def test_table1_counts_the_stacks_failures_and_lists_the_collisions_left_out_with_their_reasons(tmp_path: Path) -> None:
    rng = np.random.default_rng(3)
    rows = []
    reasons = {"counted": [], "unavoidable": ["unavoidable: no ego within its limits escapes (actor_into_ego, rear)"],
               "sim": ["sim_dominated: gain 1.2, identity control 0.9 (margin 2)"]}  # fmt: skip
    for name, excluded in reasons.items():
        summary = _summary(rng, collided=True, queries=4)
        summary["finding"] = {"collision": True, "excluded": excluded}
        cost = {"wall_s": 60.0, "cpu_s": 60.0, "peak_rss_mb": 800.0}
        rows.append(attack_row(_identity(name, "modular"), summary, cost, f"attacks/{name}"))
    assert [row["failure"] for row in rows] == [1, 0, 0]
    assert [row["excluded"] for row in rows] == ["", "unavoidable", "sim_dominated"]
    written = write_report(tmp_path, rows, [], {}, [])
    markdown = written["markdown"].read_text()
    assert "Collisions not counted as the stack's failures" in markdown
    assert "| unavoidable | modular | unavoidable |" in markdown
    assert "| sim | modular | sim_dominated |" in markdown
    adversarial = next(line for line in markdown.splitlines() if line.startswith("| modular | adversarial |"))
    assert adversarial.rstrip(" |").endswith("]")  # the stack's failures: 1 of 3 attacks, 33.3 %
    assert "33.3 [" in adversarial.split("|")[-2]
