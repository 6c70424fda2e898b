"""A campaign's outputs, written from its journal alone: the regression suite and the report."""

from __future__ import annotations

from pathlib import Path
from typing import TypedDict

from advsim_ros.campaign.config import load_campaign
from advsim_ros.campaign.journal import CampaignJournal
from advsim_ros.campaign.report import GalleryEntry, write_report
from advsim_ros.campaign.suite import export_suite
from advsim_ros.io.bag import BagConfig


class CampaignOutputs(TypedDict):
    suite: Path
    suite_size: int  # scenarios in the suite
    results_csv: Path
    report_md: Path
    report_html: Path


def write_campaign_outputs(
    config: Path, out_dir: Path, journal: CampaignJournal, bag_config: BagConfig | None = None
) -> CampaignOutputs:
    """OUTDIR/suite, results.csv, transfer.csv, report.md, report.html (each written atomically)."""
    campaign = load_campaign(config, bag_config)
    out_dir = out_dir.resolve()
    attacks = journal.of_kind("attack", finished=False)  # errors too: results.csv says which attacks failed
    suite = export_suite(out_dir, journal.of_kind("attack"), campaign.failure)
    gallery: list[GalleryEntry] = []
    for entry in journal.of_kind("attack"):
        row = entry["row"]
        if not campaign.failure.counts(entry):
            continue
        picture = out_dir / row["out_dir"] / "bev.png"
        if picture.is_file():
            title = f"{row['stack']} on {row['scenario']} @ {row['window_start']} ({row['algorithm']})"
            gallery.append(
                {"attack": row["attack"], "bev_png": picture, "bag": f"suite/{row['attack']}", "title": title}
            )
    for entry in attacks:  # the campaign's failure rule decides what counts as the stack's failure
        entry["row"]["failure"] = int(campaign.failure.counts(entry))
    written = write_report(
        out_dir,
        [entry["row"] for entry in attacks],
        [entry["row"] for entry in journal.of_kind("transfer")],
        {entry["row"]["attack"]: entry.get("curve", []) for entry in journal.of_kind("attack")},
        gallery,
    )
    return {
        "suite": suite,
        "suite_size": sum(1 for p in suite.iterdir() if p.is_dir()),
        "results_csv": written["results"],
        "report_md": written["markdown"],
        "report_html": written["html"],
    }
