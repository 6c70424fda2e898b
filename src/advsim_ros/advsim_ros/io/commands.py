"""What `advsim convert` and `advsim curate` do; cli.py parses their arguments and calls these."""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from advsim_ros.core.atomic import OutputExistsError
from advsim_ros.core.curation import (
    CurationConfig,
    CurationWindow,
    best_window,
    crop_scenario,
    curate_windows,
    load_curation_config,
)
from advsim_ros.core.types import Scenario, ScenarioError
from advsim_ros.io.av2 import load_av2_log
from advsim_ros.io.bag import BagConfig, load_bag_config, read_scenario_bag, summarize_bag, write_scenario_bag
from advsim_ros.io.kitti import load_kitti_tracking


@dataclass(frozen=True)
class ConversionReport:
    """What a conversion wrote, for the command's one-line summary."""

    output: Path
    scenario_id: str
    num_frames: int
    num_sweeps: int
    num_actors: int
    has_map: bool
    size_bytes: int  # storage files of the bag [bytes]
    seconds: float  # wall time of import and write [s]

    def describe(self) -> str:
        return (
            f"wrote {self.output}: {self.scenario_id}, {self.num_frames} frames, {self.num_sweeps} sweeps, "
            f"{self.num_actors} actors, map {'yes' if self.has_map else 'no'}, "
            f"{self.size_bytes / 1e6:.1f} MB in {self.seconds:.1f} s"
        )


def bag_config(params: Path | None) -> BagConfig:
    """The bag parameters from a params file, or the defaults (= params/bag.yaml)."""
    return load_bag_config(params) if params is not None else BagConfig()


def _write(
    scenario: Scenario, output: Path, source: str, config: BagConfig, overwrite: bool, started: float
) -> ConversionReport:
    write_scenario_bag(scenario, output, config=config, source=source, overwrite=overwrite)
    return ConversionReport(
        output=output,
        scenario_id=scenario.scenario_id,
        num_frames=scenario.num_frames,
        num_sweeps=len(scenario.sweeps),
        num_actors=len(scenario.actors),
        has_map=scenario.road_map is not None,
        size_bytes=summarize_bag(output).size_bytes,
        seconds=time.perf_counter() - started,
    )


def convert_kitti(
    root: Path,
    seq: str,
    output: Path,
    *,
    poses: Path | None = None,
    params: Path | None = None,
    overwrite: bool = False,
) -> ConversionReport:
    """KITTI tracking sequence -> scenario bag."""
    started = time.perf_counter()
    config = bag_config(params)
    scenario = load_kitti_tracking(root, seq, poses)
    return _write(scenario, output, f"kitti_tracking/{seq}", config, overwrite, started)


def convert_av2(
    log_dir: Path,
    output: Path,
    *,
    params: Path | None = None,
    overwrite: bool = False,
    lidar: str = "real",
    seed: int = 0,
) -> ConversionReport:
    """Argoverse 2 log -> scenario bag; ``lidar="simulate"`` renders a sweep per frame (io/av2_lidar.py)."""
    if lidar not in ("real", "simulate"):
        raise ScenarioError(f"--lidar must be 'real' or 'simulate', got {lidar!r}")
    started = time.perf_counter()
    config = bag_config(params)
    if output.exists() and not overwrite:  # before minutes of rendering
        raise OutputExistsError(f"{output} exists already; remove it or choose another output path")
    scenario = load_av2_log(log_dir)
    source = f"av2/{Path(log_dir).name}"
    if lidar == "simulate":
        from advsim_ros.io.av2_lidar import SIMULATED_SOURCE_NOTE, simulate_av2_lidar

        scenario = simulate_av2_lidar(scenario, Path(log_dir), np.random.default_rng(seed))
        source = f"{source}: {SIMULATED_SOURCE_NOTE}"
    return _write(scenario, output, source, config, overwrite, started)


@dataclass(frozen=True)
class CurationReport:
    """The candidate windows of one bag and the chosen one."""

    scenario_id: str
    windows: tuple[CurationWindow, ...]
    best: CurationWindow
    written: Path | None  # bag of the best window, when asked for

    def as_json(self) -> str:
        return json.dumps(
            {
                "scenario_id": self.scenario_id,
                "windows": [asdict(window) for window in self.windows],
                "best_start_frame": self.best.start_frame,
                "written": str(self.written) if self.written else None,
            },
            indent=2,
        )

    def as_table(self) -> str:
        first = self.windows[0].start_ns
        lines = [
            f"{self.scenario_id}: {len(self.windows)} windows",
            f"{'frames':>10} {'decision':>8} {'time [s]':>12} {'collision rate':>14} {'actors':>6}  lead vehicle",
        ]
        for window in self.windows:
            span = f"{(window.start_ns - first) * 1e-9:.1f}..{(window.end_ns - first) * 1e-9:.1f}"
            marker = "  <- best" if window == self.best else ""
            lines.append(
                f"{window.start_frame:>4}..{window.end_frame:<5} {window.decision_frame:>8} {span:>12} "
                f"{window.collision_rate:>14.3f} {window.num_actors:>6}  {window.lead_actor_id or '-'}{marker}"
            )
        if self.written:
            lines.append(f"wrote the best window to {self.written}")
        return "\n".join(lines)


def curate_bag(
    bag: Path,
    *,
    params: Path | None = None,
    bag_config: BagConfig | None = None,
    output: Path | None = None,
    overwrite: bool = False,
) -> CurationReport:
    """Rank a bag's candidate windows by collision rate; optionally write the best window as a bag."""
    config = load_curation_config(params) if params is not None else CurationConfig()
    bags = bag_config or BagConfig()
    scenario = read_scenario_bag(bag, config=bags, load_sweeps=output is not None)
    windows = curate_windows(scenario, config)
    best = best_window(windows)
    if output is not None:
        write_scenario_bag(
            crop_scenario(scenario, best), output, config=bags, source=f"curated/{bag}", overwrite=overwrite
        )
    return CurationReport(scenario_id=scenario.scenario_id, windows=windows, best=best, written=output)
