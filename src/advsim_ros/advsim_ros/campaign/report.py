"""The campaign report: results.csv, transfer.csv, report.md and report.html with the paper's tables.

AdvSim (Wang et al., CVPR 2021) reports original vs adversarial metrics per autonomy stack
(Table 1), each stack against the standard learned one, paired scene by scene (Table 2,
campaign.table2), how found scenarios transfer between stacks (Table 3), and the effect of the
number of perturbed actors (Table 4), the search algorithm and budget (Table 5) and the objective
(Table 6).
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
from typing import NotRequired, TypedDict

import numpy as np

from advsim_ros.campaign.report_html import GalleryItem, Rates, Section, Table, collision_plot, curve_plot, render_html
from advsim_ros.campaign.results import COLUMNS, TRANSFER_COLUMNS, ResultsRow, TransferRow, to_csv
from advsim_ros.campaign.stats import (
    DASH,
    GROUP_METRICS,
    LEVEL,
    TABLE1_METRICS,
    as_float,
    bootstrap_mean,
    cell,
    level_order,
    levels,
    ok_rows,
    truthy,
)
from advsim_ros.campaign.table2 import FAMILY_NOTE, STANDARD, applies, family_table, table2
from advsim_ros.core.atomic import write_text_atomically


class GalleryEntry(TypedDict):
    """A found failure for the report's gallery (campaign.outputs)."""

    attack: str
    bev_png: Path
    bag: str  # relative to the campaign folder
    title: NotRequired[str]  # default: the attack


def _sum_hours(rows: Iterable[ResultsRow], key: str) -> float:
    return sum(v for v in (as_float(row.get(key)) for row in rows) if math.isfinite(v)) / 3600.0


def table1(ok: Sequence[ResultsRow], stacks: Sequence[str], seed: int) -> tuple[Table, Rates]:
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


def excluded_table(ok: Sequence[ResultsRow]) -> Table | None:
    """The found collisions the failure rule does not count as the stack's failures, each with its reasons."""
    shown = [
        (str(row.get("attack")), str(row.get("stack")), str(row.get("excluded") or "").replace(";", ", "))
        for row in ok
        if as_float(row.get("adversarial_collision_5s")) > 0.5 and not truthy(row.get("failure"))
    ]
    return Table(("attack", "stack", "not counted because"), tuple(shown)) if shown else None


def _labelled(row: ResultsRow) -> ResultsRow:
    """A results row whose stack says so when it was attacked in closed loop."""
    if row.get("loop") != "closed":
        return row
    return {**row, "stack": f"{row.get('stack')} (closed loop)"}


def loop_table(closed: Sequence[ResultsRow], seed: int) -> Table:
    """Per stack and scenario: collision rates of the driven ego and of its decision plan, and the closest gap."""
    body = []
    for stack in levels(closed, "stack"):
        mine = [row for row in closed if str(row.get("stack")) == stack]
        for scenario in ("original", "adversarial"):
            driven = bootstrap_mean((row.get(f"{scenario}_collision_5s") for row in mine), seed)
            planned = bootstrap_mean((row.get(f"{scenario}_open_loop_collision_5s") for row in mine), seed)
            gap = bootstrap_mean((row.get(f"{scenario}_min_distance") for row in mine), seed)
            body.append((stack, scenario, str(len(mine)), cell(driven, True), cell(planned, True), cell(gap, False)))
    header = ("stack", "scenario", "n", "closed loop: collision ≤5 s [%]", "open loop: collision ≤5 s [%]", "gap [m]")
    return Table(header, tuple(body))


def table3(ok: Sequence[ResultsRow], transfers: Sequence[TransferRow], seed: int) -> Table:
    """Source stack × target stack: collision rate (%) up to 5 s of the source's found scenarios on the target."""
    done = ok_rows(transfers)
    sources = levels(done, "source_stack")
    targets = sorted({*levels(done, "target_stack"), *sources}, key=level_order)
    rows = []
    for source in sources:
        cells = [source]
        for target in targets:
            replays = [t["collision_5s"] for t in done if t["source_stack"] == source and t["target_stack"] == target]
            if not replays and source == target:  # the diagonal: the attacks' own result on the same scenarios
                keys = {t["attack"] for t in done if t["source_stack"] == source}
                replays = [r["adversarial_collision_5s"] for r in ok if r["stack"] == source and r["attack"] in keys]
            estimate = bootstrap_mean(replays, seed)
            cells.append(DASH if estimate.n == 0 else f"{100.0 * estimate.mean:.1f} (n={estimate.n})")
        rows.append(tuple(cells))
    return Table(("source \\ target", *targets), tuple(rows))


def grouped(rows: Sequence[ResultsRow], keys: Sequence[str], seed: int, labels: Sequence[str] | None = None) -> Table:
    """Tables 4-6: the adversarial metrics of the finished attacks per value of ``keys`` (levels with none: '–')."""
    ok = ok_rows(rows)
    groups = sorted({tuple(str(row.get(k, "")) for k in keys) for row in rows}, key=lambda g: list(map(level_order, g)))
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
    rows: Sequence[ResultsRow], curves: Mapping[str, Sequence[float]]
) -> dict[str, tuple[np.ndarray, int]]:
    """Per algorithm: the median over its attacks of best-L_adv-so-far at each query, and how many attacks.

    Curves of different lengths are compared where they exist: at query i, the attacks that ran i queries.
    """
    algorithm = {str(row.get("attack")): str(row.get("algorithm")) for row in rows}
    found: dict[str, list[np.ndarray]] = {}
    for key, curve in curves.items():
        if key in algorithm and len(curve):
            found.setdefault(algorithm[key], []).append(np.array([as_float(v) for v in curve], dtype=np.float64))
    medians = {}
    for name in sorted(found, key=level_order):
        stacked = np.full((len(found[name]), max(c.size for c in found[name])), np.nan)
        for i, values in enumerate(found[name]):
            stacked[i, : values.size] = values
        median = np.array([np.median(col[np.isfinite(col)]) if np.isfinite(col).any() else np.nan for col in stacked.T])
        medians[name] = (median, len(found[name]))
    return medians


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
            parts += [section.table.markdown(), ""]
        if section.figure is not None:
            parts += [f"![{section.figure_alt}]({section.figure.name})", ""]
    if gallery:
        parts += ["", "## Found failures", ""]
        for item in gallery:
            picture = Path(os.path.relpath(item.png, out_dir)).as_posix()
            parts.append(f"- [![{item.title}]({picture})]({item.bag}) {item.title} — `{item.attack}`")
    return re.sub(r"\n{3,}", "\n\n", "\n".join(parts)).rstrip() + "\n"


def _sections(
    out_dir: Path, rows: Sequence[ResultsRow], transfers: Sequence[TransferRow],
    curves: Mapping[str, Sequence[float]], seed: int, written: dict[str, Path],
) -> list[Section]:  # fmt: skip
    """The report's sections, the figures saved on the way (their paths added to ``written``)."""
    rows = [_labelled(row) for row in rows]  # closed-loop attacks are their stack's own rows ("stack (closed loop)")
    ok = ok_rows(rows)
    stacks = levels(rows, "stack")
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
    if applies(ok):
        sections.append(Section("table2", "Table 2: each stack against the standard stack, scene by scene",
                                f"Mean [bootstrap {LEVEL:.0%} interval] per stack on the original and the adversarial "
                                f"scenes; the last column: the stack's adversarial collision rate minus the standard "
                                f"stack's ({STANDARD}) on the scenes both were attacked on, the same way "
                                "(percentage points).",
                                table2(ok, seed)))  # fmt: skip
        sections.append(Section("table2-families", "Table 2 per scene family", FAMILY_NOTE, family_table(ok)))
    if ok_rows(transfers):
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


def _header(rows: Sequence[ResultsRow]) -> list[str]:
    ok = ok_rows(rows)
    flaky = sum(1 for row in ok if truthy(row.get("flaky")))
    return [
        f"attacks: {len(ok)} done, {len(rows) - len(ok)} failed ({len(rows)} in all); "
        f"{flaky} flaky (the best query did not reproduce when re-run)",
        f"time: {_sum_hours(rows, 'wall_s'):.2f} wall-hours, {_sum_hours(rows, 'cpu_s'):.2f} CPU-hours",
        *(f"{key}s: {', '.join(levels(rows, key)) or DASH}" for key in ("stack", "algorithm", "objective")),
    ]


def write_report(
    out_dir: Path,
    rows: Sequence[ResultsRow],
    transfers: Sequence[TransferRow],
    curves: Mapping[str, Sequence[float]],
    gallery: Sequence[GalleryEntry],
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
