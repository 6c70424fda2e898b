"""Table 2 from campaign journals (`python -m advsim_ros.campaign.table2 OUT/eval`).

Per stack, on the original and the adversarial scenes: the collision rate up to 5 s, L2 to the
human at 5 s and the plan's largest lateral acceleration and jerk (the paper's columns), with
bootstrap 95 % intervals (the campaign report's), plus each other stack's paired difference to
the standard one on the scenes both were attacked on: with few scenes the two stacks' intervals
overlap even when one of them is better on most scenes, and the paired difference is what says
whether robust training helped. It reads the journal, not results.csv, so a campaign stopped
early (scripts/table2.sh resumes it) is summarised too, its n as it stands. Several campaign
folders may be given (one per training seed: `TRAINING_SEED=N scripts/table2.sh`); their rows are
pooled and each stack is paired with the standard stack of its own campaign. A second table counts
the scenes that collided per scene family: where robust training helped, and where it did not.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from advsim_ros.campaign.config import scene_family
from advsim_ros.campaign.report import GROUP_METRICS, TABLE1_METRICS, _float, bootstrap_mean, cell

STANDARD = "learned"
# Table 2's columns: the report's per-group metrics (collision ≤5 s, L2 5 s, lateral acceleration, jerk), each on
# the original and on the adversarial scene, labelled as Table 1 labels them
METRICS: tuple[tuple[str, str, bool], ...] = tuple(
    (f"{scene}_{key}", f"{scene} {label}", percent)
    for key, label, percent in TABLE1_METRICS
    if key in {group_key for group_key, _, _ in GROUP_METRICS}
    for scene in ("original", "adversarial")
)


def journal_rows(journal: Path) -> list[dict[str, Any]]:
    """The finished attacks' rows of a campaign journal (OUTDIR/campaign.jsonl), each with its ``campaign`` folder."""
    rows = []
    for line in journal.read_text(encoding="utf-8").splitlines():
        entry = json.loads(line)
        row = entry.get("row") if isinstance(entry, dict) else None
        if str(entry.get("job", "")).startswith("attack/") and isinstance(row, dict) and row.get("status") == "ok":
            rows.append({**row, "campaign": str(journal.parent)})
    return rows


def _scene(row: Mapping[str, Any]) -> tuple[str, str, int]:
    # pooled campaigns (another training seed's run) attack the same scenes with other stacks: pairs stay in theirs
    return str(row.get("campaign", "")), str(row["scenario"]), int(row["window_start"])


def paired_differences(rows: Sequence[Mapping[str, Any]], stack: str, metric: str) -> list[float]:
    """``stack`` minus the standard stack on every scene both were attacked on (scene order)."""
    standard = {_scene(row): _float(row[metric]) for row in rows if row["stack"] == STANDARD}
    other = {_scene(row): _float(row[metric]) for row in rows if row["stack"] == stack}
    return [other[scene] - standard[scene] for scene in sorted(standard.keys() & other.keys())]


def table2_markdown(rows: Iterable[Mapping[str, Any]], seed: int = 0) -> str:
    """The Markdown table: one line per stack, the standard one first."""
    rows = list(rows)
    stacks = sorted({str(row["stack"]) for row in rows}, key=lambda name: (name != STANDARD, name))
    header = ["stack", "n", *(label for _, label, _ in METRICS), "Δ adversarial collision vs standard (paired)"]
    lines = ["| " + " | ".join(header) + " |", "|" + " --- |" * len(header)]
    for stack in stacks:
        own = [row for row in rows if row["stack"] == stack]
        cells = [cell(bootstrap_mean((row[key] for row in own), seed), percent) for key, _, percent in METRICS]
        if stack == STANDARD:
            paired = "–"
        else:
            differences = paired_differences(rows, stack, "adversarial_collision_5s")
            paired = f"{cell(bootstrap_mean(differences, seed), True)} pp (n={len(differences)})"
        lines.append("| " + " | ".join([stack, str(len(own)), *cells, paired]) + " |")
    return "\n".join(lines) + "\n"


def _collided(value: Any) -> bool:
    return _float(value) > 0.0  # NaN (not measured) is not a collision


def family_markdown(rows: Iterable[Mapping[str, Any]]) -> str:
    """Per scene family and stack: scenes whose adversarial / original scenario collided within 5 s, of n."""
    rows = list(rows)
    stacks = sorted({str(row["stack"]) for row in rows}, key=lambda name: (name != STANDARD, name))
    families = sorted({scene_family(str(row["scenario"])) for row in rows})
    lines = ["| family | " + " | ".join(stacks) + " |", "|" + " --- |" * (len(stacks) + 1)]
    for family in families:
        cells = []
        for stack in stacks:
            own = [row for row in rows if row["stack"] == stack and scene_family(str(row["scenario"])) == family]
            adversarial = sum(_collided(row["adversarial_collision_5s"]) for row in own)
            original = sum(_collided(row["original_collision_5s"]) for row in own)
            cells.append(f"{adversarial} / {original} of {len(own)}")
        lines.append(f"| {family} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> int:
    args = list(sys.argv[1:] if argv is None else argv)
    if not args:
        print("usage: python -m advsim_ros.campaign.table2 CAMPAIGN_OUTDIR...", file=sys.stderr)
        return 2
    rows = [row for folder in args for row in journal_rows(Path(folder) / "campaign.jsonl")]
    print(table2_markdown(rows))
    print("Scenes that collided within 5 s per scene family, adversarial / original of n:\n")
    print(family_markdown(rows), end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
