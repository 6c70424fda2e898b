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
from typing import Literal, NotRequired, TypeAlias, TypedDict, cast, overload

from advsim_ros.campaign.config import CampaignError
from advsim_ros.campaign.job import Shipping
from advsim_ros.campaign.results import ResultsRow, TransferRow
from advsim_ros.core.atomic import write_text_atomically
from advsim_ros.core.attack_summary import FindingRecord, Score
from advsim_ros.core.renamed import canonical_algorithm

JOURNAL_NAME = "campaign.jsonl"
VERSION = 1


class _Entry(TypedDict):
    job: str  # attack/KEY or transfer/KEY/TARGET
    error: NotRequired[str]  # the job failed: tried again when the campaign runs again
    shipping: NotRequired[Shipping]  # shipped jobs: bytes and seconds moving its inputs and outputs


class AttackEntry(_Entry):
    """A journal line of an attack job: its row, search curve and (finished ones) what it found."""

    row: ResultsRow
    curve: list[float]
    adversarial: NotRequired[Score | None]
    bag: NotRequired[str | None]  # its adversarial bag
    finding: NotRequired[FindingRecord | None]
    bag_params: NotRequired[Mapping[str, object]]  # the bag's layout (io.bag.bag_layout_json)


class TransferEntry(_Entry):
    """A journal line of a transfer job: a found scenario replayed on another stack."""

    row: TransferRow


JournalEntry: TypeAlias = AttackEntry | TransferEntry


# a journal's entries as JSON gives them, before _renamed and _typed
RawEntries: TypeAlias = dict[str, dict[str, object]]


def _entries(lines: list[bytes]) -> tuple[RawEntries, int]:
    """The entries of a journal's lines after its header, and the length in bytes of what stands (a line torn by a
    kill in the middle of its write, and anything after it, does not)."""
    entries: RawEntries = {}
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


def _renamed(entries: RawEntries) -> RawEntries:
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
    renamed: RawEntries = {}
    for job, entry in entries.items():
        kind, _, rest = job.partition("/")
        key, slash, target = rest.partition("/")
        if key in keys:
            job = f"{kind}/{keys[key]}{slash}{target}"
            entry = {**entry, "job": job}
            row = entry.get("row")
            if isinstance(row, dict):
                row = {**row, "attack": keys[key]}
                if kind == "attack":
                    row["algorithm"] = canonical_algorithm(str(row["algorithm"]))
                entry["row"] = row
        renamed[job] = entry
    return renamed


def _typed(entries: RawEntries) -> dict[str, JournalEntry]:
    # the journal's own lines: the driver appended each from a job's typed result (campaign.schedule), and JSON
    # keeps those types, so they are taken as they are rather than checked field by field
    return cast(dict[str, JournalEntry], entries)


def attack_entry(entry: JournalEntry) -> AttackEntry:
    """An entry of an attack job (its key says so)."""
    if not entry["job"].startswith("attack/"):
        raise ValueError(f"{entry['job']}: not an attack job")
    return cast(AttackEntry, entry)  # the key names the job's kind, and with it its entry's type


class CampaignJournal:
    """Finished jobs by key ("attack/KEY" or "transfer/KEY/TARGET"), in the order they finished."""

    def __init__(self, path: Path, entries: dict[str, JournalEntry]) -> None:
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
        return CampaignJournal(path, _typed(_renamed(entries)))

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
        return CampaignJournal(path, _typed(_renamed(_entries(lines)[0])))

    def __contains__(self, job: str) -> bool:
        """Finished without an error (a job that failed is tried again when the campaign is run again)."""
        return job in self.entries and "error" not in self.entries[job]

    def append(self, job: str, result: Mapping[str, object]) -> None:
        """Journal a job's result (JobOutcome less ok: an AttackEntry's or TransferEntry's keys but job)."""
        if job in self:
            return
        entry = cast(JournalEntry, {"job": job, **result})
        with self.path.open("a", encoding="utf-8") as stream:
            stream.write(json.dumps(entry) + "\n")
            stream.flush()
            os.fsync(stream.fileno())
        self.entries[job] = entry

    @overload
    def of_kind(self, kind: Literal["attack"], finished: bool = True) -> list[AttackEntry]: ...
    @overload
    def of_kind(self, kind: Literal["transfer"], finished: bool = True) -> list[TransferEntry]: ...
    def of_kind(self, kind: str, finished: bool = True) -> list[AttackEntry] | list[TransferEntry]:
        """Entries of one kind of job ("attack", "transfer"): finished ones, or (finished=False) every last entry."""
        chosen = [
            entry for job, entry in self.entries.items() if job.startswith(f"{kind}/") and (not finished or job in self)
        ]
        if kind == "attack":
            return [attack_entry(entry) for entry in chosen]
        return cast(list[TransferEntry], chosen)  # the rest: the key names the job's kind and its entry's type
