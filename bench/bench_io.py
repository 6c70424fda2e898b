"""Conversion and bag-reading throughput on KITTI tracking 0000 and the Argoverse 2 logs.

Run as ``python bench/bench_io.py [--repeat N]``; prints one JSON object of figures:
sweeps per second and megabytes per second (of bag storage) for importing, writing,
reading and streaming, for MCAP (written and read by advsim_ros and read by the
independent mcap reader) and sqlite3. Without ../shared/data it measures the same on a
generated log of KITTI's size (154 sweeps of 120,000 points) and says so.
"""

from __future__ import annotations

import argparse
import json
import platform
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from advsim_ros.core.curation import CurationConfig, curate_windows
from advsim_ros.core.types import EgoTrajectory, Scenario, Sweep
from advsim_ros.io.av2 import load_av2_log
from advsim_ros.io.bag import BagConfig, iter_bag_sweeps, read_scenario_bag, summarize_bag, write_scenario_bag
from advsim_ros.io.kitti import KITTI_BIN_DTYPE, kitti_velodyne_dir, load_kitti_tracking

SHARED_DATA = Path(__file__).resolve().parents[1] / "../shared/data"


def _best_of(repeat: int, run: Callable[[], Any]) -> tuple[float, Any]:
    """Shortest wall time of ``repeat`` runs [s] (the machine is shared; the minimum is the least disturbed)."""
    best, result = float("inf"), None
    for _ in range(repeat):
        started = time.perf_counter()
        result = run()
        best = min(best, time.perf_counter() - started)
    return best, result


def _fresh(workdir: Path) -> Path:
    """An empty folder of its own for each bag written."""
    return Path(tempfile.mkdtemp(dir=workdir))


def _generated_log(num_sweeps: int = 154, num_points: int = 120_000) -> Scenario:
    rng = np.random.default_rng(0)
    stamps = 1_000_000_000 + 100_000_000 * np.arange(num_sweeps, dtype=np.int64)
    poses = np.tile(np.eye(4), (num_sweeps, 1, 1))
    poses[:, 0, 3] = 0.5 * np.arange(num_sweeps)
    sweeps = []
    for index in range(num_sweeps):
        points = np.empty(num_points, dtype=KITTI_BIN_DTYPE)
        for name in ("x", "y", "z", "intensity"):
            points[name] = rng.uniform(-50, 50, num_points)
        sweeps.append(Sweep(int(stamps[index]), "velodyne", points, poses[index]))
    return Scenario("generated", stamps, EgoTrajectory(stamps, poses), (), tuple(sweeps))


def _mcap_decode(bag: Path) -> int:
    (path,) = bag.glob("*.mcap")
    count = 0
    with path.open("rb") as stream:
        for _, channel, _, message in make_reader(stream, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
            if channel.topic == "/sensor/lidar/points":
                count += int(message.width * message.height)
    return count


def bench_kitti(scenario_loader: Callable[[], Scenario], workdir: Path, repeat: int, source: str) -> dict[str, Any]:
    figures: dict[str, Any] = {"source": source}
    seconds, scenario = _best_of(repeat, scenario_loader)
    num_sweeps = len(scenario.sweeps)
    point_mb = sum(sweep.points.nbytes for sweep in scenario.sweeps) / 1e6
    figures["import_sweeps_per_s"] = num_sweeps / seconds
    figures["import_MB_per_s"] = point_mb / seconds
    figures["num_sweeps"] = num_sweeps
    figures["num_points"] = sum(sweep.num_points for sweep in scenario.sweeps)
    for storage in ("mcap", "sqlite3"):
        config = BagConfig(storage=storage)
        seconds, bag = _best_of(
            repeat, lambda config=config: write_scenario_bag(scenario, _fresh(workdir) / "bag", config=config)
        )
        size_mb = summarize_bag(bag).size_bytes / 1e6
        figures[f"{storage}_bag_MB"] = size_mb
        figures[f"{storage}_write_sweeps_per_s"] = num_sweeps / seconds
        figures[f"{storage}_write_MB_per_s"] = size_mb / seconds
        seconds, read_back = _best_of(repeat, lambda bag=bag: read_scenario_bag(bag))
        assert len(read_back.sweeps) == num_sweeps
        figures[f"{storage}_read_sweeps_per_s"] = num_sweeps / seconds
        figures[f"{storage}_read_MB_per_s"] = size_mb / seconds
        seconds, streamed = _best_of(repeat, lambda bag=bag: sum(1 for _ in iter_bag_sweeps(bag)))
        assert streamed == num_sweeps
        figures[f"{storage}_stream_sweeps_per_s"] = num_sweeps / seconds
        figures[f"{storage}_stream_MB_per_s"] = size_mb / seconds
        seconds, _ = _best_of(repeat, lambda bag=bag: read_scenario_bag(bag, load_sweeps=False))
        figures[f"{storage}_read_without_sweeps_s"] = seconds
        if storage == "mcap":
            seconds, points = _best_of(repeat, lambda bag=bag: _mcap_decode(bag))
            assert points == figures["num_points"]
            figures["mcap_reader_decode_sweeps_per_s"] = num_sweeps / seconds
            figures["mcap_reader_decode_MB_per_s"] = size_mb / seconds
    seconds, _ = _best_of(repeat, lambda: curate_windows(scenario, CurationConfig()))
    figures["curate_s"] = seconds
    return figures


def bench_av2(logs: list[Path], workdir: Path, repeat: int) -> dict[str, Any]:
    frames = 0
    import_s = write_s = read_s = curate_s = 0.0
    for log in logs:
        seconds, scenario = _best_of(repeat, lambda log=log: load_av2_log(log))
        import_s += seconds
        frames += scenario.num_frames
        seconds, bag = _best_of(repeat, lambda scenario=scenario: write_scenario_bag(scenario, _fresh(workdir) / "bag"))
        write_s += seconds
        seconds, _ = _best_of(repeat, lambda bag=bag: read_scenario_bag(bag))
        read_s += seconds
        seconds, _ = _best_of(repeat, lambda scenario=scenario: curate_windows(scenario, CurationConfig()))
        curate_s += seconds
    return {
        "logs": len(logs),
        "frames": frames,
        "import_frames_per_s": frames / import_s,
        "write_frames_per_s": frames / write_s,
        "read_frames_per_s": frames / read_s,
        "curate_s_per_log": curate_s / len(logs),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=2, help="runs per figure; the fastest counts (default 2)")
    args = parser.parse_args()
    results: dict[str, Any] = {"machine": f"{platform.machine()}, {platform.python_version()}", "repeat": args.repeat}
    kitti_root = SHARED_DATA / "kitti_tracking_0000"
    with tempfile.TemporaryDirectory(prefix="bench_io_") as folder:
        workdir = Path(folder)
        if kitti_root.is_dir():
            kitti_velodyne_dir(kitti_root, "0000")  # unpack into the cache first: not part of the import figure
            results["kitti"] = bench_kitti(
                lambda: load_kitti_tracking(kitti_root, "0000"), workdir, args.repeat, "kitti_tracking_0000"
            )
            logs = sorted(path for path in (SHARED_DATA / "av2").glob("*-*-*-*-*") if path.is_dir())
            if logs:
                results["av2"] = bench_av2(logs, workdir, args.repeat)
        else:
            generated = _generated_log()
            results["kitti"] = bench_kitti(lambda: generated, workdir, args.repeat, "generated (no ../shared/data)")
    print(json.dumps(_rounded(results), indent=2))


def _rounded(value: Any) -> Any:
    if isinstance(value, float):
        return round(value, 3)
    if isinstance(value, dict):
        return {key: _rounded(item) for key, item in value.items()}
    return value


if __name__ == "__main__":
    main()
