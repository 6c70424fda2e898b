"""The `advsim stack run|sanity` and `advsim train-il` commands (cli.py only parses and calls these)."""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from advsim_ros.core.futures import actor_futures_at
from advsim_ros.core.metrics import (
    MetricsConfig,
    aggregate_metrics,
    plan_from_decision,
    query_metrics,
)
from advsim_ros.core.types import Scenario
from advsim_ros.stacks.evaluation import (
    FUTURE_FRAMES,
    SanityReport,
    SanityRow,
    car_detection_ap,
    evaluate_windows,
    sanity_row,
    write_report,
)
from advsim_ros.stacks.interface import AutonomyStack, StackError
from advsim_ros.stacks.replay import replay

if TYPE_CHECKING:
    from advsim_ros.io.bag import BagConfig

STACK_NAMES = ("modular", "reference", "learned")  # "reference" is the modular stack, as in `advsim attack`


def make_stack(name: str, params: Path | None = None, weights: Path | None = None) -> AutonomyStack:
    """A reference stack by name, configured from its params file (default params/stack_<name>.yaml)."""
    if name in ("modular", "reference"):
        from advsim_ros.stacks.modular.config import load_modular_config
        from advsim_ros.stacks.modular.stack import ModularStack

        return ModularStack(load_modular_config(params))
    if name == "learned":
        from advsim_ros.stacks.learned.config import load_learned_config
        from advsim_ros.stacks.learned.stack import LearnedStack

        return LearnedStack(load_learned_config(params), weights)
    raise StackError(f"unknown stack {name!r}: choose one of {', '.join(STACK_NAMES)}")


def _publish_dir(staged: Path, target: Path) -> None:
    """Move a finished folder into place (replacing an older one) so that no partial output is left."""
    if target.exists():
        backup = Path(tempfile.mkdtemp(prefix=f".{target.name}.old.", dir=target.parent))
        os.replace(target, backup / target.name)
        os.replace(staged, target)
        shutil.rmtree(backup, ignore_errors=True)
    else:
        os.replace(staged, target)


@dataclass(frozen=True)
class RunSummary:
    """What `advsim stack run` did on a bag."""

    stack: str
    bag: str
    scenario_id: str
    sweeps: int  # sweeps planned from
    scored_plans: int  # plans with a full horizon of logged future to score against
    median_step_ms: float  # median wall time of one stack step [ms]
    collision_3s: float  # share of scored plans colliding with a logged actor within 3 s [1]
    collision_5s: float
    l2_3s: float  # mean distance to the human trajectory at 3 s [m]
    l2_5s: float
    lateral_acceleration: float  # mean of the per-plan largest |lateral acceleration| [m/s^2]
    jerk: float  # mean of the per-plan largest |jerk| [m/s^3]
    output: str  # folder with plans.npz and summary.json ("" when not saved)


def run_on_bag(
    stack_name: str,
    bag: Path,
    out: Path | None,
    params: Path | None = None,
    weights: Path | None = None,
    bag_config: BagConfig | None = None,
) -> RunSummary:
    """Replay every sweep of a scenario bag (in ``bag_config``'s layout, --bag-params) through the stack, as the
    topics would deliver them; score the plans.

    Plans are scored (core.metrics) against the bag's ego trajectory and actor tracks
    wherever the log continues for the full horizon. With `out`, plans.npz (per sweep:
    stamp, plan stamps, positions, headings) and summary.json are written to that folder.
    """
    from advsim_ros.io.bag import read_scenario_bag

    stack = make_stack(stack_name, params, weights)
    scenario = read_scenario_bag(bag, config=bag_config, load_sweeps=True)
    steps = replay(stack, scenario)
    if not steps:
        raise StackError(f"{bag}: the bag has no LiDAR sweeps to plan from")
    metrics_config = MetricsConfig()
    scored = []
    for step in steps:
        if step.frame_index + FUTURE_FRAMES < scenario.num_frames:
            stamp = int(scenario.frame_stamps_ns[step.frame_index])
            plan = plan_from_decision(step.output.plan, scenario.ego.poses[step.frame_index], stamp)
            actors = actor_futures_at(scenario.actors, plan.stamps_ns, metrics_config.actor_extrapolation)
            scored.append(query_metrics(plan, scenario.ego, actors, scenario.ego_geometry, metrics_config))
    nan = float("nan")
    total = aggregate_metrics(scored) if scored else None
    summary = RunSummary(
        stack=stack.name,
        bag=str(bag),
        scenario_id=scenario.scenario_id,
        sweeps=len(steps),
        scored_plans=len(scored),
        median_step_ms=float(1000.0 * np.median([step.output.timings_s.get("total", nan) for step in steps])),
        collision_3s=float(total.collision_rate[0]) if total else nan,
        collision_5s=float(total.collision_rate[1]) if total else nan,
        l2_3s=float(total.l2_human[0]) if total else nan,
        l2_5s=float(total.l2_human[1]) if total else nan,
        lateral_acceleration=float(total.lateral_acceleration) if total else nan,
        jerk=float(total.jerk) if total else nan,
        output=str(out) if out is not None else "",
    )
    if out is not None:
        out.parent.mkdir(parents=True, exist_ok=True)
        staged = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
        try:
            np.savez_compressed(
                staged / "plans.npz",
                sweep_stamps_ns=np.array([scenario.frame_stamps_ns[step.frame_index] for step in steps]),
                plan_stamps_ns=np.stack([step.output.plan.stamps_ns for step in steps]),
                plan_xy=np.stack([step.output.plan.xy for step in steps]),
                plan_yaws=np.stack([step.output.plan.yaws for step in steps]),
            )
            (staged / "summary.json").write_text(json.dumps(asdict(summary), indent=2) + "\n")
            _publish_dir(staged, out)
        finally:
            if staged.exists():
                shutil.rmtree(staged, ignore_errors=True)
    return summary


def kitti_car_ids(root: Path, sequence: str) -> tuple[set[str], set[str]]:
    """Track ids of KITTI Cars, and of Vans / Trucks / Trams (ignored for Car AP)."""
    from advsim_ros.io.kitti import read_kitti_labels

    kinds = {str(label.track_id): label.kind for label in read_kitti_labels(root / "label_02" / f"{sequence}.txt")}
    cars = {track for track, kind in kinds.items() if kind == "Car"}
    others = {track for track, kind in kinds.items() if kind in ("Van", "Truck", "Tram")}
    return cars, others


def sanity(
    kitti_root: Path | None,
    synthetic_seeds: Sequence[int],
    stride: int = 10,
    stacks: Sequence[str] = ("modular", "learned"),
    log: Callable[[str], None] | None = None,
) -> SanityReport:
    """The sanity table: each stack on KITTI windows and synthetic logs (unperturbed), and the detector's Car AP."""
    from advsim_ros.io.synthetic import SyntheticConfig, generate_synthetic_log
    from advsim_ros.stacks.learned.config import LearnedStackConfig

    say = log or (lambda _: None)
    data: list[tuple[str, Scenario, Callable[[int], bool] | None]] = []
    notes: list[str] = []
    held_out = LearnedStackConfig().training.kitti_last_decision
    sequence = LearnedStackConfig().training.kitti_sequence
    kitti = None
    if kitti_root is not None:
        from advsim_ros.io.kitti import load_kitti_tracking

        kitti = load_kitti_tracking(kitti_root, sequence)
        data.append((f"KITTI {sequence}, all windows", kitti, None))
        data.append((f"KITTI {sequence}, decision > frame {held_out}", kitti, lambda frame: frame > held_out))
        notes.append(
            f"The learned planner trained on KITTI {sequence} decisions up to frame {held_out}: its rows on all "
            f"KITTI windows include training data; the 'decision > frame {held_out}' rows do not."
        )
    duration = LearnedStackConfig().training.synthetic_duration
    for seed in synthetic_seeds:
        say(f"generating synthetic log {seed}")
        log_scenario = generate_synthetic_log(
            np.random.default_rng(seed), SyntheticConfig(duration=duration), f"synthetic_{seed}"
        ).scenario
        data.append((f"synthetic seed {seed}", log_scenario, None))
    if not data:
        raise StackError("nothing to evaluate: give a KITTI folder or synthetic seeds")
    rows: list[SanityRow] = []
    for stack_name in stacks:
        stack = make_stack(stack_name)
        synthetic_results = []
        for label, scenario, keep in data:
            say(f"{stack_name}: {label}")
            results = evaluate_windows(stack, scenario, MetricsConfig(), stride, keep)
            if label.startswith("synthetic"):
                synthetic_results.extend(results)
            else:
                rows.append(sanity_row(stack_name, label, results))
        if synthetic_results:
            seeds = ", ".join(str(seed) for seed in synthetic_seeds)
            rows.append(sanity_row(stack_name, f"synthetic seeds {seeds}", synthetic_results))
    detection = None
    if kitti is not None and kitti_root is not None and "modular" in stacks:
        say("modular: Car BEV AP on every KITTI sweep")
        cars, others = kitti_car_ids(kitti_root, sequence)
        detection = car_detection_ap(make_stack("modular"), kitti, cars, others)
    notes.append(
        f"Windows: 1 s of LiDAR ({10} sweeps from a reset), plan scored over 5 s; decisions {stride} frames apart."
    )
    return SanityReport(rows=rows, detection=detection, notes=notes)


def train_il_command(
    out: Path,
    kitti_root: Path | None,
    params: Path | None,
    epochs: int | None,
    log: Callable[[str], None],
    scheme: str = "standard",
    adversarial_dir: Path | Sequence[Path] | None = None,
) -> dict[str, object]:
    """Train the learned planner and write its weights; returns the training report as a dict.

    Curriculum training ranks windows with the curation parameters (params/curation.yaml, as campaigns do).
    Robust training trains on the train-split shards of every ``adversarial_dir`` and stops early on
    their validation-split shards too (never on test ones).
    """
    from advsim_ros.core.curation import CurationConfig, load_curation_config
    from advsim_ros.stacks.learned.config import load_learned_config
    from advsim_ros.stacks.learned.dataset import training_shards
    from advsim_ros.stacks.learned.train import train_il
    from advsim_ros.stacks.params import default_params_file

    if adversarial_dir is not None and scheme != "robust":
        raise StackError(f"--adversarial: only --scheme robust trains on found scenarios, not {scheme}")
    config = load_learned_config(params)
    if epochs is not None:
        old = config.training
        training = replace(old, epochs=epochs) if scheme == "standard" else replace(old, finetune_epochs=epochs)
        config = replace(config, training=training)
    folders = [adversarial_dir] if isinstance(adversarial_dir, Path) else list(adversarial_dir or [])
    adversarial, adversarial_validation = [], []
    for folder in folders:
        train, validation = training_shards(folder), training_shards(folder, "validation")
        log(f"{folder}: {sum(p.count for p in train)} adversarial samples of the train split, "
            f"{sum(p.count for p in validation)} of the validation split")  # fmt: skip
        adversarial += train
        adversarial_validation += validation
    curation_file = default_params_file("curation.yaml")
    curation = load_curation_config(curation_file) if curation_file.is_file() else CurationConfig()
    report = train_il(config, kitti_root, out, log, scheme, adversarial, curation, adversarial_validation)
    return asdict(report)


def save_sanity(report: SanityReport, out: Path | None) -> str:
    """Markdown of the report; with `out`, the JSON there (and .md beside it), atomically."""
    if out is not None:
        write_report(report, out)
    return report.markdown()
