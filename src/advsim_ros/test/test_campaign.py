"""A campaign for real: 2 windows x 2 stacks x 4 queries on a Ray cluster of two local nodes, its driver
killed with SIGKILL mid-way and the same command run again; then `advsim regress` on the suite it exported.

The resumed campaign must report exactly what an uninterrupted run reports, run no finished attack
twice, and leave no process of the killed driver's attacks behind. The JUnit XML of `advsim regress`
is read back with junitparser (not the writer's own ElementTree).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from attack_runs import alive
from campaign_runs import campaign_argv, campaign_config, result_rows

from advsim_ros.ros.launcher import wait_for


def _journaled_attacks(out: Path) -> list[str]:
    path = out / "campaign.jsonl"
    if not path.exists():
        return []
    jobs = []
    for line in path.read_text().splitlines()[1:]:
        try:
            jobs.append(json.loads(line)["job"])
        except (ValueError, KeyError):
            break
    return [job for job in jobs if job.startswith("attack/")]


def _workers_of(out: Path) -> list[int]:
    """Live campaign worker processes whose job lies in ``out``."""
    pids = []
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                argv = Path(f"/proc/{entry}/cmdline").read_bytes().split(b"\0")
            except OSError:
                continue
            if b"advsim_ros.campaign.worker" in argv and any(str(out).encode() in arg for arg in argv):
                pids.append(int(entry))
    return pids


@pytest.fixture(scope="module")
def ray_cluster() -> Iterator[str]:
    """Two Ray nodes on this machine (one CPU each): the address a campaign joins."""
    from ray.cluster_utils import Cluster

    cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 1})
    cluster.add_node(num_cpus=1)
    cluster.wait_for_nodes()
    try:
        yield cluster.address
    finally:
        cluster.shutdown()


@pytest.fixture(scope="module")
def campaigns(
    ray_cluster: str, synthetic_bag: Path, uninterrupted_campaign: Path, tmp_path_factory: pytest.TempPathFactory
) -> dict[str, Path]:
    """The campaign killed and resumed on the cluster, and the same campaign uninterrupted on a local Ray (conftest)."""
    base = tmp_path_factory.mktemp("campaign")
    config = campaign_config(base / "campaign.yaml", synthetic_bag)
    killed = base / "killed"
    driver = subprocess.Popen(
        campaign_argv(config, killed, "--workers", "2", "--ray-address", ray_cluster),
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        assert wait_for(lambda: bool(_journaled_attacks(killed)) or driver.poll() is not None, timeout=900)
        assert driver.poll() is None, driver.communicate()[1]
        os.kill(driver.pid, signal.SIGKILL)
        driver.wait(timeout=30)
    finally:
        if driver.poll() is None:
            driver.kill()
    before = _journaled_attacks(killed)
    assert 1 <= len(before) < 4
    # the killed driver's running attacks die with it (Ray ends the job's workers; each worker's
    # process and graph are tied to it)
    assert wait_for(lambda: not _workers_of(killed), timeout=60), _workers_of(killed)
    resumed = subprocess.run(
        campaign_argv(config, killed, "--workers", "2", "--ray-address", ray_cluster),
        capture_output=True, text=True, timeout=1500, check=False,
    )  # fmt: skip
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    (base / "journaled_before_kill.json").write_text(json.dumps(before))
    return {"killed": killed, "whole": uninterrupted_campaign, "base": base, "config": config}


@pytest.mark.slow
def test_a_campaign_killed_mid_way_and_resumed_reports_what_an_uninterrupted_one_does(
    campaigns: dict[str, Path],
) -> None:
    killed, whole = campaigns["killed"], campaigns["whole"]
    rows = result_rows(killed)
    assert len(rows) == 4
    assert all(row["status"] == "ok" for row in rows.values())
    assert rows == result_rows(whole)  # every figure equal, the timing columns aside
    assert sorted(_journaled_attacks(killed)) == sorted(f"attack/{key}" for key in rows)  # each attack once
    before = json.loads((campaigns["base"] / "journaled_before_kill.json").read_text())
    for job in before:  # finished before the kill: never started again
        log = (killed / "attacks" / job.split("/", 1)[1] / "job.log").read_text()
        assert log.count("job started") == 1
    for key in rows:  # no query computed twice, resumed or not
        lines = (killed / "attacks" / key / "queries.jsonl").read_text().splitlines()[1:]
        ids = [json.loads(line)["query_id"] for line in lines if "query_id" in line]
        assert len(ids) == len(set(ids)) == 6  # the original, 4 searched queries and the identity control
    report = (killed / "report.md").read_text()
    assert "Table 1" in report
    assert "| reference | adversarial | 2 |" in report
    assert (killed / "report.html").stat().st_size > 0


@pytest.mark.slow
def test_advsim_regress_is_red_for_the_scenarios_the_stack_still_fails_and_names_them_in_junit(
    campaigns: dict[str, Path], tmp_path: Path
) -> None:
    from junitparser import Failure, JUnitXml

    suite = campaigns["killed"] / "suite"
    index = json.loads((suite / "index.json").read_text())
    found_on_reference = [s for s in index["scenarios"] if s["found_on"] == "reference"]
    assert len(index["scenarios"]) == 4
    assert len(found_on_reference) == 2
    # the bar between the two reference scenarios' recorded L_adv: one still fails it, one passes now
    losses = sorted(s["recorded"]["adversarial_loss"] for s in found_on_reference)
    assert losses[0] < losses[1]
    own = tmp_path / "suite"
    own.mkdir()
    for scenario in found_on_reference:
        (own / scenario["name"]).symlink_to(suite / scenario["bag"], target_is_directory=True)
    index.update(scenarios=found_on_reference, failure={"collision": False, "adversarial_loss_above": sum(losses) / 2})
    (own / "index.json").write_text(json.dumps(index))
    junit = tmp_path / "regress.xml"
    argv = [sys.executable, "-m", "advsim_ros.cli", "regress", str(own), "--stack", "reference", "--junit", str(junit)]
    result = subprocess.run([*argv, "-o", str(tmp_path / "replays")], capture_output=True, text=True, timeout=900)
    assert result.returncode == 1, result.stdout + result.stderr
    cases = {case.name: case for suite_ in JUnitXml.fromfile(str(junit)) for case in suite_}
    worse = max(found_on_reference, key=lambda s: s["recorded"]["adversarial_loss"])["name"]
    better = min(found_on_reference, key=lambda s: s["recorded"]["adversarial_loss"])["name"]
    assert set(cases) == {worse, better}
    assert [type(r) for r in cases[worse].result] == [Failure]
    assert cases[better].result == []  # passed: neither a failure nor an error
    assert "1 passed, 1 failed" in result.stdout


@pytest.mark.slow
def test_kill_9_of_a_campaign_on_its_own_local_ray_leaves_no_process_behind(
    synthetic_bag: Path, tmp_path: Path, zombie_shm_segments: Callable[[], int]
) -> None:
    from advsim_ros.ros.reaper import descendants

    zombie_shm_segments()  # what earlier tests left
    config = campaign_config(tmp_path / "campaign.yaml", synthetic_bag, queries=500)  # a budget it cannot finish first
    out = tmp_path / "out"
    driver = subprocess.Popen(
        campaign_argv(config, out, "--workers", "2"), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )
    try:
        # Ray's own processes, its workers, the attacks' worker processes and their graphs
        # (one attack or two at once: Ray starts as many as the machine's free memory admits)
        assert wait_for(lambda: bool(_workers_of(out)) or driver.poll() is not None, timeout=300)
        assert wait_for(
            lambda: any(b"lidar_resim" in _cmdline(p) for p in descendants(driver.pid)) or driver.poll() is not None,
            timeout=300,
        )
        assert driver.poll() is None
        below = descendants(driver.pid)
        os.kill(driver.pid, signal.SIGKILL)
        driver.wait(timeout=30)
    finally:
        if driver.poll() is None:
            driver.kill()
    assert wait_for(lambda: not [pid for pid in below if alive(pid)], timeout=30), [
        _cmdline(pid) for pid in below if alive(pid)
    ]
    assert zombie_shm_segments() == 0  # the graphs' shared memory went with them


def _cmdline(pid: int) -> bytes:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:
        return b""
