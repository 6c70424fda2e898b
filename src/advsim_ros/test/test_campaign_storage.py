"""A campaign whose jobs meet in a storage, not in OUTDIR: an S3-compatible server (moto's, on loopback).

The same campaign (2 attacks, their found scenarios replayed on the other stack, a stack parameter
file from the config's folder) runs once as on one machine (OUTDIR itself the storage, the default,
here named by --storage file://) and once with
``--storage s3://...``: the jobs get the bag and the parameter file from the storage (into the node's
cache), run in a scratch folder and send their outputs back; the driver builds the journal, report
and suite from what it downloaded. Both must report the same figures. A third driver with a fresh
OUTDIR and the same storage runs no job again: what finished is in the storage.
"""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from advsim_ros.campaign.storage import Storage
from advsim_ros.core.curation import crop_frames
from advsim_ros.io.bag import write_scenario_bag
from advsim_ros.io.synthetic import generate_synthetic_log

TIMING_COLUMNS = ("wall_s", "cpu_s", "peak_rss_mb")
OUTPUTS = ("summary.json", "queries.jsonl", "bev.png", "job.log", "job_result.json", "adversarial/metadata.yaml")


def _rows(path: Path, key: str) -> dict[str, dict[str, str]]:
    with path.open() as stream:
        return {row[key]: {k: v for k, v in row.items() if k not in TIMING_COLUMNS} for row in csv.DictReader(stream)}


def _campaign(config: Path, out: Path, env: dict[str, str], *extra: str) -> subprocess.CompletedProcess[str]:
    argv = [sys.executable, "-m", "advsim_ros.cli", "campaign", str(config), "-o", str(out), "--workers", "2"]
    started = time.monotonic()
    result = subprocess.run(
        [*argv, *extra], capture_output=True, text=True, timeout=900, check=False, env={**os.environ, **env}
    )
    print(f"campaign {out.name}: {time.monotonic() - started:.1f} s")
    return result


@pytest.fixture(scope="module")
def campaigns(tmp_path_factory: pytest.TempPathFactory, s3_server: dict[str, str]) -> dict[str, Any]:
    base = tmp_path_factory.mktemp("storage_campaign")
    log = generate_synthetic_log(np.random.default_rng(3), scenario_id="synthetic_seed3")
    write_scenario_bag(crop_frames(log.scenario, 0, 59), base / "log", source="synthetic/seed=3")  # one window
    (base / "example.yaml").write_text("/**:\n  ros__parameters:\n    use_sim_time: true\n")
    example = f"{sys.executable} -m advsim_ros.stacks.example --ros-args"
    values = {
        "scenarios": [{"bag": "log", "windows": {"starts": [0]}}],
        "stacks": ["reference", {"name": "example", "command": example, "params": ["example.yaml"]}],
        "algorithms": {"random": 1},
        "reruns": 0,
        "transfer": True,
        "failure": {"collision": True, "adversarial_loss_above": 0.0},  # every scored attack: both replayed
        "parameters": {"perturber": {"num_candidates": 20000}},
    }
    config = base / "campaign.yaml"
    config.write_text(yaml.safe_dump(values))
    import fsspec

    fsspec.filesystem("s3").mkdir("campaigns")
    uri = "s3://campaigns/storage-test"
    (base / "here").mkdir()
    (base / "link").symlink_to(base / "here")  # OUTDIR named as the storage, through a link: still OUTDIR itself
    here = _campaign(config, base / "here", {}, "--storage", (base / "link").as_uri())
    assert here.returncode == 0, here.stderr[-3000:]
    shipped = _campaign(config, base / "shipped", s3_server, "--storage", uri)
    assert shipped.returncode == 0, shipped.stderr[-3000:]
    again = _campaign(config, base / "again", s3_server, "--storage", uri)
    assert again.returncode == 0, again.stderr[-3000:]
    return {"here": base / "here", "shipped": base / "shipped", "again": base / "again", "uri": uri, "base": base}


@pytest.mark.slow
def test_a_campaign_through_s3_reports_what_it_reports_on_one_machine(campaigns: dict[str, Any]) -> None:
    here, shipped = campaigns["here"], campaigns["shipped"]
    rows = _rows(here / "results.csv", "attack")
    assert len(rows) == 2
    assert all(row["status"] == "ok" for row in rows.values())
    assert _rows(shipped / "results.csv", "attack") == rows  # every figure, the timing columns aside
    transfers = _rows(here / "transfer.csv", "attack")
    assert len(transfers) == 2
    assert _rows(shipped / "transfer.csv", "attack") == transfers
    for key in rows:  # everything an attack writes came back into OUTDIR
        for name in OUTPUTS:
            assert (shipped / "attacks" / key / name).is_file(), name
    here_index = json.loads((here / "suite" / "index.json").read_text())
    assert json.loads((shipped / "suite" / "index.json").read_text()) == here_index
    for scenario in here_index["scenarios"]:
        assert (shipped / "suite" / scenario["bag"] / "metadata.yaml").is_file()
    assert "Table 1" in (shipped / "report.md").read_text()
    for key in rows:  # OUTDIR as the storage: each job ran in its folder there, as before there were storages
        assert json.loads((here / "attacks" / key / "job.json").read_text())["out_dir"] == str(here / "attacks" / key)
    assert not (here / "inputs").exists()


@pytest.mark.slow
def test_the_jobs_got_their_inputs_from_the_storage_and_sent_their_outputs_to_it(campaigns: dict[str, Any]) -> None:
    storage, shipped = Storage(campaigns["uri"]), campaigns["shipped"]
    journal = [json.loads(line) for line in (shipped / "campaign.jsonl").read_text().splitlines()[1:]]
    assert len(journal) == 4  # 2 attacks, 2 transfer replays
    bag, params = (campaigns["base"] / "log").resolve(), (campaigns["base"] / "example.yaml").resolve()
    for entry in journal:
        relative = entry["row"]["out_dir"]
        assert storage.exists(f"{relative}/job_result.json")
        job = json.loads((shipped / relative / "job.json").read_text())  # as its worker ran it, on its node
        assert not Path(job["out_dir"]).is_relative_to(shipped)  # a scratch folder of the node
        ran = job["local"] if entry["job"].startswith("attack/") else job
        assert Path(ran["bag"]) != bag
        if entry["row"].get("stack", entry["row"].get("target_stack")) == "example":
            assert ran["stack_entry"]["params"] != [str(params)]
            assert Path(ran["stack_entry"]["params"][0]).read_text() == params.read_text()  # the node's copy
        shipping = entry["shipping"]
        print(entry["job"], json.dumps(shipping))  # bytes moved and seconds of shipping per job
        assert shipping["sent_bytes"] > 0
        assert shipping["returned_bytes"] > 0
    inputs = storage.files("inputs")
    assert len([name for name in inputs if name.endswith("/manifest.json")]) == 2  # the bag, the parameter file


@pytest.mark.slow
def test_jobs_whose_result_is_in_the_storage_are_never_run_again(campaigns: dict[str, Any]) -> None:
    again, shipped = campaigns["again"], campaigns["shipped"]
    assert _rows(again / "results.csv", "attack") == _rows(shipped / "results.csv", "attack")
    for key in _rows(shipped / "results.csv", "attack"):
        assert (again / "attacks" / key / "job.log").read_text().count("job started") == 1
