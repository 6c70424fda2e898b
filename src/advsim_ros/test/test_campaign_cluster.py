"""A campaign on a Ray cluster whose worker node sees none of the driver's folders: they meet in an S3 server.

Two Ray nodes on this machine, one CPU each: the head (started by this process) and a worker node
whose `ray start --address HEAD` runs in a mount namespace of its own (`unshare --mount`), with a
tmpfs mounted over pytest's whole temporary folder, so the driver's OUTDIR, its config and the
scenario bag do not exist there; the node's temporary folder and cache lie in that tmpfs, its own.
Only the ROS-domain locks of this machine are shared with it (bound into its temporary folder), as
two graphs on one machine must not take the same domain. The storage is moto's S3 server on
loopback. With two attacks in flight at once, one runs on each node.

The campaign of 4 attacks (campaign_runs) must report what the same campaign reports run whole on one
node (conftest.uninterrupted_campaign); at least one attack ran on the worker node, and two attacks ran
at the same time on the two nodes without hearing each other (DDS on loopback, each graph its own
domain: no query of theirs saw a publisher of another graph).
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from attack_runs import alive
from campaign_runs import campaign_argv, campaign_config, result_rows

from advsim_ros.ros.launcher import wait_for

HIDE_AND_JOIN = """
mount -t tmpfs advsim-node "$HIDDEN" && mkdir -p "$NODE/tmp/advsim_ros_domains" "$NODE/cache" "$DOMAINS" &&
mount --bind "$DOMAINS" "$NODE/tmp/advsim_ros_domains" && exec "$RAY" start --address "$HEAD" --num-cpus 1 --block \
  --disable-usage-stats
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
def cluster(s3_server: dict[str, str], tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, Any]]:
    """The head node (this process's, 1 CPU) and the worker node in its own mount namespace (1 CPU)."""
    from ray.cluster_utils import Cluster

    if subprocess.run(["unshare", "--mount", "true"], check=False, capture_output=True).returncode != 0:
        pytest.skip("unshare --mount is not allowed here: no node can be kept from the driver's folders")
    hidden = tmp_path_factory.getbasetemp()  # every folder the tests made: the driver's, the bag's
    node = hidden / "worker-node"  # exists only in the worker node's namespace
    head = Cluster(initialize_head=True, head_node_args={"num_cpus": 1})
    env = {
        **os.environ, **s3_server, "HIDDEN": str(hidden), "NODE": str(node), "HEAD": head.address,
        "DOMAINS": str(Path("/tmp") / "advsim_ros_domains"), "RAY": str(Path(sys.executable).parent / "ray"),
        "TMPDIR": str(node / "tmp"), "ADVSIM_CACHE_DIR": str(node / "cache"), "RAY_TMPDIR": "/tmp",
    }  # fmt: skip
    worker = subprocess.Popen(
        ["unshare", "--mount", "--propagation", "private", "sh", "-c", HIDE_AND_JOIN],
        env=env, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
        start_new_session=True,
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
            assert len([n for n in nodes() if n["Alive"]]) == 2, worker.stderr.read() if worker.stderr else ""
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
    """The campaign on the two nodes through the S3 server; what the worker node could see while it ran."""
    import fsspec

    fsspec.filesystem("s3", skip_instance_cache=True).mkdir("cluster")
    base = tmp_path_factory.mktemp("cluster_campaign")
    config = campaign_config(base / "campaign.yaml", synthetic_bag)
    out = base / "out"
    started = time.monotonic()
    completed = subprocess.run(
        campaign_argv(config, out, "--workers", "2", "--ray-address", cluster["address"], "--storage", "s3://cluster/c"),
        capture_output=True, text=True, timeout=1500, check=False,
    )  # fmt: skip
    print(f"campaign on two nodes through S3: {time.monotonic() - started:.1f} s")
    assert completed.returncode == 0, completed.stderr[-3000:]
    seen = {str(p): _visible_on_node(cluster["worker_pid"], p) for p in (out, synthetic_bag, config, cluster["node"])}
    return {"out": out, "seen_on_worker": seen, **cluster}


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
    assert 1 <= len(on_worker) < 4, ran_on  # each node ran attacks, each in a scratch folder of its own
    assert str(synthetic_bag) not in json.dumps(
        json.loads((out / "attacks" / on_worker[0] / "job.json").read_text())["local"]
    )


@pytest.mark.slow
def test_two_attacks_at_once_on_two_nodes_do_not_hear_each_other(shipped: dict[str, Any]) -> None:
    out = shipped["out"]
    for key in result_rows(out):
        summary = json.loads((out / "attacks" / key / "summary.json").read_text())
        statuses = {query["score"]["status"] for query in summary["queries"]}
        assert statuses == {"ok"}, (key, statuses)  # no query saw a publisher of another graph on its topics
    journal = [json.loads(line) for line in (out / "campaign.jsonl").read_text().splitlines()[1:]]
    ran = [entry["shipping"]["ran"] for entry in journal]
    assert len({where["ray_node"] for where in ran}) == 2  # both nodes ran attacks
    at_once = [
        (a, b) for a in ran for b in ran
        if a["ray_node"] < b["ray_node"] and a["started_at"] < b["ended_at"] and b["started_at"] < a["ended_at"]
    ]  # fmt: skip
    assert at_once, ran  # at least once, an attack on each node at the same time


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


@pytest.fixture(scope="module")
def node_lost(shipped: dict[str, Any], synthetic_bag: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """The campaign again, its worker node killed (SIGKILL to all its processes) once an attack there has
    streamed two finished queries to the storage; then the same command run again, on the head alone."""
    from advsim_ros.campaign.storage import Storage

    base = tmp_path_factory.mktemp("node_lost")
    config = campaign_config(base / "campaign.yaml", synthetic_bag)
    out, uri = base / "out", "s3://cluster/lost"
    argv = campaign_argv(config, out, "--workers", "2", "--ray-address", shipped["address"], "--storage", uri)
    storage, namespace = Storage(uri), shipped["namespace"]
    streamed: dict[str, bytes] = {}

    def two_queries_streamed() -> bool:
        for relative in _attacks_on(namespace):
            key = f"{relative}/queries.jsonl"
            data = storage.read_bytes(key) if storage.exists(key) else b""
            if len(data.splitlines()) >= 3:  # the header and two queries
                streamed[relative] = data
        return bool(streamed)

    driver = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        assert wait_for(lambda: two_queries_streamed() or driver.poll() is not None, timeout=600, poll=0.2)
        assert driver.poll() is None, driver.communicate()[1][-3000:]
        victims = _in_namespace(namespace)
        for pid in victims:
            os.kill(pid, signal.SIGKILL)
        assert wait_for(lambda: not [pid for pid in victims if alive(pid)], timeout=30)
        _, lost_errors = driver.communicate(timeout=900)  # the campaign goes on on the head; the lost attack failed
    finally:
        if driver.poll() is None:
            driver.kill()
    assert driver.returncode != 0, "the attack lost with its node did not fail its first campaign"
    rerun = subprocess.run(argv, capture_output=True, text=True, timeout=900, check=False)
    assert rerun.returncode == 0, rerun.stderr[-3000:]
    return {"out": out, "streamed": streamed, "first_run": lost_errors, "node": shipped["node"]}


@pytest.mark.slow
def test_a_node_lost_mid_attack_costs_no_finished_query_and_the_rerun_reports_what_an_uninterrupted_run_does(
    node_lost: dict[str, Any], uninterrupted_campaign: Path
) -> None:
    out = node_lost["out"]
    rows = result_rows(out)
    assert rows == result_rows(uninterrupted_campaign)  # every figure, the timing columns aside
    assert all(row["status"] == "ok" for row in rows.values())
    journal = [json.loads(line) for line in (out / "campaign.jsonl").read_text().splitlines()[1:]]
    for relative, streamed in node_lost["streamed"].items():
        lost = [entry for entry in journal if entry["row"]["out_dir"] == relative]
        assert [bool(entry.get("error")) for entry in lost] == [True, False]  # lost with its node, then resumed
        lines = (out / relative / "queries.jsonl").read_bytes().splitlines()
        records = [json.loads(line) for line in lines[1:] if b"query_id" in line]
        ids = [record["query_id"] for record in records]
        assert len(ids) == len(set(ids)) == 6  # the original, 4 searched queries and the identity control
        for line in streamed.splitlines()[1:]:  # finished on the lost node: kept as they were, not computed again
            assert line in lines
        ran = json.loads((out / relative / "job.json").read_text())["out_dir"]
        assert not Path(ran).is_relative_to(node_lost["node"])  # resumed on the head: the worker node is gone
