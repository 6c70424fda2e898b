"""Benchmark of whole attacks on a 6 s KITTI tracking 0000 window (real node processes over DDS).

Each run is `advsim attack` as a user runs it (a process of its own), timed from outside, with the
graph's timeline traced (ADVSIM_TRACE_DIR) for a per-query breakdown:

1. ``overhead``: the example stack (a constant-velocity planner, a few ms per sweep) with random
   search: the median query is the framework's own cost (perturb, 10 frames with re-simulation,
   plan, score);
2. ``full``: BO with the paper's 75 queries against the reference (modular) stack, end to end, with
   cold caches (re-simulation model and drivable area built) and again warm: wall time, time to the
   first finished query, per-query breakdown, peak memory and CPU per process.

``--baseline DIR`` runs the same warm full attack with another checkout's `advsim` (its own .venv, e.g.
the previous main in a git worktree) alternately with this one, so the machine's drift cancels,
with the same figures (memory per process included), the ratio of the medians and whether the
scores are the same.

``--lanes K`` (K > 1) adds, per repeat and alternately, the warm 75-query BO attack with batches of
K queries after the initial design (``bo.batch_size=K``, greedy qUCB) on one lane and on K lanes
(``advsim attack --lanes K``: the same queries and scores, so the ratio is the lanes' speed-up),
and the same two runs with random search (one batch: every query independent).

``--readme-path`` measures only the README's path instead: `advsim attack` on the whole log as `advsim
convert kitti` writes it, ``--window-start 20``, beside the same window cut into a bag of its own (and the
``--baseline`` checkout's README path), alternately; a first round with empty caches (cold), then
``--repeats`` warm rounds; every run timed from its start to its exit and split into start-up, searched
queries, re-runs and controls, outputs and exit.

Usage: python bench/bench_attack.py [--queries 75] [--overhead-queries 10] [--repeats 1] [--baseline DIR]
       [--lanes K] [--skip-cold] [--readme-path]
Prints one JSON object. Needs ../shared/data/kitti_tracking_0000.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from advsim_ros.core.curation import crop_frames
from advsim_ros.io.bag import write_scenario_bag
from advsim_ros.io.cache import CACHE_ENV, cache_root
from advsim_ros.io.kitti import load_kitti_tracking
from advsim_ros.ros.trace import TRACE_ENV, query_breakdown, read_trace

REPO = Path(__file__).resolve().parents[1]
KITTI = REPO / ".." / "shared" / "data" / "kitti_tracking_0000"


def window_bag(first: int = 0) -> Path:
    """KITTI 0000 frames first..first+59 as a scenario bag of its own, cached."""
    path = cache_root() / "bench" / (f"kitti_0000_window_{first}_v2")
    if not (path / "metadata.yaml").exists():
        window = crop_frames(load_kitti_tracking(KITTI.resolve(), "0000"), first, first + 59)
        path.parent.mkdir(parents=True, exist_ok=True)
        write_scenario_bag(window, path, source="kitti_tracking/0000", overwrite=True)
    return path


def converted_log() -> Path:
    """The whole log as the README makes it: `advsim convert kitti ... -o logs/kitti_0000` (cached)."""
    path = cache_root() / "bench" / "kitti_0000_log"
    if not (path / "metadata.yaml").exists():
        path.parent.mkdir(parents=True, exist_ok=True)
        command = [str(REPO / ".venv" / "bin" / "advsim"), "convert", "kitti", str(KITTI), "-o", str(path)]
        subprocess.run([*command, "--overwrite"], check=True, capture_output=True)
    return path


def stage_split(
    events: list[tuple[float, str, str, int, int]], started: float, ended: float, queries: int
) -> dict[str, float]:
    """Seconds of one `advsim attack` from its start to its exit: start-up (to the pre-launch checks passed and
    the graph's first query), the searched queries, the re-runs and controls, the outputs, the exit."""
    at = {event: stamp for stamp, _, event, query, _ in events if event in ("checked", "graph_done", "outputs_written")}
    first = min(stamp for stamp, _, event, _, _ in events if event == "query_start")
    searched = max(stamp for stamp, _, event, query, _ in events if event == "journaled" and query <= queries)
    return {
        "start_up": first - started,
        "... of it before the graph (imports, checks)": at["checked"] - started,
        "queries": searched - first,
        "reruns_and_controls": at["graph_done"] - searched,
        "outputs": at["outputs_written"] - at["graph_done"],
        "exit": ended - at["outputs_written"],
    }


def attack(
    checkout: Path,
    bag: Path,
    out: Path,
    stack: str,
    algorithm: str,
    queries: int,
    env: dict[str, str],
    extra: tuple[str, ...] = (),
    window_start: int = 0,
) -> tuple[float, float]:
    """Monotonic start and end of one `advsim attack` run with a checkout's own environment."""
    command = [
        str(checkout / ".venv" / "bin" / "advsim"), "attack", str(bag), "--stack", stack, "--algo", algorithm,
        "--queries", str(queries), "--window-start", str(window_start), "-o", str(out), *extra,
    ]  # fmt: skip
    started = time.monotonic()
    result = subprocess.run(command, env=env, capture_output=True, text=True, check=False)
    ended = time.monotonic()
    if result.returncode != 0:
        raise RuntimeError(f"{' '.join(command)} failed:\n{result.stderr[-2000:]}")
    return started, ended


def traced(
    bag: Path,
    scratch: Path,
    name: str,
    stack: str,
    algorithm: str,
    queries: int,
    cache: Path,
    extra: tuple[str, ...] = (),
    checkout: Path = REPO,
    window_start: int = 0,
) -> dict[str, Any]:
    """One run of a checkout (this one by default), with its trace turned into figures."""
    trace_dir = scratch / f"{name}-trace"
    env = {**os.environ, TRACE_ENV: str(trace_dir), CACHE_ENV: str(cache)}
    if checkout != REPO:  # the other checkout's venv sets up its own ROS wheels
        env.pop("_ROS_WHEELS_BOOTSTRAP_COMPLETE", None)
    started, ended = attack(checkout, bag, scratch / name, stack, algorithm, queries, env, extra, window_start)
    wall = ended - started
    events = read_trace(trace_dir)
    start = next(stamp for stamp, _, event, _, _ in events if event == "checked")
    first = next(stamp for stamp, _, event, _, _ in events if event == "journaled")
    stages = query_breakdown(events)
    searched = [stages[q] for q in sorted(stages) if q > 0]
    summary = json.loads((scratch / name / "summary.json").read_text())
    return {
        "wall_s": wall,
        "stages_s": stage_split(events, started, ended, queries),
        "first_query_finished_s": first - start,
        "median_query_s": statistics.median(item["total"] for item in searched),
        "max_query_s": max(item["total"] for item in searched),
        "median_per_stage_s": {key: statistics.median(item[key] for item in searched) for key in searched[0]},
        "resources": summary["resources"],
        "original_adversarial_loss": (summary["original"] or {}).get("adversarial_loss"),
        "best_adversarial_loss": ((summary["best"] or {}).get("score") or {}).get("adversarial_loss"),
        "failed_queries": summary["failed_queries"],
        "scores": [query["score"]["adversarial_loss"] for query in summary["queries"]],
        "digests": [(query["score"]["input_digest"], query["score"]["plan_digest"]) for query in summary["queries"]],
    }


def _median_of(runs: list[dict[str, Any]], resource: str) -> float | None:
    """The median of a figure of summary.json's resources over the runs that have it (None when none has)."""
    values = [run["resources"][resource] for run in runs if resource in run["resources"]]
    return statistics.median(values) if values else None


def readme_path(args: argparse.Namespace) -> dict[str, Any]:
    """The README's attack on the whole converted log (window 20) beside the same window cut into a bag of its
    own, alternately (and the baseline checkout's README path), each run timed from its start to its exit."""
    log, own = converted_log(), window_bag(20)
    runs: dict[str, list[dict[str, Any]]] = {}
    with tempfile.TemporaryDirectory() as folder:
        scratch, cache = Path(folder), Path(folder) / "cache"
        checkouts = [("readme_path", REPO, log, 20), ("window_bag", REPO, own, 0)]
        if args.baseline is not None:
            checkouts.insert(1, ("baseline_readme_path", args.baseline, log, 20))
        for repeat in range(args.repeats + 1):  # the first round builds the caches (cold), reported apart
            for name, checkout, bag, start in checkouts:
                run = traced(
                    bag, scratch, f"{name}{repeat}", "reference", "bo", args.queries, cache, (), checkout, start
                )
                runs.setdefault(name if repeat else f"{name}_cold", []).append(run)
    figures: dict[str, Any] = {"scenario": "KITTI tracking 0000, window 20 (frames 20..79)", "cores": os.cpu_count()}
    for name, measured in runs.items():
        figures[name] = {
            "median_wall_s": statistics.median(run["wall_s"] for run in measured),
            "median_stages_s": {
                key: statistics.median(run["stages_s"][key] for run in measured) for key in measured[0]["stages_s"]
            },
            "median_graph_peak_rss_mb": statistics.median(run["resources"]["graph_peak_rss_mb"] for run in measured),
            # the process that writes the outputs (attack.outputs_worker; None before it existed)
            "median_outputs_peak_rss_mb": _median_of(measured, "outputs_peak_rss_mb"),
            "runs": measured,
        }
    first = runs["readme_path"][0]
    figures["same_scores_every_run"] = {
        name: all(run["scores"] == measured[0]["scores"] for run in measured) for name, measured in runs.items()
    }
    if args.baseline is not None:
        before = runs["baseline_readme_path"][0]
        figures["readme_path_same_scores_as_baseline"] = first["scores"] == before["scores"]
        figures["readme_path_same_digests_as_baseline"] = first["digests"] == before["digests"]
    return figures


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--queries", type=int, default=75, help="queries of the full BO attack")
    parser.add_argument("--overhead-queries", type=int, default=10, help="queries of the overhead run")
    parser.add_argument(
        "--repeats", type=int, default=1, help="warm full attacks (and baseline ones) to take medians of"
    )
    parser.add_argument("--baseline", type=Path, default=None, help="another checkout with its .venv, run alternately")
    parser.add_argument("--lanes", type=int, default=1, help="also compare batched attacks on 1 and on K lanes")
    parser.add_argument("--skip-cold", action="store_true", help="leave out the cold attack and the overhead run")
    parser.add_argument(
        "--readme-path", action="store_true", help="only the README's path: the whole log, window 20, vs its own bag"
    )
    args = parser.parse_args()
    if not KITTI.is_dir():
        print(json.dumps({"error": f"KITTI tracking 0000 not found at {KITTI.resolve()}"}))
        return 1
    if args.readme_path:
        json.dump(readme_path(args), sys.stdout, indent=2)
        print()
        return 0
    bag = window_bag()
    figures: dict[str, Any] = {"scenario": "KITTI tracking 0000, frames 0..59", "cores": os.cpu_count()}
    with tempfile.TemporaryDirectory() as folder:
        scratch = Path(folder)
        cache = scratch / "cache"
        if args.skip_cold:  # the caches still have to be built once: an attack of two queries does it
            traced(bag, scratch, "cold", "reference", "random", 2, cache)
        else:
            figures["full_cold"] = traced(bag, scratch, "cold", "reference", "bo", args.queries, cache)
            example = f"{sys.executable} -m advsim_ros.stacks.example"
            figures["overhead"] = traced(bag, scratch, "overhead", example, "random", args.overhead_queries, cache)
        warm, baseline = [], []
        lanes: dict[str, list[dict[str, Any]]] = {}
        k = args.lanes
        lane_runs = {
            f"bo_batch{k}_lanes1": ("bo", ("--param", f"search.bo.batch_size={k}")),
            f"bo_batch{k}_lanes{k}": ("bo", ("--param", f"search.bo.batch_size={k}", "--lanes", str(k))),
            "random_lanes1": ("random", ()),
            f"random_lanes{k}": ("random", ("--lanes", str(k))),
        }
        for repeat in range(args.repeats):
            warm.append(traced(bag, scratch, f"warm{repeat}", "reference", "bo", args.queries, cache))
            for name, (algorithm, extra) in lane_runs.items() if k > 1 else ():
                run = traced(bag, scratch, f"{name}-{repeat}", "reference", algorithm, args.queries, cache, extra)
                lanes.setdefault(name, []).append(run)
            if args.baseline is not None:
                baseline.append(
                    traced(bag, scratch, f"base{repeat}", "reference", "bo", args.queries, cache, (), args.baseline)
                )
        figures["full_warm"] = warm[0] if len(warm) == 1 else {"runs": warm}
        figures["full_warm_median_wall_s"] = statistics.median(run["wall_s"] for run in warm)
        if baseline:
            median = statistics.median(run["wall_s"] for run in baseline)
            figures["baseline"] = {
                "checkout": str(args.baseline.resolve()),
                "runs": baseline,
                "median_wall_s": median,
                "ratio_this_to_baseline": figures["full_warm_median_wall_s"] / median,
                "same_scores": all(run["scores"] == warm[0]["scores"] for run in baseline),
            }
        if lanes:
            medians = {name: statistics.median(run["wall_s"] for run in runs) for name, runs in lanes.items()}
            figures["lanes"] = {
                "k": k,
                "runs": lanes,
                "median_wall_s": medians,
                "speedup_bo": medians[f"bo_batch{k}_lanes1"] / medians[f"bo_batch{k}_lanes{k}"],
                "speedup_random": medians["random_lanes1"] / medians[f"random_lanes{k}"],
                "same_scores_bo": all(
                    a["scores"] == b["scores"]
                    for a, b in zip(lanes[f"bo_batch{k}_lanes1"], lanes[f"bo_batch{k}_lanes{k}"], strict=True)
                ),
                "same_scores_random": all(
                    a["scores"] == b["scores"]
                    for a, b in zip(lanes["random_lanes1"], lanes[f"random_lanes{k}"], strict=True)
                ),
            }
    json.dump(figures, sys.stdout, indent=2)
    print()
    return 0


if __name__ == "__main__":
    sys.exit(main())
