"""Search overhead per query, and the comparison of the algorithms on test functions.

Run as ``python bench/bench_search.py [--repeat N]``; prints one JSON object:

- ``overhead``: seconds of search work per query (ask + tell, the objective excluded) for
  every algorithm at budget 75 and D = 12 and 24, asking one point at a time as the search
  node does: median, 90th percentile and maximum over all queries of N runs; for BO also
  the median over the queries its GP proposes (after the initial design), and one run with
  torch's default thread count for comparison.

``python bench/bench_search.py --table [--seeds 10] [--budget 75]`` prints instead the mean
best value per algorithm on the shifted-rotated Ackley and Rastrigin and the collision-like
function (advsim_ros.core.search.synthetic) over the seeds, every algorithm at the same
budget, as JSON with the markdown table of docs/search.md under ``markdown``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import time
from typing import Any

import numpy as np

from advsim_ros.core.search import ALGORITHM_NAMES, default_config, make_search
from advsim_ros.core.search.bo_config import BoConfig
from advsim_ros.core.search.synthetic import TEST_FUNCTION_NAMES, best_values, make_test_function

DIMENSIONS = (12, 24)  # one and two perturbed actors
BUDGET = 75


def _machine() -> dict[str, Any]:
    import torch

    return {
        "python": platform.python_version(),
        "cpus": os.cpu_count(),
        "load_average_1min": os.getloadavg()[0],
        "torch_default_threads": torch.get_num_threads(),
    }


def _overhead_run(name: str, dimension: int, seed: int, **overrides: Any) -> list[float]:
    """Seconds of ask + tell for each query of one run on the Ackley function."""
    config = dataclasses.replace(default_config(name), max_queries=BUDGET, **overrides)
    search = make_search(name, dimension, np.random.default_rng(seed), config)
    function = make_test_function("ackley", dimension, np.random.default_rng([seed, 0]))
    seconds = []
    while not search.done:
        start = time.perf_counter()
        points = search.ask(1)
        asked = time.perf_counter()
        values = function(points)
        told = time.perf_counter()
        search.tell(points, values)
        seconds.append((asked - start) + (time.perf_counter() - told))
    return seconds


def _summary(seconds: list[float]) -> dict[str, float]:
    array = np.array(seconds)
    return {
        "median_s": float(np.median(array)),
        "p90_s": float(np.percentile(array, 90)),
        "max_s": float(array.max()),
        "queries": int(array.size),
    }


def overhead(repeat: int) -> dict[str, Any]:
    import torch

    results: dict[str, Any] = {}
    for name in ALGORITHM_NAMES:
        for dimension in DIMENSIONS:
            runs = [_overhead_run(name, dimension, seed) for seed in range(repeat)]
            entry = _summary([value for run in runs for value in run])
            if name == "bo":
                initial = BoConfig().initial_points
                entry["median_model_queries_s"] = float(np.median([v for run in runs for v in run[initial:]]))
            results[f"{name}_D{dimension}"] = entry
    default_threads = torch.get_num_threads()
    run = _overhead_run("bo", 24, 0, torch_threads=default_threads)
    results["bo_D24_torch_default_threads"] = {**_summary(run), "torch_threads": default_threads}
    return results


def comparison(seeds: int, budget: int) -> dict[str, Any]:
    table: dict[str, dict[str, dict[str, float]]] = {}
    for function_name in TEST_FUNCTION_NAMES:
        for dimension in DIMENSIONS:
            row: dict[str, dict[str, float]] = {}
            for name in ALGORITHM_NAMES:
                config = dataclasses.replace(default_config(name), max_queries=budget)
                start = time.perf_counter()
                values = best_values(name, config, function_name, dimension, range(seeds))
                row[name] = {
                    "mean_best": float(values.mean()),
                    "std_best": float(values.std()),
                    "seconds": time.perf_counter() - start,
                }
            table[f"{function_name}_D{dimension}"] = row
    return {"seeds": seeds, "budget": budget, "table": table, "markdown": _markdown(table, seeds, budget)}


def _markdown(table: dict[str, dict[str, dict[str, float]]], seeds: int, budget: int) -> str:
    header = "| function | D | " + " | ".join(ALGORITHM_NAMES) + " |"
    lines = [
        f"Mean best value over {seeds} seeds at {budget} queries (maximised; higher is better; "
        "bold: the best algorithm of the row).",
        "",
        header,
        "|" + "---|" * (len(ALGORITHM_NAMES) + 2),
    ]
    for key, row in table.items():
        function_name, dimension = key.rsplit("_D", 1)
        best = max(row, key=lambda name: row[name]["mean_best"])
        cells = [
            f"**{row[name]['mean_best']:.2f}**" if name == best else f"{row[name]['mean_best']:.2f}"
            for name in ALGORITHM_NAMES
        ]
        lines.append(f"| {function_name} | {dimension} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("--repeat", type=int, default=3, help="runs per algorithm and dimension (overhead)")
    parser.add_argument("--table", action="store_true", help="compare the algorithms on the test functions")
    parser.add_argument("--seeds", type=int, default=10, help="seeds per table cell")
    parser.add_argument("--budget", type=int, default=BUDGET, help="queries per run in the table")
    args = parser.parse_args()
    start = time.perf_counter()
    figures: dict[str, Any] = {"machine": _machine()}
    if args.table:
        figures["comparison"] = comparison(args.seeds, args.budget)
    else:
        figures["overhead"] = overhead(args.repeat)
    figures["wall_s"] = time.perf_counter() - start
    print(json.dumps(figures, indent=2))


if __name__ == "__main__":
    main()
