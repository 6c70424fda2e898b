"""Found failures as a regression suite, and `advsim regress`: replay every scenario on a stack, gate on it.

A campaign exports the adversarial scenario of every attack that counts as a failure into
OUTDIR/suite/NAME (a scenario bag each) with index.json naming them, the stack each was found
on, its recorded score and the failure rule. `regress` replays every scenario of a suite on a
stack (each replay one isolated graph, campaign.worker) and reports each as a JUnit test case:
failed when the replayed scenario still counts as a failure, an error when it could not be scored.
"""

from __future__ import annotations

import json
import math
import shutil
import xml.etree.ElementTree as ET
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NotRequired, TypedDict, cast

from advsim_ros.campaign.config import CampaignError, FailureRule
from advsim_ros.campaign.journal import AttackEntry
from advsim_ros.campaign.results import TransferRow
from advsim_ros.core.atomic import atomic_folder, write_json_atomically, write_text_atomically
from advsim_ros.core.attack_summary import FindingRecord, Score

INDEX_NAME = "index.json"


class FindingDigest(TypedDict):
    """What a suite's index (or a report) says of a finding."""

    reproduced: bool | None
    original_flaky: bool | None
    sim_dominated: bool | None
    fault: str | None  # its class: avoidable | unavoidable
    mover: str | None
    side: str | None


class SuiteScenario(TypedDict):
    """One scenario of a suite's index.json: a found failure, its bag (a folder beside the index) and its score."""

    name: str
    bag: str
    found_on: str  # the stack it was found on
    scenario: str
    window_start: int
    algorithm: str
    recorded: Score  # adversarial_loss, collision_3s, collision_5s of the recorded query
    finding: FindingDigest | None
    bag_params: NotRequired[Mapping[str, object]]  # the bag's layout (io.bag.bag_layout_json), if not the contract's


def export_suite(out_dir: Path, attacks: Sequence[AttackEntry], rule: FailureRule) -> Path:
    """Copy every failing attack's adversarial bag into out_dir/suite and (re)write its index; the suite folder."""
    suite = out_dir / "suite"
    suite.mkdir(parents=True, exist_ok=True)
    scenarios = []
    for entry in attacks:
        row, bag = entry["row"], entry.get("bag")
        if not bag or not rule.counts(entry):
            continue
        name = str(row["attack"])
        target = suite / name
        if not (target / "metadata.yaml").is_file():
            with atomic_folder(target, overwrite=True) as staged:
                shutil.copytree(bag, staged)
        recorded = entry.get("adversarial") or {}  # a counted failure has its score
        scenario: SuiteScenario = {
            "name": name, "bag": name, "found_on": row["stack"], "scenario": row["scenario"],
            "window_start": row["window_start"], "algorithm": row["algorithm"],
            "recorded": {k: recorded.get(k) for k in ("adversarial_loss", "collision_3s", "collision_5s")},
            "finding": finding_digest(entry.get("finding")),
        }  # fmt: skip
        layout = entry.get("bag_params")
        if layout:  # the bag's layout
            scenario["bag_params"] = layout
        scenarios.append(scenario)
    index = {
        "suite_version": 1,
        "failure": {"collision": rule.collision, "adversarial_loss_above": rule.adversarial_loss_above},
        "scenarios": sorted(scenarios, key=lambda s: s["name"]),
    }
    write_json_atomically(suite / INDEX_NAME, index)
    return suite


def finding_digest(finding: FindingRecord | None) -> FindingDigest | None:
    """What a suite (or a report) says of a finding: reproduced, controls, fault class and who moved into whom."""
    if not finding:
        return None
    fault = finding.get("fault")
    contact = fault.get("contact") if fault else None
    return {
        "reproduced": finding.get("reproduced"),
        "original_flaky": finding.get("original_flaky"),
        "sim_dominated": finding.get("sim_dominated"),
        "fault": fault.get("class") if fault else None,
        "mover": contact.get("mover") if contact else None,
        "side": contact.get("side") if contact else None,
    }


@dataclass(frozen=True)
class Verdict:
    name: str
    outcome: str  # passed | failed | error
    message: str
    score: Mapping[str, float | None]  # collision_5s, adversarial_loss of the replay
    seconds: float


def read_index(suite: Path) -> tuple[FailureRule, list[SuiteScenario]]:
    """The failure rule and scenarios of a suite; CampaignError when it is not one."""
    path = suite / INDEX_NAME
    try:
        index = json.loads(path.read_text(encoding="utf-8"))
        rule = FailureRule(bool(index["failure"]["collision"]), index["failure"]["adversarial_loss_above"])
        scenarios: list[SuiteScenario] = list(index["scenarios"])  # export_suite's (JSON keeps their types)
    except OSError:
        raise CampaignError(f"{suite}: not a regression suite (no {INDEX_NAME})") from None
    except (ValueError, KeyError, TypeError):
        raise CampaignError(f"{path}: not a valid suite index") from None
    for scenario in scenarios:
        if not (suite / scenario["bag"] / "metadata.yaml").is_file():
            raise CampaignError(f"{suite}: scenario {scenario['name']}: its bag {scenario['bag']} is missing")
    return rule, scenarios


def regress(
    suite: Path,
    stack_entry: Any,  # a config `stacks` entry (a name or a mapping; config.stack_spec reads it)
    out_dir: Path,
    plan_timeout: float = 10.0,
    progress: Callable[[Verdict], None] | None = None,
) -> list[Verdict]:
    """Replay every scenario of the suite on the stack; one verdict each."""
    from advsim_ros.campaign.schedule import run_job

    rule, scenarios = read_index(suite)
    verdicts = []
    for scenario in scenarios:
        relative = f"replays/{scenario['name']}"
        spec = {
            "kind": "transfer", "bag": str((suite / scenario["bag"]).resolve()), "stack_entry": stack_entry,
            "source": scenario["name"], "source_stack": scenario["found_on"], "target_stack": "regress",
            "out_dir": str(out_dir / relative), "relative_dir": relative, "config_dir": str(Path.cwd()),
            "plan_timeout": plan_timeout, "bag_params": scenario.get("bag_params"),
        }  # fmt: skip
        shutil.rmtree(out_dir / relative, ignore_errors=True)  # a regression run always replays anew
        outcome = run_job(spec)
        seconds = _seconds(out_dir / relative)
        if not outcome["ok"]:
            verdict = Verdict(scenario["name"], "error", outcome["error"], {}, seconds)
        else:
            row = cast(TransferRow, outcome["row"])  # a transfer job's
            score = {"collision_5s": row["collision_5s"], "adversarial_loss": row["adversarial_loss"]}
            if row["status"] != "ok":
                verdict = Verdict(
                    scenario["name"], "error", f"the replay was not scored ({row['status']})", score, seconds
                )
            elif rule.failed(score):
                message = f"collision up to 5 s: {bool(score['collision_5s'])}, L_adv {score['adversarial_loss']:.4g}"
                verdict = Verdict(scenario["name"], "failed", message, score, seconds)
            else:
                verdict = Verdict(scenario["name"], "passed", "", score, seconds)
        verdicts.append(verdict)
        if progress is not None:
            progress(verdict)
    return verdicts


def _seconds(replay_dir: Path) -> float:
    try:
        return float(json.loads((replay_dir / "summary.json").read_text(encoding="utf-8"))["wall_time_s"])
    except (OSError, ValueError, KeyError):
        return math.nan


def junit_xml(verdicts: Sequence[Verdict], suite_name: str) -> str:
    """JUnit XML (one testsuite, a testcase per scenario) for any CI to gate on."""
    failures = sum(1 for v in verdicts if v.outcome == "failed")
    errors = sum(1 for v in verdicts if v.outcome == "error")
    total = sum(v.seconds for v in verdicts if math.isfinite(v.seconds))
    root = ET.Element("testsuites", name="advsim regress", tests=str(len(verdicts)))
    node = ET.SubElement(
        root, "testsuite", name=suite_name, tests=str(len(verdicts)), failures=str(failures), errors=str(errors),
        time=f"{total:.3f}",
    )  # fmt: skip
    for verdict in verdicts:
        seconds = f"{verdict.seconds:.3f}" if math.isfinite(verdict.seconds) else "0"
        case = ET.SubElement(node, "testcase", classname=suite_name, name=verdict.name, time=seconds)
        if verdict.outcome in ("failed", "error"):
            tag = "failure" if verdict.outcome == "failed" else "error"
            ET.SubElement(case, tag, message=verdict.message).text = json.dumps(dict(verdict.score))
    ET.indent(root)
    return ET.tostring(root, encoding="unicode", xml_declaration=True) + "\n"


def write_junit(path: Path, verdicts: Sequence[Verdict], suite_name: str) -> None:
    write_text_atomically(path, junit_xml(verdicts, suite_name))
