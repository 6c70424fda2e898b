"""One campaign job run on this machine: the worker process (campaign.worker) with its own log, tied to this one.

schedule.run_job runs it for a job whose paths are the driver's; campaign.shipping for a shipped job, in a
scratch folder of the node its inputs were fetched to. A job with OUT/job_result.json is finished and is
not run again.
"""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Mapping
from pathlib import Path
from typing import Required, TypedDict, cast

from advsim_ros.campaign.results import ResultsRow, TransferRow
from advsim_ros.campaign.worker import RESULT_NAME, JobSpec
from advsim_ros.core.atomic import write_json_atomically
from advsim_ros.core.attack_summary import FindingRecord, Score
from advsim_ros.ros.launcher import die_with_parent


class RanOn(TypedDict):
    """Where and when a shipped job ran: its host, its Ray node (None outside a Ray task), wall-clock times [s]."""

    host: str
    ray_node: str | None
    started_at: float
    ended_at: float


class Shipping(TypedDict, total=False):
    """What moving a shipped job cost: bytes and seconds of the driver's uploads, the node's fetches and uploads
    (and the journal streamed meanwhile), and the driver's download; where the job ran."""

    uploaded_bytes: float
    upload_s: float
    fetched_bytes: float
    sent_bytes: float
    fetch_s: float
    send_s: float
    streamed_bytes: float
    returned_bytes: float
    return_s: float
    ran: RanOn


class JobOutcome(TypedDict, total=False):
    """What running a job gives the driver (through Ray): ok and its result (worker.JobResult's keys), or its
    error; shipped jobs add what moving them cost. Less ok, it is the job's journal entry."""

    ok: Required[bool]
    error: str  # not ok: one line, naming the job's log
    row: ResultsRow | TransferRow  # by the job's kind
    curve: list[float]
    adversarial: Score | None
    bag: str | None
    finding: FindingRecord | None
    bag_params: Mapping[str, object]
    shipping: Shipping


def finished(result: Mapping[str, object]) -> JobOutcome:
    """The outcome of a finished job from its job_result.json (a worker.JobResult as JSON, which keeps its types)."""
    return cast(JobOutcome, {"ok": True, **result})


def run_local_job(spec: JobSpec) -> JobOutcome:
    """The worker process for one job whose paths are this machine's, tied to this one; its result or its error."""
    out_dir = Path(spec["out_dir"])
    result_file = out_dir / RESULT_NAME
    if result_file.is_file():  # finished before the driver could journal it
        return finished(json.loads(result_file.read_text(encoding="utf-8")))
    out_dir.mkdir(parents=True, exist_ok=True)
    job_file = out_dir / "job.json"
    write_json_atomically(job_file, spec)
    with (out_dir / "job.log").open("ab") as log:
        log.write(f"advsim campaign: {spec['kind']} job started in {out_dir}\n".encode())
        log.flush()
        completed = subprocess.run(
            die_with_parent([sys.executable, "-m", "advsim_ros.campaign.worker", str(job_file)]),
            stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT, check=False,
        )  # fmt: skip
    if completed.returncode == 0 and result_file.is_file():
        return finished(json.loads(result_file.read_text(encoding="utf-8")))
    lines = (out_dir / "job.log").read_text(encoding="utf-8", errors="replace").strip().splitlines()
    reason = next((line for line in reversed(lines) if line.strip()), f"exit status {completed.returncode}")
    return {"ok": False, "error": f"{reason} (log: {out_dir / 'job.log'})"}
