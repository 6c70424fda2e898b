"""Running a campaign on Ray: every attack one Ray task (one isolated graph), journaled as it finishes.

`ray.init()` starts a Ray instance on this machine unless an address of a running cluster is
given. Each job is a Ray task that declares the CPU and memory it needs and runs the attack in a
process of its own (campaign.worker); at most ``workers`` jobs are in flight at once. After an
attack whose adversarial scenario counts as a failure, its scenario is replayed on every other
stack of the campaign (transfer, Table 3). Finished jobs go to the campaign journal at once, so
a killed driver loses nothing finished; the same command resumes. With a storage other than OUTDIR
(``storage:``, ``--storage``), a job's inputs and outputs travel through it (campaign.shipping), so that
no node needs to see the driver's folders.
"""

from __future__ import annotations

import logging
import math
import os
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from advsim_ros.attack.run import search_notes
from advsim_ros.campaign.config import AttackPlan, Campaign, CampaignError, expand, load_campaign, materialize
from advsim_ros.campaign.job import JobOutcome, Shipping, run_local_job
from advsim_ros.campaign.journal import JOURNAL_NAME, AttackEntry, CampaignJournal, attack_entry
from advsim_ros.campaign.results import TransferRow, failed_row, identity_of
from advsim_ros.campaign.shipping import bring_back, run_shipped_job, ship_job
from advsim_ros.campaign.storage import Storage, storage_uri
from advsim_ros.campaign.worker import JobSpec
from advsim_ros.io.bag import BagConfig
from advsim_ros.ros.launcher import start_reaper
from advsim_ros.ros.reaper import descendants, start_time

ATTACK_CPUS = 1.0  # Ray resources an attack asks for: its graph is mostly one busy process at a time
# [bytes]: a KITTI attack's processes peak at 2.2 GB RSS summed while its graph builds the re-simulation model,
# 1.7 GB with the model cached (bench/bench_attack.py: graph and orchestrator, cold and warm)
ATTACK_MEMORY = int(2.5 * 1024**3)


@dataclass(frozen=True)
class Job:
    """One unit of work: an attack, or the replay of an attack's found scenario on another stack."""

    name: str  # journal key: attack/KEY or transfer/KEY/TARGET
    spec: JobSpec  # the worker's JOB.json


def run_job(spec: JobSpec) -> JobOutcome:
    """Body of the Ray task: the worker process for one job, tied to this one; its result or its error."""
    if "storage" in spec:  # its inputs and outputs in the storage: fetched here, the job run here, sent back
        return run_shipped_job(spec)
    return run_local_job(spec)


def _attack_job(plan: AttackPlan, out_dir: Path, config_dir: Path) -> Job:
    relative = f"attacks/{plan.key}"
    spec = {
        "kind": "attack", "plan": plan.as_json(), "out_dir": str(out_dir / relative), "relative_dir": relative,
        "config_dir": str(config_dir),
    }  # fmt: skip
    return Job(f"attack/{plan.key}", spec)


def _transfer_jobs(campaign: Campaign, entry: AttackEntry, out_dir: Path) -> Iterator[Job]:
    """Replays of a found failure on every other stack of the campaign."""
    row = entry["row"]
    if not campaign.transfer or not entry.get("bag") or not campaign.failure.counts(entry):
        return
    for target, stack_entry in campaign.stacks.items():
        if target == row["stack"]:
            continue
        relative = f"transfer/{row['attack']}--on--{target}"
        spec = {
            "kind": "transfer", "bag": entry["bag"], "stack_entry": stack_entry, "source": row["attack"],
            "source_stack": row["stack"], "target_stack": target, "out_dir": str(out_dir / relative),
            "relative_dir": relative, "config_dir": str(campaign.path.parent), "plan_timeout": campaign.plan_timeout,
            "parameters": campaign.parameters, "bag_params": entry.get("bag_params"),
        }  # fmt: skip
        yield Job(f"transfer/{row['attack']}/{target}", spec)


def _start_ray(workers: int, address: str | None, out_dir: Path) -> Callable[[], None]:
    """Ray for this campaign; returns what ties a local Ray's processes to this one (call it now and then).

    Ray's own processes of a local instance share this process's group, and some (its agents) outlive
    a killed driver for minutes: a reaper (ros.reaper) is told each of them and kills them when this
    process is gone, however it ended.
    """
    import ray

    if address:
        ray.init(address=address, logging_level=logging.WARNING, log_to_driver=False)
        return lambda: None
    ray.init(address="local", num_cpus=workers, include_dashboard=False, logging_level=logging.WARNING,
             log_to_driver=False)  # fmt: skip
    reaper = start_reaper(out_dir / "ray_reaper.log", os.environ)
    assert reaper.stdin is not None
    tell, told = reaper.stdin, set()

    def tie() -> None:
        for pid in descendants(os.getpid()):
            started = start_time(pid)
            if pid != reaper.pid and started is not None and (pid, started) not in told:
                told.add((pid, started))
                tell.write(f"pid {pid} {started}\n".encode())
        tell.flush()

    tie()
    return tie


def _attack_memory() -> int:
    """Memory an attack asks Ray for: ATTACK_MEMORY, or what the largest node has if that is less.

    A local Ray offers the memory that was free when it started; asking for more than any node has
    would leave every attack pending forever, so on a small machine attacks run one at a time.
    """
    import ray

    nodes = ray.nodes()  # type: ignore[no-untyped-call]
    largest = max((node["Resources"].get("memory", 0.0) for node in nodes if node["Alive"]), default=0.0)
    if largest >= ATTACK_MEMORY:
        return ATTACK_MEMORY
    print(
        f"advsim campaign: no Ray node has the {ATTACK_MEMORY / 1024**3:.1f} GiB an attack may use "
        f"(largest: {largest / 1024**3:.1f} GiB free); attacks ask for that much and may be killed short of memory",
        file=sys.stderr,
    )
    return max(int(largest), 1)


def campaign_search_notes(plans: list[AttackPlan], out_dir: Path, config_dir: Path) -> list[str]:
    """What the search settings of these attacks warn about (search_notes), once per algorithm and budget."""
    budgets = {(plan.algorithm, plan.budget): plan for plan in plans}
    return [
        f"algorithms {{{plan.algorithm}: {plan.budget}}}: {text}"
        for plan in budgets.values()
        for text in search_notes(plan.options(out_dir, config_dir))
    ]


def run_campaign(
    config: Path,
    out_dir: Path,
    workers: int = 1,
    address: str | None = None,
    progress: Callable[[dict[str, int]], None] | None = None,
    note: Callable[[str], None] | None = None,
    bag_config: BagConfig | None = None,
    storage: str | None = None,
) -> CampaignJournal:
    """Run (or resume) every job of the campaign; returns its journal. A bad config starts nothing.

    ``note`` gets what the search settings warn about (search_notes), once per algorithm and budget;
    ``bag_config`` (--bag-params) is the layout of the bags whose entries name none (config.load_campaign);
    ``storage`` (--storage) is where jobs meet when it is not OUTDIR, else the config's ``storage:``.
    """
    campaign = load_campaign(config, bag_config)
    uri = storage_uri(config, storage)
    if workers < 1:
        raise CampaignError(f"--workers: must be at least 1, got {workers}")
    out_dir = out_dir.resolve()
    shipped = Storage(uri) if uri is not None else None
    if shipped is not None and shipped.local_root is not None and shipped.local_root.resolve() == out_dir:
        shipped = None  # OUTDIR itself: every job works in its folder there, as on one machine
    if (out_dir / JOURNAL_NAME).exists():  # another campaign's folder is refused before anything is written
        CampaignJournal.open(out_dir, campaign.digest, campaign.path)
    campaign = materialize(campaign, out_dir / "logs")
    plans = expand(campaign)  # every window checked against its log
    if note is not None:
        for text in campaign_search_notes(plans, out_dir, campaign.path.parent):
            note(text)
    journal = CampaignJournal.open(out_dir, campaign.digest, campaign.path)
    todo = [_attack_job(p, out_dir, campaign.path.parent) for p in plans if f"attack/{p.key}" not in journal]
    for entry in journal.of_kind("attack"):
        todo.extend(job for job in _transfer_jobs(campaign, entry, out_dir) if job.name not in journal)
    total_attacks = len(plans)
    finished = journal.of_kind("attack")
    replays = sum(1 for job in todo if job.spec["kind"] == "transfer")
    state = {"attacks": total_attacks, "done": len(finished), "errors": 0, "replays": replays, "replayed": 0}
    state["failures"] = sum(1 for e in finished if campaign.failure.counts(e))
    if progress is not None:
        progress(dict(state))
    if not todo:
        return journal
    tie_local_ray = _start_ray(workers, address, out_dir)
    import ray

    task = ray.remote(run_job).options(num_cpus=ATTACK_CPUS, memory=_attack_memory(), max_retries=0)
    uploaded: dict[Path, dict[str, str]] = {}  # inputs in the storage: path -> reference
    sending: dict[str, Shipping] = {}  # what shipping each job in flight cost the driver
    try:
        in_flight: dict[Any, Job] = {}  # by Ray's ObjectRef (Ray is untyped here)
        while todo or in_flight:
            while todo and len(in_flight) < workers:
                job = todo.pop(0)
                spec = job.spec
                if shipped is not None:
                    sent, started = shipped.sent, time.monotonic()
                    spec = ship_job(spec, shipped, out_dir, campaign.path.parent, uploaded)
                    sending[job.name] = {"uploaded_bytes": shipped.sent - sent, "upload_s": time.monotonic() - started}
                in_flight[task.remote(spec)] = job
            tie_local_ray()  # Ray starts worker processes as tasks come
            ready, _ = ray.wait(list(in_flight), num_returns=1)
            job = in_flight.pop(ready[0])
            try:
                outcome: JobOutcome = ray.get(ready[0])  # run_job's
            except ray.exceptions.RayError as error:  # its worker died (Ray's memory monitor, a crash): one job lost
                outcome = {"ok": False, "error": f"Ray: {type(error).__name__}: {str(error).splitlines()[0]}"}
            if shipped is not None:
                outcome = bring_back(shipped, job.spec, outcome, out_dir, sending.pop(job.name))
            journal.append(job.name, _journal_entry(job, outcome))
            if job.spec["kind"] == "attack":
                state["done" if outcome["ok"] else "errors"] += 1
                entry = attack_entry(journal.entries[job.name])
                if campaign.failure.counts(entry):
                    state["failures"] += 1
                transfers = list(_transfer_jobs(campaign, entry, out_dir))
                todo.extend(transfers)
                state["replays"] += len(transfers)
            else:
                state["replayed"] += 1
            if progress is not None:
                progress(dict(state))
    finally:
        ray.shutdown()
    return journal


def _journal_entry(job: Job, outcome: JobOutcome) -> dict[str, object]:
    """What the journal keeps of a job (its entry less its key); a job that failed keeps its error (and is tried
    again on resume)."""
    if outcome["ok"]:
        return {k: v for k, v in outcome.items() if k != "ok"}
    spec = job.spec
    if spec["kind"] == "attack":
        plan = AttackPlan.from_json(spec["plan"])
        row = failed_row(identity_of(plan), outcome["error"], spec["relative_dir"])
        return {"row": row, "curve": [], "error": outcome["error"]}
    replayed: TransferRow = {
        "attack": spec["source"], "source_stack": spec["source_stack"], "target_stack": spec["target_stack"],
        "collision_5s": math.nan, "adversarial_loss": math.nan, "status": "failed", "out_dir": spec["relative_dir"],
    }  # fmt: skip
    return {"row": replayed, "error": outcome["error"]}
