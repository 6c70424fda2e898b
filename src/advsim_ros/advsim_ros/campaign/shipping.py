"""Jobs whose worker may see none of the driver's folders: inputs and outputs travel through the storage.

On the driver (``ship_job``), every driver path a job names is replaced by a reference into the
campaign's storage (campaign.storage): the scenario bag and the stack's parameter files from the
config's folder become inputs uploaded once and keyed by their content digest; a transfer's
adversarial bag is the stored output folder of the attack that found it. On the node
(``run_shipped_job``, the body of the job's Ray task), a job whose job_result.json is in the
storage has finished and is not run again; otherwise its inputs are fetched into the node's cache,
the job runs exactly as on one machine (job.run_local_job) in a scratch folder of the node, and
every output it wrote goes to the storage, job_result.json last. Back on the driver
(``bring_back``), the job's folder is downloaded into OUTDIR: the campaign journal, the report and
the regression suite are built from there as on one machine.

While an attack runs, its journal (queries.jsonl) is streamed to the storage as its queries finish
(every STREAM_S, complete lines only, one whole object each time). A job tried again, on this node or
another (its node was lost, or it failed), starts from the journal its last try left in the storage: the
attack resumes, and no finished query is computed again (its fingerprint names the bag by content, not by
the path it has in a node's cache). Its outputs replace those of the try before, whose log goes on in job.log.
"""

from __future__ import annotations

import shutil
import socket
import tempfile
import threading
import time
from pathlib import Path

from advsim_ros.campaign.job import JobOutcome, RanOn, Shipping, finished, run_local_job
from advsim_ros.campaign.storage import Storage
from advsim_ros.campaign.worker import RESULT_NAME, JobSpec
from advsim_ros.core.atomic import atomic_folder

LOG_NAME = "job.log"
ATTACK_JOURNAL = "queries.jsonl"  # attack.run.JOURNAL_NAME
STREAM_S = 2.0  # [s] how often a running attack's journal goes to the storage when it grew


class _Streamer(threading.Thread):
    """Sends a journal's complete lines to the storage every STREAM_S when they changed (the job's end sends all)."""

    def __init__(self, uri: str, source: Path, key: str) -> None:
        super().__init__(name="advsim-journal-streamer", daemon=True)
        self.storage = Storage(uri)  # its own: its byte counts are the streaming's
        self.source, self.key = source, key
        self.last = source.read_bytes() if source.exists() else b""  # what the storage holds
        self._done = threading.Event()

    def push(self) -> None:
        try:
            data = self.source.read_bytes()
        except OSError:  # not there yet
            return
        data = data[: data.rfind(b"\n") + 1]
        if data != self.last:
            self.storage.write_bytes(self.key, data)
            self.last = data

    def run(self) -> None:
        while not self._done.wait(STREAM_S):
            try:
                self.push()
            except Exception as error:
                print(f"advsim campaign: journal not streamed ({type(error).__name__}: {error})", flush=True)

    def stop(self) -> None:
        self._done.set()
        self.join()


def _params(entry: object) -> list[str]:
    """The parameter files a `stacks` entry names (relative to the config's folder, or absolute)."""
    return [str(p) for p in entry.get("params") or ()] if isinstance(entry, dict) else []


def ship_job(spec: JobSpec, storage: Storage, out_dir: Path, config_dir: Path,
             uploaded: dict[Path, dict[str, str]]) -> JobSpec:  # fmt: skip
    """The job's spec with its inputs in the storage instead of driver paths (uploaded: each path's reference)."""

    def put(path: Path) -> dict[str, str]:
        if path not in uploaded:
            uploaded[path] = storage.put_input(path)
        return uploaded[path]

    shipped = {k: v for k, v in spec.items() if k not in ("out_dir", "config_dir", "bag")}
    if spec["kind"] == "attack":
        bag, entry = put(Path(spec["plan"]["bag"])), spec["plan"]["stack_entry"]
    else:
        found, entry = Path(spec["bag"]), spec["stack_entry"]
        key = found.relative_to(out_dir).as_posix() if found.is_relative_to(out_dir) else None
        bag = {"key": key} if key and storage.exists(f"{key}/metadata.yaml") else put(found)
    params = [put((config_dir / p).resolve()) for p in _params(entry)]
    return {**shipped, "storage": storage.uri, "inputs": {"bag": bag, "params": params}}


def run_shipped_job(spec: JobSpec) -> JobOutcome:
    """Body of the Ray task of a shipped job: its result (from the storage when it finished before) or its error."""
    storage = Storage(spec["storage"])
    relative = spec["relative_dir"]
    if storage.exists(f"{relative}/{RESULT_NAME}"):  # finished before the driver could journal it
        return finished(storage.read_json(f"{relative}/{RESULT_NAME}"))
    started, began = time.monotonic(), time.time()
    scratch = Path(tempfile.mkdtemp(prefix="advsim-job-"))
    try:
        out_dir = scratch / relative
        inputs = spec["inputs"]
        if "key" in inputs["bag"]:  # an attack's adversarial bag: this job's alone, not cached
            bag = scratch / "inputs" / Path(inputs["bag"]["key"]).name
            storage.get_tree(inputs["bag"]["key"], bag)
        else:
            bag = storage.fetch_input(inputs["bag"])
        params = [str(storage.fetch_input(reference)) for reference in inputs["params"]]
        if storage.exists(f"{relative}/{LOG_NAME}"):  # the log of earlier tries goes on
            storage.get_file(f"{relative}/{LOG_NAME}", out_dir / LOG_NAME)
        streamer = None
        if spec["kind"] == "attack":  # the journal an earlier try left (streamed, or sent at its end): resumed
            if storage.exists(f"{relative}/{ATTACK_JOURNAL}"):
                storage.get_file(f"{relative}/{ATTACK_JOURNAL}", out_dir / ATTACK_JOURNAL)
            streamer = _Streamer(storage.uri, out_dir / ATTACK_JOURNAL, f"{relative}/{ATTACK_JOURNAL}")
            streamer.start()
        local = {k: v for k, v in spec.items() if k not in ("storage", "inputs")}
        local.update(out_dir=str(out_dir), config_dir=str(scratch))
        entry = spec["plan"]["stack_entry"] if spec["kind"] == "attack" else spec["stack_entry"]
        entry = {**entry, "params": params} if params else entry
        if spec["kind"] == "attack":  # the plan keeps the driver's bag: it is the attack's identity (results.csv)
            local["local"] = {"bag": str(bag), "stack_entry": entry}
        else:
            local.update(bag=str(bag), stack_entry=entry)
        fetched, fetch_s = storage.received, time.monotonic() - started
        try:
            outcome = run_local_job(local)
        finally:
            if streamer is not None:
                streamer.stop()
        started = time.monotonic()
        storage.remove(relative)  # what an earlier try left there (its log goes on in this one's)
        storage.put_tree(out_dir, relative, skip=(RESULT_NAME,))
        if outcome["ok"]:
            result = {k: v for k, v in outcome.items() if k != "ok"}  # worker.JobResult, its keys in their order
            if result.get("bag"):  # relative to the job's folder: bring_back puts it in OUTDIR
                result["bag"] = Path(str(result["bag"])).relative_to(out_dir).as_posix()
            storage.write_json(f"{relative}/{RESULT_NAME}", result)  # last: the job has finished
            outcome = finished(result)
        else:
            outcome["error"] = str(outcome["error"]).replace(str(out_dir), f"{storage.uri.rstrip('/')}/{relative}")
        outcome["shipping"] = {
            "fetched_bytes": fetched, "sent_bytes": storage.sent, "fetch_s": fetch_s,
            "send_s": time.monotonic() - started, "ran": _where(began),
            "streamed_bytes": streamer.storage.sent if streamer is not None else 0,
        }  # fmt: skip
        return outcome
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


def _where(began: float) -> RanOn:
    """Where and when a job ran: its host, its Ray node (when in a Ray task), wall-clock start and end [s]."""
    import ray

    node = ray.get_runtime_context().get_node_id() if ray.is_initialized() else None
    return {"host": socket.gethostname(), "ray_node": node, "started_at": began, "ended_at": time.time()}


def bring_back(storage: Storage, spec: JobSpec, outcome: JobOutcome, out_dir: Path, sending: Shipping) -> JobOutcome:
    """Download a shipped job's folder into OUTDIR; its outcome with the bag and the log named there, and what
    shipping it cost (sending: the driver's uploads for it; the node's fetches and uploads; this download)."""
    relative = spec["relative_dir"]
    started, received = time.monotonic(), storage.received
    if storage.exists(relative):  # nothing when its Ray worker died before it uploaded anything
        with atomic_folder(out_dir / relative, overwrite=True) as staged:
            storage.get_tree(relative, staged)
    outcome = outcome.copy()
    if outcome.get("bag"):
        outcome["bag"] = str(out_dir / relative / str(outcome["bag"]))
    if "error" in outcome:
        outcome["error"] = str(outcome["error"]).replace(
            f"{storage.uri.rstrip('/')}/{relative}", str(out_dir / relative)
        )
    shipping: Shipping = {**sending, **outcome.get("shipping", {})}
    shipping["returned_bytes"] = storage.received - received
    shipping["return_s"] = time.monotonic() - started
    return {**outcome, "shipping": shipping}
