"""Benchmark of campaigns: attacks per hour with 1 and with 2 concurrent workers, memory and start-up per attack.

A campaign of ``--windows`` KITTI tracking 0000 windows x the reference stack x random search with
``--queries`` queries runs as `advsim campaign` (a process of its own, local Ray) once with
``--workers 1`` and once with ``--workers 2``, alternately ``--repeats`` times, each in a fresh
output folder with the shared re-simulation cache already warm (a warm-up campaign builds it).
Start-up per attack is its wall time less the wall time of its scored queries (graph start,
model load, feasible sets). Peak memory per attack: its graph's processes and its orchestrator.

With ``--shipping``, the same campaign (``--workers 2``) runs instead once in a shared folder (OUTDIR
itself, as on one machine) and once shipped through an S3 storage (moto's server on loopback,
``--storage s3://...``): the bytes each attack moved (the driver's uploads, the node's downloads and
uploads, the streamed journal, the driver's download) and the seconds of shipping per attack, from
each journal line's ``shipping`` record, beside both campaigns' wall times.

Usage: python bench/bench_campaign.py [--windows 4] [--queries 8] [--repeats 1] [--shipping]
Prints one JSON object. Needs ../shared/data/kitti_tracking_0000.
"""

from __future__ import annotations

import argparse
import csv
import json
import logging
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import yaml

from advsim_ros.core.curation import crop_frames
from advsim_ros.io.bag import write_scenario_bag
from advsim_ros.io.cache import cache_root
from advsim_ros.io.kitti import load_kitti_tracking

REPO = Path(__file__).resolve().parents[1]
KITTI = REPO / ".." / "shared" / "data" / "kitti_tracking_0000"
FRAMES = 120  # KITTI 0000 frames 0..119: room for windows starting at 0, 20, 40, 60


def kitti_bag() -> Path:
    path = cache_root() / "bench" / f"kitti_0000_frames_0_{FRAMES - 1}"
    if not (path / "metadata.yaml").exists():
        log = crop_frames(load_kitti_tracking(KITTI.resolve(), "0000"), 0, FRAMES - 1)
        path.parent.mkdir(parents=True, exist_ok=True)
        write_scenario_bag(log, path, source="kitti_tracking/0000", overwrite=True)
    return path


def write_config(path: Path, bag: Path, windows: int, queries: int) -> Path:
    values = {
        "scenarios": [{"bag": str(bag), "windows": {"starts": [20 * i for i in range(windows)]}}],
        "stacks": ["reference"],
        "algorithms": {"random": queries},
        "reruns": 0,
        "transfer": False,
    }
    path.write_text(yaml.safe_dump(values))
    return path


def campaign(config: Path, out: Path, workers: int, *extra: str) -> dict[str, Any]:
    started = time.monotonic()
    subprocess.run(
        [sys.executable, "-m", "advsim_ros.cli", "campaign", str(config), "-o", str(out), "--workers", str(workers),
         *extra],
        check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip
    wall = time.monotonic() - started
    with (out / "results.csv").open() as stream:
        rows = list(csv.DictReader(stream))
    startups = []
    for row in rows:
        summary = json.loads((out / row["out_dir"] / "summary.json").read_text())
        scored = sum(q["score"].get("wall_time") or 0.0 for q in summary["queries"])
        startups.append(float(row["wall_s"]) - scored)
    return {
        "wall_s": wall,
        "attacks": len(rows),
        "attacks_per_hour": 3600.0 * len(rows) / wall,
        "peak_rss_mb_per_attack": [float(row["peak_rss_mb"]) for row in rows],
        "startup_s_per_attack": startups,
    }


MOVED = ("uploaded_bytes", "fetched_bytes", "sent_bytes", "streamed_bytes", "returned_bytes")
SHIPPING_S = ("upload_s", "fetch_s", "send_s", "return_s")


def shipping(config: Path, base: Path, queries: int) -> dict[str, Any]:
    """The campaign in a shared folder and shipped through moto's S3 server: what shipping cost per attack."""
    import fsspec
    from moto.server import ThreadedMotoServer

    logging.getLogger("werkzeug").setLevel(logging.ERROR)  # one line per request otherwise
    server = ThreadedMotoServer(ip_address="127.0.0.1", port=0, verbose=False)
    server.start()
    host, port = server.get_host_and_port()
    endpoint = f"http://{host}:{port}"
    os.environ.update(AWS_ENDPOINT_URL=endpoint, AWS_ACCESS_KEY_ID="bench", AWS_SECRET_ACCESS_KEY="bench")
    os.environ.setdefault("AWS_DEFAULT_REGION", "us-east-1")
    try:
        fsspec.filesystem("s3").mkdir("bench")
        shared = campaign(config, base / "shared", 2)
        shipped = campaign(config, base / "shipped", 2, "--storage", "s3://bench/campaign")
    finally:
        server.stop()
    lines = (base / "shipped" / "campaign.jsonl").read_text().splitlines()[1:]
    records = [json.loads(line)["shipping"] for line in lines]
    per_attack = [
        {"mb_moved": sum(r.get(k, 0) for k in MOVED) / 1e6, "shipping_s": sum(r.get(k, 0.0) for k in SHIPPING_S),
         **{k: r.get(k) for k in (*MOVED, *SHIPPING_S)}}
        for r in records
    ]  # fmt: skip
    return {
        "benchmark": "campaign shipping",
        "scenario": f"kitti_tracking_0000 frames 0..{FRAMES - 1}, windows from 0 every 20 frames",
        "attacks": len(records),
        "algorithm": f"random, {queries} queries, no re-runs; 2 workers, one node",
        "storage": "moto S3 server on loopback",
        "mb_moved_per_attack_median": statistics.median(a["mb_moved"] for a in per_attack),
        "shipping_s_per_attack_median": statistics.median(a["shipping_s"] for a in per_attack),
        # what every attack moves, its inputs aside (uploaded once per campaign, fetched once per node)
        "mb_outputs_per_attack_median": statistics.median(
            sum(a[k] or 0 for k in ("sent_bytes", "streamed_bytes", "returned_bytes")) / 1e6 for a in per_attack
        ),
        "outputs_s_per_attack_median": statistics.median((a["send_s"] or 0) + (a["return_s"] or 0) for a in per_attack),
        "mb_inputs_once": max(a["uploaded_bytes"] or 0 for a in per_attack) / 1e6,
        "wall_s_shared_folder": shared["wall_s"],
        "wall_s_shipped": shipped["wall_s"],
        "per_attack": per_attack,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--windows", type=int, default=4)
    parser.add_argument("--queries", type=int, default=8)
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--shipping", action="store_true", help="a shared folder against an S3 storage instead")
    args = parser.parse_args()
    bag = kitti_bag()
    if args.shipping:
        with tempfile.TemporaryDirectory(prefix="bench_campaign_") as scratch:
            base = Path(scratch)
            config = write_config(base / "campaign.yaml", bag, args.windows, args.queries)
            campaign(write_config(base / "warm.yaml", bag, args.windows, 1), base / "warm", 2)  # models built, cached
            print(json.dumps(shipping(config, base, args.queries), indent=2))
        return
    with tempfile.TemporaryDirectory(prefix="bench_campaign_") as scratch:
        base = Path(scratch)
        config = write_config(base / "campaign.yaml", bag, args.windows, args.queries)
        campaign(write_config(base / "warm.yaml", bag, args.windows, 1), base / "warm", 2)  # models built, cached
        runs: dict[int, list[dict[str, Any]]] = {1: [], 2: []}
        for repeat in range(args.repeats):
            for workers in (1, 2):
                runs[workers].append(campaign(config, base / f"run{repeat}_w{workers}", workers))
    rates = {w: statistics.median(r["attacks_per_hour"] for r in runs[w]) for w in runs}
    every = [run for w in runs for run in runs[w]]
    print(
        json.dumps(
            {
                "benchmark": "campaign",
                "scenario": f"kitti_tracking_0000 frames 0..{FRAMES - 1}, windows from 0 every 20 frames",
                "attacks": args.windows,
                "stack": "reference",
                "algorithm": f"random, {args.queries} queries, no re-runs",
                "repeats": args.repeats,
                "attacks_per_hour_1_worker": rates[1],
                "attacks_per_hour_2_workers": rates[2],
                "ratio_2_to_1": rates[2] / rates[1],
                "peak_rss_mb_per_attack_median": statistics.median(
                    m for r in every for m in r["peak_rss_mb_per_attack"]
                ),
                "peak_rss_mb_per_attack_max": max(m for r in every for m in r["peak_rss_mb_per_attack"]),
                "startup_s_per_attack_warm_median": statistics.median(
                    s for r in every for s in r["startup_s_per_attack"]
                ),
                "runs": {str(w): runs[w] for w in runs},
            },
            indent=2,
        )
    )


if __name__ == "__main__":
    main()
