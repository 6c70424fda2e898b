"""What an attack's outputs say, gathered once for drawing: the adversarial bag, summary.json, the original window.

Inputs are explicit: the adversarial scenario bag (OUTDIR/adversarial) and the summary (a dict
or the path of summary.json). The original window comes from the source bag the summary names
and the stack's original plan from the journal it names (OUTDIR/queries.jsonl); either may be
gone (a copied OUTDIR), and then the original side is drawn without it.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import cast

import numpy as np

from advsim_ros.contract import names, topics
from advsim_ros.contract.plan import plan_from_path
from advsim_ros.contract.protocol import perturbation_from_msg
from advsim_ros.core.attack_summary import AttackSummary
from advsim_ros.core.episode import WindowConfig
from advsim_ros.core.journal import QueryRecord, read_records
from advsim_ros.core.metrics import MetricsConfig
from advsim_ros.core.types import ActorTrack, FloatArray, Plan, Scenario, ScenarioError
from advsim_ros.io.bag import BagConfig, BagReader, bag_layout_of, read_scenario_bag
from advsim_ros.viz.markers import first_collision_ns


def load_summary(summary: AttackSummary | Path) -> AttackSummary:
    """The summary: given, or read from summary.json (ScenarioError naming the file when unreadable)."""
    if not isinstance(summary, str | Path):
        return summary.copy()
    try:
        loaded = json.loads(Path(summary).read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as error:
        raise ScenarioError(f"cannot read the attack summary {summary}: {error}") from None
    if not isinstance(loaded, dict) or "scenario" not in loaded:
        raise ScenarioError(f"{summary} is not an attack's summary.json (no 'scenario' key)")
    return cast(AttackSummary, loaded)  # attack.outputs wrote it from an AttackSummary; JSON keeps the types


def bag_plan(bag: Path) -> Plan | None:
    """The stack's plan recorded in an adversarial bag (/planning/trajectory), None when it has none."""
    with BagReader(bag) as reader:
        connection = reader.connection(topics.PLAN.name, names.PATH)
        if connection is None:
            return None
        for _, _, path in reader.messages([connection]):
            return plan_from_path(path)
    return None


def bag_perturbed_ids(bag: Path) -> tuple[str, ...]:
    """The perturbed actors named by an adversarial bag's /advsim/perturbation (empty when it has none)."""
    with BagReader(bag) as reader:
        connection = reader.connection(topics.PERTURBATION.name, names.PERTURBATION)
        if connection is None:
            return ()
        for _, _, value in reader.messages([connection]):
            return tuple(perturbation_from_msg(value).actor_ids)
    return ()


@dataclass(frozen=True, eq=False)
class AttackView:
    """One attack's outcome, original vs adversarial, over the attacked window (log time)."""

    summary: AttackSummary
    bag: Path  # the adversarial scenario bag
    adversarial: Scenario  # the adversarial bag: the window, perturbed actors, the LiDAR the stack saw
    original: Scenario | None  # the same window of the source bag (logged actors and LiDAR); None when it is gone
    perturbed_ids: tuple[str, ...]
    adversarial_plan: Plan | None  # the stack's plan of the decision frame in the recorded query
    original_plan: Plan | None  # the stack's plan of the decision frame on the original log (query 0)
    decision_index: int  # frame of the window the stack planned from (its last LiDAR sweep)
    adversarial_collision_ns: int | None  # log time of the first collision of the SDV on its plan [ns]
    original_collision_ns: int | None
    # closed loop: what the ego drove ((K, 2) [m]) and the drives of reactive actors, in each query
    adversarial_driven: FloatArray | None = None
    original_driven: FloatArray | None = None
    adversarial_reacted: tuple[ActorTrack, ...] = ()
    original_reacted: tuple[ActorTrack, ...] = ()

    @property
    def decision_ns(self) -> int:
        return int(self.adversarial.frame_stamps_ns[self.decision_index])


def load_attack_view(
    bag: Path,
    summary: AttackSummary | Path,
    bag_config: BagConfig | None = None,
    original: Scenario | None = None,
    written: tuple[Scenario, Plan | None] | None = None,
) -> AttackView:
    """Read an attack's outputs: the adversarial bag and its summary (dict or summary.json path).

    Both bags are read in ``bag_config``'s layout (--bag-params), else in the one the summary recorded
    (the attack wrote adversarial/ in its source bag's layout), else in the contract's. ``original``: the
    attacked window of the source log, when the caller has it (else read from the source bag). ``written``:
    the adversarial scenario and plan the caller has just written to ``bag`` (else read from it)."""
    values = load_summary(summary)
    bag = Path(bag)
    scenario = values["scenario"]
    layout = bag_config or bag_layout_of(scenario.get("bag_params"), "summary.json scenario.bag_params")
    adversarial = written[0] if written else read_scenario_bag(bag, config=layout, load_sweeps=True)
    window = WindowConfig(
        window_start_frame=int(scenario["window_start_frame"]),
        history_frames=int(scenario["history_frames"]),
        future_frames=int(scenario["future_frames"]),
    )
    if adversarial.num_frames != window.num_frames:
        raise ScenarioError(
            f"{bag} has {adversarial.num_frames} frames but the summary's window has {window.num_frames}: "
            "not the adversarial bag of this summary"
        )
    perturbed = tuple(values.get("perturbed_actors") or ()) or bag_perturbed_ids(bag)
    if original is None or not np.array_equal(original.frame_stamps_ns, adversarial.frame_stamps_ns):
        original = _original_window(Path(scenario["bag"]), window, adversarial, layout)
    first, shown = _journaled_queries(values)
    original_plan = first.plan if first else None
    adversarial_plan = written[1] if written else bag_plan(bag)
    decision = window.decision_index
    config = MetricsConfig()
    return AttackView(
        summary=values,
        bag=bag,
        adversarial=adversarial,
        original=original,
        perturbed_ids=perturbed,
        adversarial_plan=adversarial_plan,
        original_plan=original_plan,
        decision_index=decision,
        adversarial_collision_ns=(
            first_collision_ns(adversarial, adversarial_plan, decision, config) if adversarial_plan else None
        ),
        original_collision_ns=(
            first_collision_ns(original, original_plan, decision, config) if original and original_plan else None
        ),
        adversarial_driven=shown.executed.xy if shown and shown.executed else None,
        original_driven=first.executed.xy if first and first.executed else None,
        adversarial_reacted=shown.reacted if shown else (),
        original_reacted=first.reacted if first else (),
    )


def _original_window(
    source: Path, window: WindowConfig, adversarial: Scenario, layout: BagConfig | None
) -> Scenario | None:
    """The attacked window of the source bag, when it is still there and is the same log."""
    if not (source / "metadata.yaml").is_file():
        return None
    log = read_scenario_bag(source, config=layout, load_sweeps=True)
    cropped = window.crop(log)
    if not np.array_equal(cropped.frame_stamps_ns, adversarial.frame_stamps_ns):
        return None  # the source bag was replaced by another log
    return cropped


def _journaled_queries(summary: AttackSummary) -> tuple[QueryRecord | None, QueryRecord | None]:
    """Query 0 and the query the adversarial side shows (the recorded one; a replay's last run) from the
    journal the summary names; None for each the journal lacks or when it is gone."""
    journal = Path(summary.get("outputs", {}).get("journal", ""))
    if not journal.is_file():
        return None, None
    records = read_records(journal)
    by_id = {record.query_id: record for record in records}
    if "replay" in summary:
        return by_id.get(0), records[-1] if records else None
    recorded = summary.get("recorded_query_id")
    return by_id.get(0), by_id.get(recorded) if isinstance(recorded, int) else None


def number(value: object, digits: int = 3) -> str:
    """A summary value for people: 'n/a' for missing or NaN, else `digits` significant figures."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "n/a"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, int | float):
        return f"{value:.{digits}g}"
    return str(value)
