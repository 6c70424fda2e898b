"""Table 2: each stack against the standard (learned) stack, on the scenes both were attacked on.

Per stack, on the original and the adversarial scenes: the collision rate up to 5 s, L2 to the
human at 5 s and the plan's largest lateral acceleration and jerk (the paper's columns), with
bootstrap 95 % intervals (the campaign report's), plus each other stack's paired difference to
the standard one on the scenes both were attacked on: with few scenes the two stacks' intervals
overlap even when one of them is better on most scenes, and the paired difference is what says
whether robust training helped. A second table counts the scenes that collided per scene family:
where robust training helped, and where it did not.

The campaign report (campaign.report) has both as sections when a campaign attacked the standard
stack and another one. `advsim campaign-table2 OUT...` prints them from one or more campaign
folders' journals, not results.csv, so a campaign stopped early (scripts/table2.sh resumes it) is
summarised too, its n as it stands; several folders (one per training seed:
`TRAINING_SEED=N scripts/table2.sh`) are pooled, each stack paired with the standard stack of its
own campaign.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path

from advsim_ros.campaign.config import scene_family
from advsim_ros.campaign.journal import CampaignJournal
from advsim_ros.campaign.report_html import Table
from advsim_ros.campaign.results import ResultsRow
from advsim_ros.campaign.stats import GROUP_METRICS, TABLE1_METRICS, as_float, bootstrap_mean, cell

STANDARD = "learned"
# Table 2's columns: the report's per-group metrics (collision ≤5 s, L2 5 s, lateral acceleration, jerk), each on
# the original and on the adversarial scene, labelled as Table 1 labels them
METRICS: tuple[tuple[str, str, bool], ...] = tuple(
    (f"{scene}_{key}", f"{scene} {label}", percent)
    for key, label, percent in TABLE1_METRICS
    if key in {group_key for group_key, _, _ in GROUP_METRICS}
    for scene in ("original", "adversarial")
)
FAMILY_NOTE = "Scenes that collided within 5 s per scene family, adversarial / original of n."


class PooledRow(ResultsRow):
    """A results row of one of several campaigns pooled into one table."""

    campaign: str  # its campaign folder


def campaign_rows(out_dirs: Iterable[Path]) -> list[PooledRow]:
    """The finished attacks' rows of campaign folders' journals, each with its ``campaign`` folder."""
    rows: list[PooledRow] = []
    for out_dir in out_dirs:
        for entry in CampaignJournal.read(Path(out_dir)).of_kind("attack"):
            row = entry.get("row")
            if isinstance(row, dict) and row.get("status") == "ok":
                rows.append({**row, "campaign": str(out_dir)})
    return rows


def applies(rows: Iterable[ResultsRow]) -> bool:
    """Whether Table 2 says something: the standard stack and at least one other one were attacked."""
    stacks = {str(row.get("stack")) for row in rows}
    return STANDARD in stacks and len(stacks) > 1


# what makes two stacks' attacks a pair: the same scene attacked the same way (a campaign of several algorithms,
# actors, objectives or seeds has one pair per combination)
PAIRED_BY = ("scenario", "window_start", "algorithm", "budget", "actors", "objective", "seed")


def _scene(row: Mapping[str, object]) -> tuple[str, ...]:  # a ResultsRow, or a PooledRow with its campaign
    # pooled campaigns (another training seed's run) attack the same scenes with other stacks: pairs stay in theirs
    return (str(row.get("campaign", "")), *(str(row.get(key, "")) for key in PAIRED_BY))


def paired_differences(rows: Sequence[ResultsRow], stack: str, metric: str) -> list[float]:
    """``stack`` minus the standard stack on every scene both were attacked on, the same way (scene order)."""
    standard = {_scene(row): as_float(row.get(metric)) for row in rows if row["stack"] == STANDARD}
    other = {_scene(row): as_float(row.get(metric)) for row in rows if row["stack"] == stack}
    return [other[scene] - standard[scene] for scene in sorted(standard.keys() & other.keys())]


def _stacks(rows: Sequence[ResultsRow]) -> list[str]:
    return sorted({str(row["stack"]) for row in rows}, key=lambda name: (name != STANDARD, name))


def table2(rows: Iterable[ResultsRow], seed: int = 0) -> Table:
    """One line per stack, the standard one first."""
    rows = list(rows)
    header = ("stack", "n", *(label for _, label, _ in METRICS), "Δ adversarial collision vs standard (paired)")
    body = []
    for stack in _stacks(rows):
        own = [row for row in rows if row["stack"] == stack]
        cells = [cell(bootstrap_mean((row.get(key) for row in own), seed), percent) for key, _, percent in METRICS]
        if stack == STANDARD:
            paired = "–"
        else:
            differences = paired_differences(rows, stack, "adversarial_collision_5s")
            paired = f"{cell(bootstrap_mean(differences, seed), True)} pp (n={len(differences)})"
        body.append((stack, str(len(own)), *cells, paired))
    return Table(header, tuple(body))


def _collided(value: float) -> bool:
    return as_float(value) > 0.0  # NaN (not measured) is not a collision


def family_table(rows: Iterable[ResultsRow]) -> Table:
    """Per scene family and stack: scenes whose adversarial / original scenario collided within 5 s, of n."""
    rows = list(rows)
    stacks = _stacks(rows)
    body = []
    for family in sorted({scene_family(str(row["scenario"])) for row in rows}):
        cells = []
        for stack in stacks:
            own = [row for row in rows if row["stack"] == stack and scene_family(str(row["scenario"])) == family]
            adversarial = sum(_collided(row["adversarial_collision_5s"]) for row in own)
            original = sum(_collided(row["original_collision_5s"]) for row in own)
            cells.append(f"{adversarial} / {original} of {len(own)}")
        body.append((family, *cells))
    return Table(("family", *stacks), tuple(body))


def table2_markdown(rows: Iterable[ResultsRow], seed: int = 0) -> str:
    """Table 2 and the family table in Markdown, as `advsim campaign-table2` prints them."""
    rows = list(rows)
    return f"{table2(rows, seed).markdown()}\n\n{FAMILY_NOTE}\n\n{family_table(rows).markdown()}\n"
