"""What every campaign table is made of: the metric columns, bootstrap means and their cells, the finished rows.

A mean comes with a percentile-bootstrap 95 % interval, seeded so that the same results give the
same report (campaign.report, campaign.table2).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from typing import NamedTuple, SupportsFloat, TypeVar

import numpy as np

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
Row = TypeVar("Row", bound=Mapping[str, object])  # a results or transfer row (campaign.results), or a pooled one


class Estimate(NamedTuple):
    """A mean with its bootstrap interval over ``n`` finite values (all NaN when n is 0)."""

    mean: float
    low: float
    high: float
    n: int


def as_float(value: object) -> float:
    """A cell as a float: None, '' (a CSV's NaN) and what does not parse are NaN."""
    if not isinstance(value, str | SupportsFloat):  # None, a list, ...
        return math.nan
    try:
        return float(value)
    except (TypeError, ValueError):
        return math.nan


def truthy(value: object) -> bool:
    return value.strip().lower() in ("1", "true", "yes") if isinstance(value, str) else bool(value)


def bootstrap_mean(
    values: Iterable[object], seed: int = 0, resamples: int = RESAMPLES, level: float = LEVEL
) -> Estimate:
    """Mean and percentile-bootstrap interval of the finite values; its own generator, so a cell's interval
    depends on the seed and its values only (not on which other cells the campaign has)."""
    data = np.array([v for v in map(as_float, values) if math.isfinite(v)], dtype=np.float64)
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


def ok_rows(rows: Iterable[Row]) -> list[Row]:
    return [row for row in rows if row.get("status") == "ok"]


def level_order(value: str) -> tuple[int, float, str]:
    """Numbers in numeric order (budget 50 before 200), then text."""
    number = as_float(value)
    return (0, number, "") if math.isfinite(number) else (1, 0.0, value)


def levels(rows: Iterable[Mapping[str, object]], key: str) -> list[str]:
    return sorted({str(row.get(key, "")) for row in rows}, key=level_order)
