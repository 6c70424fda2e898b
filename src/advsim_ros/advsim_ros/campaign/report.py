"""The campaign report: results.csv, transfer.csv, report.md and report.html with the paper's tables.

AdvSim (Wang et al., CVPR 2021) reports original vs adversarial metrics per autonomy stack
(Table 1), how found scenarios transfer between stacks (Table 3), and the effect of the number of
perturbed actors (Table 4), the search algorithm and budget (Table 5) and the objective (Table 6).
Each table is made only when the campaign has that dimension, over the attacks that finished
(status ok); a mean comes with a percentile-bootstrap 95 % interval, seeded so that the same
results give the same report. Everything is written atomically: a reader never sees half a file.
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from advsim_ros.campaign.report_html import GalleryItem, Rates, Section, Table, collision_plot, curve_plot, render_html
from advsim_ros.campaign.results import COLUMNS, TRANSFER_COLUMNS, to_csv
from advsim_ros.core.atomic import write_text_atomically

RESAMPLES = 2000
LEVEL = 0.95
# (metric, column label, is a 0/1 collision flag shown as a rate in %): Table 1's columns
TABLE1_METRICS: tuple[tuple[str, str, bool], ...] = (
    ("collision_3s", "collision ≤3 s [%]", True),
    ("collision_5s", "collision ≤5 s [%]", True),
    ("l2_human_3s", "L2 3 s [m]", False),
    ("l2_human_5s", "L2 5 s [m]", False),
    ("lateral_acceleration", "lat. acc. [m/s²]", False),
    ("jerk", "jerk [m/s³]", False),
    ("detection_ap", "det. AP", False),
    ("prediction_l2_3s", "pred. L2 3 s [m]", False),
    ("prediction_l2_5s", "pred. L2 5 s [m]", False),
)
# Tables 4-6: the adversarial scenario's metrics per group
GROUP_METRICS: tuple[tuple[str, str, bool], ...] = (
    ("collision_5s", "adv. collision ≤5 s [%]", True),
    ("l2_human_5s", "adv. L2 5 s [m]", False),
    ("lateral_acceleration", "adv. lat. acc. [m/s²]", False),
    ("jerk", "adv. jerk [m/s³]", False),
)
DASH = "–"


class Estimate(NamedTuple):
    """A mean with its bootstrap interval over ``n`` finite values (all NaN when n is 0)."""

    mean: float
    low: float
    high: float
    n: int


def _float(value: Any) -> float:
    """A cell as a float: None, '' (a CSV's NaN) and what does not parse are NaN."""
    if isinstance(value, bool):
        return float(value)
    try:
        return float(value)
    except (TypeError, ValueError):
        return math.nan


def _truthy(value: Any) -> bool:
    return value.strip().lower() in ("1", "true", "yes") if isinstance(value, str) else bool(value)


def bootstrap_mean(values: Iterable[Any], seed: int = 0, resamples: int = RESAMPLES, level: float = LEVEL) -> Estimate:
    """Mean and percentile-bootstrap interval of the finite values; its own generator, so a cell's interval
    depends on the seed and its values only (not on which other cells the campaign has)."""
    data = np.array([v for v in map(_float, values) if math.isfinite(v)], dtype=np.float64)
    if data.size == 0:
        return Estimate(math.nan, math.nan, math.nan, 0)
    mean = float(data.mean())
    if np.all(data == data[0]):  # n = 1 or all alike: every resample has this mean
        return Estimate(float(data[0]), float(data[0]), float(data[0]), int(data.size))
    rng = np.random.default_rng(seed)
    chunk = max(1, 4_000_000 // data.size)  # bounded memory for large campaigns
    means = np.concatenate([
        data[rng.integers(0, data.size, size=(min(chunk, resamples - start), data.size))].mean(axis=1)
        for start in range(0, resamples, chunk)
    ])  # fmt: skip
    low, high = np.percentile(means, [50.0 * (1.0 - level), 50.0 * (1.0 + level)])
    return Estimate(mean, float(low), float(high), int(data.size))


def _number(value: float) -> str:
    if abs(value) < 5e-5:  # round-off of an exact zero (a plan that matches the log) reads as 0
        return "0"
    return f"{value:.0f}" if abs(value) >= 100 else f"{value:.3g}"


def cell(estimate: Estimate, percent: bool = False) -> str:
    """'mean [low, high]' (a 0/1 rate in %), '–' when no value was finite."""
    if estimate.n == 0:
        return DASH
    scale, show = (100.0, (lambda v: f"{v:.1f}")) if percent else (1.0, _number)
    return f"{show(estimate.mean * scale)} [{show(estimate.low * scale)}, {show(estimate.high * scale)}]"


def _ok(rows: Iterable[Mapping[str, Any]]) -> list[Mapping[str, Any]]:
    return [row for row in rows if row.get("status") == "ok"]


def _order(value: str) -> tuple[int, float, str]:
    """Numbers in numeric order (budget 50 before 200), then text."""
    number = _float(value)
    return (0, number, "") if math.isfinite(number) else (1, 0.0, value)


def _levels(rows: Iterable[Mapping[str, Any]], key: str) -> list[str]:
    return sorted({str(row.get(key, "")) for row in rows}, key=_order)


def _sum_hours(rows: Iterable[Mapping[str, Any]], key: str) -> float:
    return sum(v for v in (_float(row.get(key)) for row in rows) if math.isfinite(v)) / 3600.0


def table1(ok: Sequence[Mapping[str, Any]], stacks: Sequence[str], seed: int) -> tuple[Table, Rates]:
    """Original vs adversarial per stack; also the collision rates (%) the bar plot draws."""
    rows: list[tuple[str, ...]] = []
    rates: dict[tuple[str, str, str], tuple[float, ...]] = {}  # (stack, scenario, "3s"|"5s") -> (mean, low, high) in %
    for stack in stacks:
        mine = [row for row in ok if str(row.get("stack")) == stack]
        for scenario in ("original", "adversarial"):
            cells = [stack, scenario, str(len(mine))]
            for metric, _, percent in TABLE1_METRICS:
                estimate = bootstrap_mean((row.get(f"{scenario}_{metric}") for row in mine), seed)
                cells.append(cell(estimate, percent))
                if percent:
                    rates[(stack, scenario, metric[-2:])] = tuple(100.0 * v for v in estimate[:3])
            # the found collisions the failure rule counts as the stack's (reproduced, controls passed, avoidable)
            failures = bootstrap_mean((row.get("failure") for row in mine), seed) if scenario == "adversarial" else None
            cells.append(DASH if failures is None else cell(failures, True))
            rows.append(tuple(cells))
    header = ("stack", "scenario", "n", *(label for _, label, _ in TABLE1_METRICS), "stack's failures [%]")
    return Table(header, tuple(rows)), rates


def excluded_table(ok: Sequence[Mapping[str, Any]]) -> Table | None:
    """The found collisions the failure rule does not count as the stack's failures, each with its reasons."""
    shown = [
        (str(row.get("attack")), str(row.get("stack")), str(row.get("excluded") or "").replace(";", ", "))
        for row in ok
        if _float(row.get("adversarial_collision_5s")) > 0.5 and not _truthy(row.get("failure"))
    ]
    return Table(("attack", "stack", "not counted because"), tuple(shown)) if shown else None


def _labelled(row: Mapping[str, Any]) -> Mapping[str, Any]:
    """A results row whose stack says so when it was attacked in closed loop."""
    if row.get("loop") != "closed":
        return row
    return {**row, "stack": f"{row.get('stack')} (closed loop)"}


def loop_table(closed: Sequence[Mapping[str, Any]], seed: int) -> Table:
    """Per stack and scenario: collision rates of the driven ego and of its decision plan, and the closest gap."""
    body = []
    for stack in _levels(closed, "stack"):
        mine = [row for row in closed if str(row.get("stack")) == stack]
        for scenario in ("original", "adversarial"):
            driven = bootstrap_mean((row.get(f"{scenario}_collision_5s") for row in mine), seed)
            planned = bootstrap_mean((row.get(f"{scenario}_open_loop_collision_5s") for row in mine), seed)
            gap = bootstrap_mean((row.get(f"{scenario}_min_distance") for row in mine), seed)
            body.append((stack, scenario, str(len(mine)), cell(driven, True), cell(planned, True), cell(gap, False)))
    header = ("stack", "scenario", "n", "closed loop: collision ≤5 s [%]", "open loop: collision ≤5 s [%]", "gap [m]")
    return Table(header, tuple(body))


def table3(ok: Sequence[Mapping[str, Any]], transfers: Sequence[Mapping[str, Any]], seed: int) -> Table:
    """Source stack × target stack: collision rate (%) up to 5 s of the source's found scenarios on the target."""
    done = _ok(transfers)
    sources = _levels(done, "source_stack")
    targets = sorted({*_levels(done, "target_stack"), *sources}, key=_order)
    rows = []
    for source in sources:
        cells = [source]
        for target in targets:
            replays = [t for t in done if str(t["source_stack"]) == source and str(t["target_stack"]) == target]
            if not replays and source == target:  # the diagonal: the attacks' own result on the same scenarios
                keys = {str(t.get("attack")) for t in done if str(t["source_stack"]) == source}
                replays = [{"collision_5s": r.get("adversarial_collision_5s")} for r in ok
                           if str(r.get("stack")) == source and str(r.get("attack")) in keys]  # fmt: skip
            estimate = bootstrap_mean((t.get("collision_5s") for t in replays), seed)
            cells.append(DASH if estimate.n == 0 else f"{100.0 * estimate.mean:.1f} (n={estimate.n})")
        rows.append(tuple(cells))
    return Table(("source \\ target", *targets), tuple(rows))


def grouped(
    rows: Sequence[Mapping[str, Any]], keys: Sequence[str], seed: int, labels: Sequence[str] | None = None
) -> Table:
    """Tables 4-6: the adversarial metrics of the finished attacks per value of ``keys`` (levels with none: '–')."""
    ok = _ok(rows)
    groups = sorted({tuple(str(row.get(k, "")) for k in keys) for row in rows}, key=lambda g: [_order(v) for v in g])
    body = []
    for group in groups:
        mine = [row for row in ok if tuple(str(row.get(k, "")) for k in keys) == group]
        cells = [*group, str(len(mine))]
        cells += [cell(bootstrap_mean((r.get(f"adversarial_{m}") for r in mine), seed), p) for m, _, p in GROUP_METRICS]
        queries = bootstrap_mean((r.get("queries") for r in mine), seed)
        cells.append(DASH if queries.n == 0 else f"{queries.mean:.1f}")
        cells.append(f"{_sum_hours(mine, 'cpu_s'):.2f}" if mine else DASH)
        body.append(tuple(cells))
    header = (*(labels or keys), "n", *(label for _, label, _ in GROUP_METRICS), "queries", "CPU-hours")
    return Table(header, tuple(body))


def median_curves(
    rows: Sequence[Mapping[str, Any]], curves: Mapping[str, Sequence[float]]
) -> dict[str, tuple[np.ndarray, int]]:
    """Per algorithm: the median over its attacks of best-L_adv-so-far at each query, and how many attacks.

    Curves of different lengths are compared where they exist: at query i, the attacks that ran i queries.
    """
    algorithm = {str(row.get("attack")): str(row.get("algorithm")) for row in rows}
    found: dict[str, list[np.ndarray]] = {}
    for key, curve in curves.items():
        if key in algorithm and len(curve):
            found.setdefault(algorithm[key], []).append(np.array([_float(v) for v in curve], dtype=np.float64))
    medians = {}
    for name in sorted(found, key=_order):
        stacked = np.full((len(found[name]), max(c.size for c in found[name])), np.nan)
        for i, values in enumerate(found[name]):
            stacked[i, : values.size] = values
        median = np.array([np.median(col[np.isfinite(col)]) if np.isfinite(col).any() else np.nan for col in stacked.T])
        medians[name] = (median, len(found[name]))
    return medians


def _markdown_table(table: Table) -> str:
    def line(cells: Sequence[str]) -> str:
        return "| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |"

    return "\n".join([line(table.header), line(["---"] * len(table.header)), *(line(r) for r in table.rows)])


def render_markdown(
    title: str, header: Sequence[str], links: Sequence[tuple[str, str]], sections: Sequence[Section],
    gallery: Sequence[GalleryItem], out_dir: Path,
) -> str:  # fmt: skip
    """report.md: the same sections as the HTML page, figures and gallery pictures as relative image links."""
    parts = [f"# {title}", "", *(f"- {line}" for line in header), "", " · ".join(f"[{t}]({h})" for h, t in links)]
    for section in sections:
        parts += ["", f"## {section.title}", ""]
        if section.note:
            parts += [section.note, ""]
        if section.table is not None:
            parts += [_markdown_table(section.table), ""]
        if section.figure is not None:
            parts += [f"![{section.figure_alt}]({section.figure.name})", ""]
    if gallery:
        parts += ["", "## Found failures", ""]
        for item in gallery:
            picture = Path(os.path.relpath(item.png, out_dir)).as_posix()
            parts.append(f"- [![{item.title}]({picture})]({item.bag}) {item.title} — `{item.attack}`")
    return re.sub(r"\n{3,}", "\n\n", "\n".join(parts)).rstrip() + "\n"


def _sections(
    out_dir: Path, rows: Sequence[Mapping[str, Any]], transfers: Sequence[Mapping[str, Any]],
    curves: Mapping[str, Sequence[float]], seed: int, written: dict[str, Path],
) -> list[Section]:  # fmt: skip
    """The report's sections, the figures saved on the way (their paths added to ``written``)."""
    rows = [_labelled(row) for row in rows]  # closed-loop attacks are their stack's own rows ("stack (closed loop)")
    ok = _ok(rows)
    stacks = _levels(rows, "stack")
    by_stack = ["stack"] if len(stacks) > 1 else []
    sections: list[Section] = []
    if ok:
        table, rates = table1(ok, stacks, seed)
        written["collision_plot"] = out_dir / "collision_rates.png"
        collision_plot(written["collision_plot"], stacks, rates)
        sections.append(Section("table1", "Table 1: original vs adversarial scenarios, per stack",
                                f"Mean [bootstrap {LEVEL:.0%} interval] over the finished attacks; '{DASH}': "
                                "the metric was not measured.", table, written["collision_plot"],
                                "collision rates per stack, original vs adversarial"))  # fmt: skip
    excluded = excluded_table(ok)
    if excluded is not None:
        sections.append(Section("excluded", "Collisions not counted as the stack's failures",
                                "Found collisions the campaign's failure rule leaves out (failure.exclude): flaky "
                                "(did not reproduce), original_flaky, sim_dominated (within the margin of what "
                                "re-simulation alone does), unavoidable (no ego within its limits escapes). "
                                "docs/attack.md, \"Reading a finding\".", excluded))  # fmt: skip
    closed = [row for row in ok if row.get("loop") == "closed"]
    if closed:
        sections.append(Section("loops", "Closed loop against open loop, on the same scenarios",
                                "Collision rate up to 5 s [%]: of what the ego drove replanning every 0.1 s (closed "
                                "loop), and of the plan it made at the decision frame (open loop, the paper's), on the "
                                "same original and adversarial scenarios; the closest gap it came to an actor [m].",
                                loop_table(closed, seed)))  # fmt: skip
    if _ok(transfers):
        sections.append(Section("table3", "Table 3: transfer between stacks",
                                "Collision rate up to 5 s [%] of the source stack's found scenarios replayed on the "
                                "target stack (n replays); a diagonal without replays is the attacks' own result.",
                                table3(ok, transfers, seed)))  # fmt: skip
    dimensions: list[tuple[str, str, list[str], list[str]]] = [
        ("table4", "Table 4: number of perturbed actors", ["actors"], ["actors"]),
        ("table5", "Table 5: search algorithm and budget", ["algorithm", "budget"], ["algorithm", "budget"]),
        ("table6", "Table 6: objective", ["objective"], ["objective"]),
    ]
    for anchor, title, keys, labels in dimensions:
        if len({tuple(str(row.get(k, "")) for k in keys) for row in rows}) > 1:
            note = "Adversarial scenarios of the finished attacks: mean [bootstrap interval]; queries: mean per attack."
            sections.append(Section(anchor, title, note, grouped(rows, by_stack + keys, seed, by_stack + labels)))
    medians = median_curves(rows, curves)
    if medians:
        written["curve_plot"] = out_dir / "l_adv_curves.png"
        curve_plot(written["curve_plot"], medians)
        sections.append(Section("curves", "Search progress", "Median over each algorithm's attacks of the best "
                                "L_adv found after each searched query.", None, written["curve_plot"],
                                "best L_adv against query, per algorithm"))  # fmt: skip
    failed = [row for row in rows if row.get("status") != "ok"]
    if failed:
        shown = tuple((str(r.get("attack")), str(r.get("stack")), str(r.get("algorithm")), str(r.get("error", "")))
                      for r in failed[:50])  # fmt: skip
        sections.append(Section("failed", "Failed attacks", f"{len(shown)} of {len(failed)} shown; see results.csv.",
                                Table(("attack", "stack", "algorithm", "error"), shown)))  # fmt: skip
    return sections


def _header(rows: Sequence[Mapping[str, Any]]) -> list[str]:
    ok = _ok(rows)
    flaky = sum(1 for row in ok if _truthy(row.get("flaky")))
    return [
        f"attacks: {len(ok)} done, {len(rows) - len(ok)} failed ({len(rows)} in all); "
        f"{flaky} flaky (the best query did not reproduce when re-run)",
        f"time: {_sum_hours(rows, 'wall_s'):.2f} wall-hours, {_sum_hours(rows, 'cpu_s'):.2f} CPU-hours",
        *(f"{key}s: {', '.join(_levels(rows, key)) or DASH}" for key in ("stack", "algorithm", "objective")),
    ]


def write_report(
    out_dir: Path,
    rows: Sequence[Mapping[str, Any]],
    transfers: Sequence[Mapping[str, Any]],
    curves: Mapping[str, Sequence[float]],
    gallery: Sequence[Mapping[str, Any]],
    seed: int = 0,
) -> dict[str, Path]:
    """Write results.csv, transfer.csv (when there are transfers), the figures, report.md and report.html;
    return {name: path}. The pages come last, so the files they link exist when they appear."""
    out_dir = Path(out_dir)
    written: dict[str, Path] = {"results": out_dir / "results.csv"}
    write_text_atomically(written["results"], to_csv(rows, COLUMNS))
    links = [("results.csv", "results.csv")]
    if transfers:
        written["transfer"] = out_dir / "transfer.csv"
        write_text_atomically(written["transfer"], to_csv(transfers, TRANSFER_COLUMNS))
        links.append(("transfer.csv", "transfer.csv"))
    sections = _sections(out_dir, rows, transfers, curves, seed, written)
    items = [GalleryItem(str(g["attack"]), str(g.get("title", g["attack"])), Path(g["bev_png"]), str(g["bag"]))
             for g in gallery]  # fmt: skip
    title, header = "AdvSim campaign report", _header(rows)
    written["markdown"] = out_dir / "report.md"
    write_text_atomically(written["markdown"], render_markdown(title, header, links, sections, items, out_dir))
    written["html"] = out_dir / "report.html"
    write_text_atomically(written["html"], render_html(title, header, links, sections, items))
    return written
