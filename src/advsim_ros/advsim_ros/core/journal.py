"""The attack journal: every finished query, appended and fsync'd as it finishes, and the attack it belongs to.

The first line is a header with the attack's fingerprint (bag, window, stack, algorithm, seed,
budget, a digest of every parameter); each further line is one finished query (its
perturbation and its score). A run killed at any point leaves a journal whose complete lines
all stand (a line cut short by the kill is dropped on reopening); running the same attack again
replays them into the search instead of recomputing them, and a journal of a different attack
is refused with the keys that differ. A line damaged in the middle (a disk error, an editor) is
not silently dropped: it is kept aside in queries.jsonl.corrupt with a warning naming its line,
and its query is evaluated again.
"""

from __future__ import annotations

import json
import logging
import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from advsim_ros.core.atomic import write_text_atomically
from advsim_ros.core.closed_loop import ExecutedTrajectory
from advsim_ros.core.renamed import canonical_algorithm
from advsim_ros.core.types import ActorClass, ActorTrack, Plan, ScenarioError

JOURNAL_VERSION = 1
_log = logging.getLogger(__name__)
_FINISHED_KEY = "search_finished"


class JournalError(ScenarioError):
    """A journal that cannot be used for this attack; the message says why."""


@dataclass(frozen=True)
class Fingerprint:
    """What makes two attacks the same attack: name -> value (strings, numbers, digests)."""

    values: Mapping[str, Any]
    # what journals of before recorded instead of a value that is the same attack's now (a bag's path, before the
    # bag's content digest): a recorded journal with either resumes
    former: Mapping[str, Any] = field(default_factory=dict)

    def differences(self, other: Fingerprint) -> list[str]:
        """Keys whose values differ (self: as recorded; other: now, with its former values)."""
        keys = sorted(set(self.values) | set(other.values))
        return [
            key
            for key in keys
            if self.values.get(key) != other.values.get(key)
            and (key not in other.former or self.values.get(key) != other.former[key])
        ]


def _track_json(track: ActorTrack) -> dict[str, Any]:
    return {
        "actor_id": track.actor_id,
        "actor_class": track.actor_class.value,
        "size": track.size.tolist(),
        "stamps_ns": track.stamps_ns.tolist(),
        "centers": track.centers.tolist(),
        "yaws": track.yaws.tolist(),
    }


def _track_from_json(values: Mapping[str, Any]) -> ActorTrack:
    return ActorTrack(
        actor_id=str(values["actor_id"]),
        actor_class=ActorClass(values["actor_class"]),
        size=np.array(values["size"], dtype=np.float64),
        stamps_ns=np.array(values["stamps_ns"], dtype=np.int64),
        centers=np.array(values["centers"], dtype=np.float64).reshape(-1, 3),
        yaws=np.array(values["yaws"], dtype=np.float64),
    )


def _plan_json(plan: Plan | None) -> dict[str, Any] | None:
    if plan is None:
        return None
    return {"stamps_ns": plan.stamps_ns.tolist(), "xy": plan.xy.tolist(), "yaws": plan.yaws.tolist()}


def _executed_json(executed: ExecutedTrajectory | None) -> dict[str, Any] | None:
    if executed is None:
        return None
    return {"stamps_ns": executed.stamps_ns.tolist(), "states": executed.states.tolist()}


def _executed_from_json(values: Mapping[str, Any] | None) -> ExecutedTrajectory | None:
    if values is None:
        return None
    states = np.array(values["states"], dtype=np.float64).reshape(-1, 6)
    return ExecutedTrajectory(np.array(values["stamps_ns"], dtype=np.int64), states, ())


def _plan_from_json(values: Mapping[str, Any] | None) -> Plan | None:
    if values is None:
        return None
    return Plan(
        stamps_ns=np.array(values["stamps_ns"], dtype=np.int64),
        xy=np.array(values["xy"], dtype=np.float64).reshape(-1, 2),
        yaws=np.array(values["yaws"], dtype=np.float64),
    )


@dataclass(frozen=True)
class QueryRecord:
    """One finished query as journaled: what was asked, what the stack answered, how it scored."""

    query_id: int
    algorithm: str
    actor_ids: tuple[str, ...]
    delta: tuple[float, ...]
    score: Mapping[str, Any]  # the QueryScore as a JSON object (contract.protocol.ScoreRecord.as_dict)
    tracks: tuple[ActorTrack, ...] = ()  # the perturbed actors' trajectories (log time)
    plan: Plan | None = None  # the stack's plan of the decision frame (log time), None when it gave none
    executed: ExecutedTrajectory | None = None  # closed loop: what the ego drove (log time; plans not kept)
    reacted: tuple[ActorTrack, ...] = ()  # closed loop, reactive actors: the drives of those that reacted (log time)

    @property
    def ok(self) -> bool:
        return bool(self.score.get("status") == "ok")

    @property
    def value(self) -> float:
        """L_adv as the search sees it: NaN for a failed query."""
        loss = self.score.get("adversarial_loss")
        return float(loss) if self.ok and loss is not None else math.nan

    def as_json(self) -> dict[str, Any]:
        return {
            "query_id": self.query_id,
            "algorithm": self.algorithm,
            "actor_ids": list(self.actor_ids),
            "delta": list(self.delta),
            "score": dict(self.score),
            "tracks": [_track_json(track) for track in self.tracks],
            "plan": _plan_json(self.plan),
            **({"executed": _executed_json(self.executed)} if self.executed is not None else {}),
            **({"reacted": [_track_json(track) for track in self.reacted]} if self.reacted else {}),
        }

    @staticmethod
    def from_json(values: Mapping[str, Any]) -> QueryRecord:
        return QueryRecord(
            query_id=int(values["query_id"]),
            algorithm=canonical_algorithm(str(values["algorithm"])),  # journals of before a rename: its name now
            actor_ids=tuple(str(a) for a in values["actor_ids"]),
            delta=tuple(float(v) for v in values["delta"]),
            score=dict(values["score"]),
            tracks=tuple(_track_from_json(track) for track in values.get("tracks", ())),
            plan=_plan_from_json(values.get("plan")),
            executed=_executed_from_json(values.get("executed")),
            reacted=tuple(_track_from_json(track) for track in values.get("reacted", ())),
        )


def _renamed(fingerprint: Fingerprint) -> Fingerprint:
    """A recorded fingerprint with its algorithm as it is named now (a journal of SimBA as "rs" resumes as "simba")."""
    algorithm = fingerprint.values.get("algorithm")
    if not isinstance(algorithm, str) or canonical_algorithm(algorithm) == algorithm:
        return fingerprint
    return Fingerprint({**fingerprint.values, "algorithm": canonical_algorithm(algorithm)})


class Journal:
    """Append-only JSON lines: a fingerprint header, then one QueryRecord per line."""

    def __init__(
        self, path: Path, fingerprint: Fingerprint, records: Sequence[QueryRecord], finished: bool = False
    ) -> None:
        self.path = path
        self.fingerprint = fingerprint
        self._records = {record.query_id: record for record in records}
        self.finished = finished  # the search ended: nothing more will be journaled

    @staticmethod
    def open(path: Path, fingerprint: Fingerprint) -> Journal:
        """The journal at path for this attack: created if absent, refused if it belongs to another attack."""
        path = Path(path)
        if not path.exists():
            header = {"journal_version": JOURNAL_VERSION, "fingerprint": dict(fingerprint.values)}
            write_text_atomically(path, json.dumps(header) + "\n")
            return Journal(path, fingerprint, ())
        lines = path.read_bytes().split(b"\n")
        try:
            header = json.loads(lines[0])
            recorded = _renamed(Fingerprint(header["fingerprint"]))
        except (ValueError, KeyError, TypeError):
            raise JournalError(
                f"{path}: not an attack journal (unreadable header); use another output folder"
            ) from None
        different = recorded.differences(fingerprint)
        if different:
            details = ", ".join(
                f"{key}: {recorded.values.get(key)!r} there, {fingerprint.values.get(key)!r} now" for key in different
            )
            raise JournalError(
                f"{path.parent} holds another attack ({details}); use another output folder or the same settings"
            )
        records, kept, corrupt, finished = [], [lines[0]], [], False
        for number, line in enumerate(lines[1:], start=2):
            if not line.strip():
                continue
            try:
                values = json.loads(line)
                if values.get(_FINISHED_KEY):
                    finished = True
                else:
                    records.append(QueryRecord.from_json(values))
            except (ValueError, KeyError, TypeError, AttributeError):
                if number == len(lines):  # the last line, cut short by a kill while it was written: dropped
                    continue
                corrupt.append((number, line))  # damaged in place: kept aside, and said
                continue
            kept.append(line)
        clean = b"\n".join(kept) + b"\n"
        if corrupt:
            _set_aside(path, corrupt)
        if clean != path.read_bytes():  # rewrite without the torn tail or the damaged lines; the next append is clean
            write_text_atomically(path, clean.decode("utf-8"))
        return Journal(path, fingerprint, records, finished)

    @property
    def records(self) -> list[QueryRecord]:
        return [self._records[q] for q in sorted(self._records)]

    def __contains__(self, query_id: int) -> bool:
        return query_id in self._records

    def __len__(self) -> int:
        return len(self._records)

    def _write_line(self, values: Mapping[str, Any]) -> None:
        with self.path.open("a", encoding="utf-8") as stream:
            stream.write(json.dumps(values) + "\n")
            stream.flush()
            os.fsync(stream.fileno())

    def append(self, record: QueryRecord) -> None:
        """Record a finished query durably (fsync) before anything else relies on it; each query once."""
        if record.query_id in self._records:
            return
        self._write_line(record.as_json())
        self._records[record.query_id] = record

    def mark_finished(self) -> None:
        """The search is over: running the attack again only rewrites its outputs."""
        if not self.finished:
            self._write_line({_FINISHED_KEY: True, "queries": len(self._records)})
            self.finished = True


CORRUPT_SUFFIX = ".corrupt"  # queries.jsonl.corrupt: journal lines found damaged, as they were


def _set_aside(path: Path, corrupt: Sequence[tuple[int, bytes]]) -> None:
    """Keep damaged journal lines beside the journal and say so; their queries are evaluated again."""
    aside = path.with_name(path.name + CORRUPT_SUFFIX)
    with aside.open("ab") as stream:
        for _, line in corrupt:
            stream.write(line + b"\n")
        stream.flush()
        os.fsync(stream.fileno())
    numbers = ", ".join(str(number) for number, _ in corrupt)
    _log.warning(
        f"{path}: line(s) {numbers} damaged (not a query record); kept aside in {aside}, their queries run again"
    )


def read_records(path: Path) -> list[QueryRecord]:
    """The query records of a journal without checking its fingerprint (the search node replays them)."""
    path = Path(path)
    if not path.exists():
        return []
    records = []
    for line in path.read_text(encoding="utf-8").splitlines()[1:]:
        try:
            values = json.loads(line)
            if not values.get(_FINISHED_KEY):
                records.append(QueryRecord.from_json(values))
        except (ValueError, KeyError, TypeError, AttributeError):
            continue  # Journal.open has set damaged lines aside; a torn last line is not a query
    return records


def ranked_queries(values: Mapping[int, float], count: int) -> list[int]:
    """The ``count`` query ids of highest finite value, best first (ties: the earlier query)."""
    finite = [(value, query_id) for query_id, value in values.items() if math.isfinite(value)]
    finite.sort(key=lambda item: (-item[0], item[1]))
    return [query_id for _, query_id in finite[:count]]
