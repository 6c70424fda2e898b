"""A campaign on a Ray cluster whose worker node sees none of the driver's folders: they meet in an S3 server.

Two Ray nodes on this machine, one CPU each: the head (started by this process) and a worker node
whose `ray start --address HEAD` runs in a mount namespace of its own (`unshare --mount`), with a
tmpfs mounted over pytest's whole temporary folder, so the driver's OUTDIR, its config and the
scenario bag do not exist there; the node's temporary folder and cache lie in that tmpfs, its own.
Only the ROS-domain locks of this machine are shared with it (bound into its temporary folder), as
two graphs on one machine must not take the same domain. The storage is moto's S3 server on
loopback. With two attacks in flight at once, one runs on each node.

One campaign of 4 attacks (campaign_runs) serves every test: once the worker node has finished an attack
and a second attack there has streamed two finished queries to the storage, every process of the node
is killed (SIGKILL); the campaign goes on on the head, the lost attack fails, and the same command run
again resumes it on the head from its streamed journal. It must report what the same campaign reports
run whole on one node (conftest.uninterrupted_campaign), with no finished query computed again; an
attack ran to its end on the worker node, and two attacks ran at the same time on the two nodes
without hearing each other (DDS on loopback, each graph its own domain: no query of theirs saw a
publisher of another graph).
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from attack_runs import alive
from campaign_runs import campaign_argv, campaign_config, result_rows

from advsim_ros.io.cache import cache_root
from advsim_ros.ros.launcher import wait_for

HIDE_AND_JOIN = """
mount -t tmpfs advsim-node "$HIDDEN" && mkdir -p "$NODE/tmp/advsim_ros_domains" "$NODE/cache/resim" &&
mount --bind "$DOMAINS" "$NODE/tmp/advsim_ros_domains" && mount --bind "$RESIM" "$NODE/cache/resim" &&
exec "$RAY" start --address "$HEAD" --num-cpus 1 --block --disable-usage-stats
"""


def _namespace_of(pid: int) -> str | None:
    try:
        return os.readlink(f"/proc/{pid}/ns/mnt")
    except OSError:
        return None


def _in_namespace(namespace: str) -> list[int]:
    """Live processes of a mount namespace."""
    return [int(e) for e in os.listdir("/proc") if e.isdigit() and _namespace_of(int(e)) == namespace]


def _visible_on_node(pid: int, path: Path) -> bool:
    """Whether a path exists in the mount namespace of the process."""
    return (
        subprocess.run(["nsenter", "--target", str(pid), "--mount", "test", "-e", str(path)], check=False).returncode
        == 0
    )


@pytest.fixture(scope="module")
def cluster(
    s3_server: dict[str, str], uninterrupted_campaign: Path, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[dict[str, Any]]:
    """The head node (this process's, 1 CPU) and the worker node in its own mount namespace (1 CPU).

    The worker node's cache is its own, but for the re-simulation models: this machine's folder of them
    (where uninterrupted_campaign built the log's) is bound into it, as a cache folder several nodes mount
    (docs/campaign.md), so that both nodes attack at the same pace and the worker node gets several attacks.
    """
    from ray.cluster_utils import Cluster

    if subprocess.run(["unshare", "--mount", "true"], check=False, capture_output=True).returncode != 0:
        pytest.skip("unshare --mount is not allowed here: no node can be kept from the driver's folders")
    hidden = tmp_path_factory.getbasetemp()  # every folder the tests made: the driver's, the bag's
    node = hidden / "worker-node"  # exists only in the worker node's namespace
    domains, models = Path(tempfile.gettempdir()) / "advsim_ros_domains", cache_root() / "resim"
    if models.is_relative_to(hidden):
        pytest.skip(f"the models' cache {models} lies in pytest's temporary folder, which the worker node must not see")
    for folder in (domains, models):
        folder.mkdir(parents=True, exist_ok=True)
    head = Cluster(initialize_head=True, head_node_args={"num_cpus": 1})
    env = {
        **os.environ, **s3_server, "HIDDEN": str(hidden), "NODE": str(node), "HEAD": head.address,
        "DOMAINS": str(domains), "RESIM": str(models), "RAY": str(Path(sys.executable).parent / "ray"),
        "TMPDIR": str(node / "tmp"), "ADVSIM_CACHE_DIR": str(node / "cache"), "RAY_TMPDIR": "/tmp",
    }  # fmt: skip
    log = tmp_path_factory.mktemp("worker_node") / "ray_start.log"  # opened here: written from the node's side
    with log.open("wb") as output:
        worker = subprocess.Popen(
            ["unshare", "--mount", "--propagation", "private", "sh", "-c", HIDE_AND_JOIN],
            env=env, stdin=subprocess.DEVNULL, stdout=output, stderr=subprocess.STDOUT, start_new_session=True,
        )  # fmt: skip
    namespace = None
    try:
        assert wait_for(lambda: _namespace_of(worker.pid) != _namespace_of(os.getpid()), timeout=30)
        namespace = _namespace_of(worker.pid)
        import ray

        ray.init(address=head.address)
        try:
            nodes = ray.nodes  # type: ignore[no-untyped-call]
            wait_for(lambda: len([n for n in nodes() if n["Alive"]]) == 2 or worker.poll() is not None, 120)
            assert len([n for n in nodes() if n["Alive"]]) == 2, log.read_text(errors="replace")[-3000:]
        finally:
            ray.shutdown()
        yield {"address": head.address, "worker_pid": worker.pid, "node": node, "namespace": namespace}
    finally:
        left = _in_namespace(namespace) if namespace else []
        for pid in left:  # the node's ray start, raylet, Ray workers and whatever they started: all of the node
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        worker.wait(timeout=30)
        head.shutdown()
        assert wait_for(lambda: not [pid for pid in left if alive(pid)], timeout=30)


@pytest.fixture(scope="module")
def shipped(cluster: dict[str, Any], synthetic_bag: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """The campaign on the two nodes through the S3 server, its worker node killed (SIGKILL to every process of
    it) once it has finished an attack and another attack there has streamed two finished queries to the
    storage; then the same command run again (on the head alone). What the worker node could see, what the
    lost attack had streamed."""
    import fsspec

    from advsim_ros.campaign.storage import Storage

    fsspec.filesystem("s3", skip_instance_cache=True).mkdir("cluster")
    base = tmp_path_factory.mktemp("cluster_campaign")
    config = campaign_config(base / "campaign.yaml", synthetic_bag)
    out, uri, namespace = base / "out", "s3://cluster/c", cluster["namespace"]
    argv = campaign_argv(config, out, "--workers", "2", "--ray-address", cluster["address"], "--storage", uri)
    storage = Storage(uri)
    on_worker: set[str] = set()  # attacks seen running on the worker node
    streamed: dict[str, bytes] = {}

    first_seen: dict[str, float] = {}  # [s] wall clock: when each attack was first seen running on the worker node

    def one_finished_there_and_another_streaming() -> bool:
        running = _attacks_on(namespace)
        on_worker.update(running)
        now = time.time()
        first_seen.update({relative: first_seen.get(relative, now) for relative in running})
        finished = [name for name in storage.files("attacks") if name.endswith("/job_result.json")]
        if len(finished) < 2 and not any(storage.exists(f"{r}/job_result.json") for r in on_worker.difference(running)):
            return False  # the worker node finishes an attack first, unless only the attacks in flight are left
        for relative in running:
            key = f"{relative}/queries.jsonl"
            data = storage.read_bytes(key) if storage.exists(key) else b""
            if len(data.splitlines()) >= 3 and not storage.exists(f"{relative}/job_result.json"):  # header, 2 queries
                streamed[relative] = data
        return bool(streamed)

    started = time.monotonic()
    driver = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        assert wait_for(lambda: one_finished_there_and_another_streaming() or driver.poll() is not None, 900, 0.2)
        assert driver.poll() is None, f"the campaign ended first: on the worker node {on_worker}"
        seen = {
            str(p): _visible_on_node(cluster["worker_pid"], p) for p in (out, synthetic_bag, config, cluster["node"])
        }
        victims, killed_at = _in_namespace(namespace), time.time()
        for pid in victims:
            os.kill(pid, signal.SIGKILL)
        assert wait_for(lambda: not [pid for pid in victims if alive(pid)], timeout=30)
        _, errors = driver.communicate(timeout=900)  # the campaign goes on on the head; the lost attack failed
    finally:
        if driver.poll() is None:
            driver.kill()
    assert driver.returncode == 1, errors[-3000:]
    rerun = subprocess.run(argv, capture_output=True, text=True, timeout=900, check=False)
    assert rerun.returncode == 0, rerun.stderr[-3000:]
    print(f"campaign on two nodes through S3, its worker node lost, run again: {time.monotonic() - started:.1f} s")
    lost = [{"node": "worker", "started_at": first_seen[relative], "ended_at": killed_at} for relative in streamed]
    return {"out": out, "seen_on_worker": seen, "streamed": streamed, "lost_spans": lost, **cluster}


@pytest.mark.slow
def test_a_campaign_whose_worker_node_cannot_see_the_drivers_folders_reports_what_one_node_reports(
    shipped: dict[str, Any], uninterrupted_campaign: Path, synthetic_bag: Path
) -> None:
    out, node = shipped["out"], shipped["node"]
    seen = shipped["seen_on_worker"]
    assert seen.pop(str(node))
    assert not node.exists()
    assert seen == dict.fromkeys(seen, False)  # OUTDIR, the config, the bag: none of them exists on the worker node
    rows = result_rows(out)
    assert len(rows) == 4
    assert all(row["status"] == "ok" for row in rows.values())
    assert rows == result_rows(uninterrupted_campaign)  # every figure, the timing columns aside
    ran_on = {key: json.loads((out / "attacks" / key / "job.json").read_text())["out_dir"] for key in rows}
    on_worker = [key for key, folder in ran_on.items() if Path(folder).is_relative_to(node)]
    assert 1 <= len(on_worker) < 4, ran_on  # each node ran attacks to their end, each in a scratch folder of its own
    assert str(synthetic_bag) not in json.dumps(
        json.loads((out / "attacks" / on_worker[0] / "job.json").read_text())["local"]
    )


@pytest.mark.slow
def test_two_attacks_at_once_on_two_nodes_do_not_hear_each_other(shipped: dict[str, Any]) -> None:
    out, node = shipped["out"], shipped["node"]
    for key in result_rows(out):
        summary = json.loads((out / "attacks" / key / "summary.json").read_text())
        statuses = {query["score"]["status"] for query in summary["queries"]}
        assert statuses == {"ok"}, (key, statuses)  # no query saw a publisher of another graph on its topics
    spans = list(shipped["lost_spans"])  # the lost try, on the worker node till it was killed
    for entry in (json.loads(line) for line in (out / "campaign.jsonl").read_text().splitlines()[1:]):
        if "ran" in entry.get("shipping", {}):  # every try that ran to its end (not the lost one)
            folder = json.loads((out / entry["row"]["out_dir"] / "job.json").read_text())["out_dir"]
            domain = json.loads((out / entry["row"]["out_dir"] / "run" / "graph.json").read_text())["ros_domain_id"]
            where = "worker" if Path(folder).is_relative_to(node) else "head"
            spans.append({**entry["shipping"]["ran"], "node": where, "domain": domain})
    workers, heads = [s for s in spans if s["node"] == "worker"], [s for s in spans if s["node"] == "head"]
    at_once = [
        (a, b) for a in workers for b in heads if a["started_at"] < b["ended_at"] and b["started_at"] < a["ended_at"]
    ]
    assert at_once, spans  # at least once, an attack on each node at the same time
    for a, b in at_once:  # each graph on its own domain (one machine: the nodes share its domain locks)
        assert "domain" not in a or a["domain"] != b["domain"]


def _attacks_on(namespace: str) -> list[str]:
    """The storage folders (relative_dir) of the attacks whose worker process runs in the mount namespace."""
    found = []
    for pid in _in_namespace(namespace):
        try:
            argv = Path(f"/proc/{pid}/cmdline").read_bytes().decode().split("\0")
            if "advsim_ros.campaign.worker" in argv:  # its JOB.json, read through the node's own root
                job = json.loads(
                    Path(f"/proc/{pid}/root{argv[argv.index('advsim_ros.campaign.worker') + 1]}").read_text()
                )
                found += [job["relative_dir"]] if job["kind"] == "attack" else []
        except (OSError, ValueError, KeyError, IndexError):
            continue
    return found


@pytest.mark.slow
def test_a_node_lost_mid_attack_costs_no_finished_query_and_the_rerun_reports_what_an_uninterrupted_run_does(
    shipped: dict[str, Any], uninterrupted_campaign: Path
) -> None:
    out = shipped["out"]
    rows = result_rows(out)
    assert rows == result_rows(uninterrupted_campaign)  # every figure, the timing columns aside
    assert all(row["status"] == "ok" for row in rows.values())
    journal = [json.loads(line) for line in (out / "campaign.jsonl").read_text().splitlines()[1:]]
    for relative, streamed in shipped["streamed"].items():
        lost = [entry for entry in journal if entry["row"]["out_dir"] == relative]
        assert [bool(entry.get("error")) for entry in lost] == [True, False]  # lost with its node, then resumed
        lines = (out / relative / "queries.jsonl").read_bytes().splitlines()
        records = [json.loads(line) for line in lines[1:] if b"query_id" in line]
        ids = [record["query_id"] for record in records]
        assert len(ids) == len(set(ids)) == 6  # the original, 4 searched queries and the identity control
        for line in streamed.splitlines()[1:]:  # finished on the lost node: kept as they were, not computed again
            assert line in lines
        ran = json.loads((out / relative / "job.json").read_text())["out_dir"]
        assert not Path(ran).is_relative_to(shipped["node"])  # resumed on the head: the worker node is gone
