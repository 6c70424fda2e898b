"""The campaign report's figures (matplotlib, Agg) and its self-contained HTML page.

The page inlines its CSS and every picture (base64 PNG) so it can be mailed or archived alone and
opened where nothing can be fetched; only its links (results.csv, the bags) are relative. The HTML
helpers are the single-attack report's (viz.report), so both pages look and escape alike.
"""

from __future__ import annotations

import io
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from advsim_ros.core.atomic import atomic_file
from advsim_ros.viz.report import REPORT_CSS, data_uri, esc, html_table

_EXTRA_CSS = """
.gallery { display: flex; flex-wrap: wrap; gap: 1rem; } .gallery figure { width: 22rem; }
figcaption { font-size: .85rem; } td { white-space: nowrap; } .wide { overflow-x: auto; }
"""


@dataclass(frozen=True)
class Table:
    """A table as text cells, so Markdown and HTML show exactly the same numbers."""

    header: tuple[str, ...]
    rows: tuple[tuple[str, ...], ...]

    def markdown(self) -> str:
        """The table in Markdown (no newline at the end); a '|' in a cell escaped."""

        def line(cells: Sequence[str]) -> str:
            return "| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |"

        return "\n".join([line(self.header), line(["---"] * len(self.header)), *(line(r) for r in self.rows)])


@dataclass(frozen=True)
class Section:
    """One heading of the report: a note, then a table and/or a figure (a PNG beside report.md)."""

    anchor: str
    title: str
    note: str = ""
    table: Table | None = None
    figure: Path | None = None
    figure_alt: str = ""


@dataclass(frozen=True)
class GalleryItem:
    """A found failure: its bird's-eye view and the adversarial bag (relative to the campaign folder)."""

    attack: str
    title: str
    png: Path
    bag: str


def _save(figure: Any, path: Path) -> None:  # a matplotlib Figure (matplotlib: imported lazily, untyped here)
    """Save a figure atomically: a half-written PNG would break both report pages."""
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png")
    with atomic_file(path, "wb") as stream:
        stream.write(buffer.getvalue())


def _pyplot() -> Any:  # matplotlib.pyplot, imported lazily (a heavy import)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


Rates = Mapping[tuple[str, str, str], tuple[float, ...]]


def collision_plot(path: Path, stacks: Sequence[str], rates: Rates) -> None:
    """Bars per stack: collision rate (%) up to 3 s and 5 s, original vs adversarial, with their 95 % intervals.

    ``rates`` maps (stack, "original"|"adversarial", "3s"|"5s") to (mean, low, high); NaN draws no bar.
    """
    plt = _pyplot()
    kinds = (("original", "3s", "#9ec5e8"), ("adversarial", "3s", "#f4a3a3"),
             ("original", "5s", "#1f77b4"), ("adversarial", "5s", "#d62728"))  # fmt: skip
    width = 0.8 / len(kinds)
    figure, axis = plt.subplots(figsize=(max(5.0, 1.6 * len(stacks) + 2.0), 3.4), dpi=96)
    try:
        x = np.arange(len(stacks), dtype=np.float64)
        for k, (scenario, horizon, colour) in enumerate(kinds):
            values = np.array([rates[(s, scenario, horizon)] for s in stacks], dtype=np.float64).reshape(-1, 3)
            errors = np.abs(np.vstack([values[:, 0] - values[:, 1], values[:, 2] - values[:, 0]]))
            axis.bar(x + (k - 1.5) * width, np.nan_to_num(values[:, 0]), width, color=colour,
                     yerr=np.nan_to_num(errors), capsize=3, label=f"{scenario}, up to {horizon[:-1]} s")  # fmt: skip
        axis.set_xticks(x, list(stacks))
        axis.set_ylabel("collision rate [%]")
        axis.set_ylim(0, 135)  # headroom: the legend never hides a bar
        axis.set_yticks(range(0, 101, 20))
        axis.grid(axis="y", alpha=0.3)
        axis.legend(fontsize=8, ncols=2)
        figure.tight_layout()
        _save(figure, path)
    finally:
        plt.close(figure)


def curve_plot(path: Path, medians: Mapping[str, tuple[np.ndarray, int]]) -> None:
    """Median best-L_adv-so-far against the searched query, one line per algorithm (n attacks in the legend)."""
    plt = _pyplot()
    figure, axis = plt.subplots(figsize=(7.0, 3.4), dpi=96)
    try:
        for algorithm, (median, count) in medians.items():
            axis.step(np.arange(1, median.size + 1), median, where="post", lw=2, label=f"{algorithm} (n={count})")
        axis.set_xlabel("searched query")
        axis.set_ylabel("best L_adv so far (median)")
        axis.grid(alpha=0.3)
        axis.legend(fontsize=8)
        figure.tight_layout()
        _save(figure, path)
    finally:
        plt.close(figure)


def _figure_html(section: Section) -> str:
    if section.figure is None:
        return ""
    uri = data_uri(section.figure, "image/png")
    if uri is None:
        return f'<p class="muted">{esc(section.figure.name)} was not written.</p>'
    return f'<figure><img id="{esc(section.anchor)}-figure" alt="{esc(section.figure_alt)}" src="{uri}"></figure>'


def _gallery_html(items: Sequence[GalleryItem]) -> str:
    figures = []
    for number, item in enumerate(items):
        uri = data_uri(item.png, "image/png")
        picture = (f'<img id="gallery-{number}" alt="{esc(item.title)}" src="{uri}">' if uri
                   else f'<span class="muted">{esc(item.png.name)} is missing</span>')  # fmt: skip
        figures.append(
            f'<figure><a href="{esc(item.bag)}">{picture}</a><figcaption>{esc(item.title)} — '
            f'<code>{esc(item.attack)}</code>, bag <a href="{esc(item.bag)}">{esc(item.bag)}</a></figcaption></figure>'
        )
    return '<div class="gallery">' + "".join(figures) + "</div>"


def render_html(
    title: str, header: Sequence[str], links: Sequence[tuple[str, str]], sections: Sequence[Section],
    gallery: Sequence[GalleryItem],
) -> str:  # fmt: skip
    """The whole page; ``links`` are (relative href, label) of the campaign's files."""
    parts = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        '<meta name="viewport" content="width=device-width, initial-scale=1">',
        '<link rel="icon" href="data:,">',  # no favicon request
        f"<title>{esc(title)}</title>",
        f"<style>{REPORT_CSS}{_EXTRA_CSS}</style></head><body>",
        f"<h1>{esc(title)}</h1>",
        '<ul id="summary">' + "".join(f"<li>{esc(line)}</li>" for line in header) + "</ul>",
        "<p>" + " · ".join(f'<a href="{esc(href)}">{esc(label)}</a>' for href, label in links) + "</p>",
    ]
    for section in sections:
        parts.append(f'<h2 id="{esc(section.anchor)}">{esc(section.title)}</h2>')
        if section.note:
            parts.append(f'<p class="muted">{esc(section.note)}</p>')
        if section.table is not None:
            parts.append(f'<div class="wide">{html_table(section.table.header, section.table.rows)}</div>')
        parts.append(_figure_html(section))
    if gallery:
        parts += ['<h2 id="gallery">Found failures</h2>', _gallery_html(gallery)]
    parts.append("</body></html>")
    return "\n".join(parts)
