"""The campaign journal: one line per finished job, appended and fsync'd by the driver as it finishes.

The header names the configuration (its digest); a folder holds one campaign. A driver killed at
any point leaves a journal whose complete lines all stand (a torn last line is dropped on
reopening). Running the campaign again skips every journaled job; a job that finished but was
not journaled yet is picked up from its own folder's result file (campaign.worker), not re-run.
A journal written before an algorithm was renamed (SimBA was "rs") reads with the name it has now,
in its rows and its attacks' keys, so that the campaign resumes under either name.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from advsim_ros.campaign.config import CampaignError
from advsim_ros.core.atomic import write_text_atomically
from advsim_ros.core.renamed import canonical_algorithm

JOURNAL_NAME = "campaign.jsonl"
VERSION = 1


def _entries(lines: list[bytes]) -> tuple[dict[str, dict[str, Any]], int]:
    """The entries of a journal's lines after its header, and the length in bytes of what stands (a line torn by a
    kill in the middle of its write, and anything after it, does not)."""
    entries: dict[str, dict[str, Any]] = {}
    good = len(lines[0]) + 1
    for line in lines[1:]:
        if line.strip():
            try:
                entry = json.loads(line)
                entries[str(entry["job"])] = entry
            except (ValueError, KeyError, TypeError):
                break  # torn by a kill mid-write: what came before stands
        good += len(line) + 1
    return entries, good


def _renamed(entries: dict[str, dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """Entries with a renamed algorithm under its name now: its rows' ``algorithm`` and the attack keys naming it
    (config.expand spells ``-{algorithm}{budget}-``), in attack and transfer jobs alike."""
    keys: dict[str, str] = {}
    for entry in entries.values():
        row = entry.get("row")
        if str(entry["job"]).startswith("attack/") and isinstance(row, dict):
            old = str(row.get("algorithm", ""))
            if canonical_algorithm(old) != old:
                key = str(row.get("attack", ""))
                budget = row.get("budget", "")
                keys[key] = key.replace(f"-{old}{budget}-", f"-{canonical_algorithm(old)}{budget}-", 1)
    if not keys:
        return entries
    renamed: dict[str, dict[str, Any]] = {}
    for job, entry in entries.items():
        kind, _, rest = job.partition("/")
        key, slash, target = rest.partition("/")
        if key in keys:
            job = f"{kind}/{keys[key]}{slash}{target}"
            entry = {**entry, "job": job}
            if isinstance(entry.get("row"), dict):
                entry["row"] = dict(entry["row"], attack=keys[key])
                if kind == "attack":
                    entry["row"]["algorithm"] = canonical_algorithm(str(entry["row"]["algorithm"]))
        renamed[job] = entry
    return renamed


class CampaignJournal:
    """Finished jobs by key ("attack/KEY" or "transfer/KEY/TARGET"), in the order they finished."""

    def __init__(self, path: Path, entries: dict[str, dict[str, Any]]) -> None:
        self.path = path
        self.entries = entries

    @staticmethod
    def open(out_dir: Path, digest: str, config: Path) -> CampaignJournal:
        path = out_dir / JOURNAL_NAME
        if not path.exists():
            header = {"campaign_journal": VERSION, "config_digest": digest, "config": str(config)}
            write_text_atomically(path, json.dumps(header) + "\n")
            return CampaignJournal(path, {})
        lines = path.read_bytes().split(b"\n")
        try:
            header = json.loads(lines[0])
            recorded = header["config_digest"]
        except (ValueError, KeyError, TypeError):
            raise CampaignError(f"{path}: not a campaign journal; use another output folder") from None
        if recorded != digest:
            raise CampaignError(
                f"{out_dir} holds a campaign of another configuration ({header.get('config')}, changed since); "
                "use another output folder or the same configuration"
            )
        entries, good = _entries(lines)
        if good < path.stat().st_size:
            with path.open("r+b") as stream:
                stream.truncate(good)
                os.fsync(stream.fileno())
        return CampaignJournal(path, _renamed(entries))

    @staticmethod
    def read(out_dir: Path) -> CampaignJournal:
        """The journal of the campaign in out_dir as it stands, read only: for reports of finished or running
        campaigns (whatever their configuration now); a torn last line is left out, not cut off."""
        path = out_dir / JOURNAL_NAME
        if not path.is_file():
            raise CampaignError(f"{out_dir}: no campaign journal ({JOURNAL_NAME}); is it a campaign's output folder?")
        lines = path.read_bytes().split(b"\n")
        try:
            json.loads(lines[0])["campaign_journal"]
        except (ValueError, KeyError, TypeError):
            raise CampaignError(f"{path}: not a campaign journal") from None
        return CampaignJournal(path, _renamed(_entries(lines)[0]))

    def __contains__(self, job: str) -> bool:
        """Finished without an error (a job that failed is tried again when the campaign is run again)."""
        return job in self.entries and "error" not in self.entries[job]

    def append(self, job: str, result: Mapping[str, Any]) -> None:
        if job in self:
            return
        entry = {"job": job, **result}
        with self.path.open("a", encoding="utf-8") as stream:
            stream.write(json.dumps(entry) + "\n")
            stream.flush()
            os.fsync(stream.fileno())
        self.entries[job] = entry

    def of_kind(self, kind: str, finished: bool = True) -> list[dict[str, Any]]:
        """Entries of one kind of job ("attack", "transfer"): finished ones, or (finished=False) every last entry."""
        return [
            entry for job, entry in self.entries.items() if job.startswith(f"{kind}/") and (not finished or job in self)
        ]
