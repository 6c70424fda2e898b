"""`advsim attack`, `replay` and `demo`: attacks, regression replays and the demo."""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import yaml
from tqdm import tqdm

from advsim_ros.adapters.profile import load_profile
from advsim_ros.attack import AttackError, AttackOptions, StackSpec, run_attack, search_notes
from advsim_ros.attack.follow import stack_log_tails
from advsim_ros.attack.outputs import recorded_score
from advsim_ros.attack.summary import comparison_table
from advsim_ros.cli.common import CommandError
from advsim_ros.core.attack_summary import AttackSummary
from advsim_ros.core.renamed import RENAMED_ALGORITHMS
from advsim_ros.core.search.registry import ALGORITHM_NAMES
from advsim_ros.io.bag import add_bag_params_option, bag_params_config
from advsim_ros.io.synthetic import SyntheticConfig, write_synthetic_bag
from advsim_ros.io.synthetic_families import FAMILY_NAMES


class _AlgorithmNames(tuple[str, ...]):
    """--algo's choices: the registry's names (shown in the help) and old names (AttackOptions warns, renames)."""

    def __contains__(self, name: object) -> bool:
        return super().__contains__(name) or name in RENAMED_ALGORITHMS


ALGORITHM_CHOICES = _AlgorithmNames(ALGORITHM_NAMES)
# the demo's scene: a lead car braking ahead, in which 20 BO queries find a collision of the reference stack
DEMO_FAMILY, DEMO_SEED = "lead_brake", 1


NO_VISUALS_HELP = "leave out bev.gif and report.html (seconds per attack; `advsim report OUTDIR` draws them later)"


def add_attack_commands(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    attack = subparsers.add_parser("attack", help="attack a stack on a scenario bag: search, bag out, summary, BEV")
    attack.add_argument("bag", type=Path, help="scenario bag (rosbag2 folder), e.g. from `advsim convert`")
    add_bag_params_option(attack)
    add_stack_arguments(attack)
    attack.add_argument("--algo", default="bo", choices=ALGORITHM_CHOICES, help="search algorithm (default bo)")
    attack.add_argument("--queries", type=int, default=75, help="search queries (default 75, the paper's BO budget)")
    attack.add_argument("--actors", type=int, default=1, help="actors perturbed at once (default 1)")
    attack.add_argument("--seed", type=int, default=0, help="seed of the search (default 0)")
    attack.add_argument(
        "--window-start", type=int, default=None, help="first frame of the 6 s window (default: the curated one)"
    )
    attack.add_argument(
        "--reruns",
        type=int,
        default=2,
        help="evaluate the best query, and the original, this many more times (default 2; 0: never)",
    )
    attack.add_argument("--rerun-top", type=int, default=1, help="re-run the N best queries (default 1)")
    attack.add_argument(
        "--lanes",
        type=int,
        default=1,
        help="evaluate up to N queries of a batch at once, each on its own graph and stack (default 1; the scores "
        "are the same; the algorithm's batch decides how many run together: docs/attack.md)",
    )
    attack.add_argument("--no-visuals", action="store_true", help=NO_VISUALS_HELP)
    attack.add_argument("-o", "--out", type=Path, required=True, help="output folder (re-using it resumes the run)")
    attack.set_defaults(run=_run_attack)

    replay = subparsers.add_parser("replay", help="re-run a stack on a saved adversarial scenario and score it")
    replay.add_argument("bag", type=Path, help="OUTDIR/adversarial of an attack")
    add_bag_params_option(replay)
    add_stack_arguments(replay)
    replay.add_argument("-o", "--out", type=Path, default=None, help="output folder (default: <bag>-replay)")
    replay.add_argument(
        "--check", action="store_true", help="exit 3 unless every run reproduces the recorded score (regression test)"
    )
    replay.add_argument("--runs", type=int, default=1, help="how many times to replay (default 1)")
    replay.add_argument("--no-visuals", action="store_true", help=NO_VISUALS_HELP)
    replay.add_argument("--tolerance", type=float, default=1e-6, help="--check: allowed |L_adv difference|")
    replay.set_defaults(run=_run_replay)

    demo = subparsers.add_parser(
        "demo", help="synthesize a street log with a staged interaction and attack the reference stack on it"
    )
    demo.add_argument("-o", "--out", type=Path, default=Path("out/demo"), help="output folder (default out/demo)")
    demo.add_argument("--queries", type=int, default=20, help="search queries (default 20)")
    demo.add_argument("--algo", default="bo", choices=ALGORITHM_CHOICES, help="search algorithm (default bo)")
    demo.add_argument(
        "--seed", type=int, default=DEMO_SEED, help=f"seed of the synthetic log and the search (default {DEMO_SEED})"
    )
    demo.add_argument(
        "--family", default=DEMO_FAMILY, choices=FAMILY_NAMES, help=f"synthetic scene family (default {DEMO_FAMILY})"
    )
    demo.set_defaults(run=_run_demo)


class _StackCommands(argparse.Action):
    """--stack, repeatable: the first one given replaces the default, each further one adds a process."""

    def __call__(
        self,
        parser: argparse.ArgumentParser,
        namespace: argparse.Namespace,
        values: str | Sequence[object] | None,
        option_string: str | None = None,
    ) -> None:
        given = getattr(namespace, self.dest)
        setattr(namespace, self.dest, [*([] if given is self.default else given), values])


def add_stack_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--stack",
        action=_StackCommands,
        default=["reference"],
        help='"reference" (modular, the default), "learned", or a command line that starts your stack; repeat it '
        "for a stack of several processes (the first is the main one; --remap applies to all)",
    )
    parser.add_argument(
        "--remap",
        action="append",
        default=[],
        metavar="CONTRACT:=YOURS",
        help="the topic your stack uses for a contract topic, e.g. /sensor/lidar/points:=/points_raw (repeatable)",
    )
    parser.add_argument("--remap-file", type=Path, default=None, help="YAML mapping of contract topic -> your topic")
    parser.add_argument(
        "--stack-profile",
        type=Path,
        default=None,
        metavar="FILE.yaml",
        help="how to start your stack and adapt it (processes, topics, types, frames, timer-driven planning; "
        "docs/stacks.md); replaces --stack and --remap",
    )
    parser.add_argument(
        "--remap-mode",
        choices=("relay", "rename"),
        default="relay",
        help="relay (default): the graph bridges your names, whatever starts your nodes; rename: pass "
        "-r YOURS:=CONTRACT to your command (only when it hands --ros-args to its node)",
    )
    parser.add_argument("--no-restart", action="store_true", help="do not restart the stack when it exits")
    parser.add_argument(
        "--loop",
        choices=("open", "closed"),
        default="open",
        help="open (default, the paper's): score the decision plan; closed: the ego drives the stack's plans for "
        "5 s, every sweep rendered where it is, and what it drove is scored (docs/attack.md)",
    )
    parser.add_argument(
        "--reactive-actors",
        action="store_true",
        help="with --loop closed: moving vehicles keep their paths but react to the ego's driving (IDM: they brake "
        "behind it instead of driving through it; docs/attack.md)",
    )
    parser.add_argument("--plan-timeout", type=float, default=10.0, help="longest wait for a plan per frame [s]")
    parser.add_argument(
        "--param",
        action="append",
        default=[],
        metavar="NODE.KEY=VALUE",
        help="a node parameter for this run, e.g. perturber.num_candidates=20000 (repeatable; VALUE is YAML)",
    )
    parser.add_argument(
        "--connect-timeout",
        type=float,
        default=120.0,
        help="longest wait for the stack to subscribe to the LiDAR and publish plans [s] (default 120)",
    )


def stack_spec(args: argparse.Namespace) -> StackSpec:
    if args.stack_profile is not None:
        if args.stack != ["reference"] or args.remap or args.remap_file is not None:
            raise CommandError("--stack-profile says how to start and connect the stack: leave out --stack and --remap")
        spec = StackSpec.from_profile(load_profile(args.stack_profile))
        return dataclasses.replace(spec, restart=spec.restart and not args.no_restart)
    remappings: dict[str, str] = {}
    if args.remap_file is not None:
        try:
            loaded = yaml.safe_load(args.remap_file.read_text(encoding="utf-8"))
        except yaml.YAMLError as error:
            raise CommandError(f"{args.remap_file}: not valid YAML ({error})") from error
        if not isinstance(loaded, dict) or not all(
            isinstance(k, str) and isinstance(v, str) for k, v in loaded.items()
        ):
            raise CommandError(f"{args.remap_file}: expected a mapping of topic names to topic names")
        remappings.update(loaded)
    for item in args.remap:
        source, separator, target = item.partition(":=")
        if not separator or not source or not target:
            raise CommandError(f"--remap {item!r}: expected FROM:=TO")
        remappings[source] = target
    spec = StackSpec.parse_all(args.stack, remappings)
    return dataclasses.replace(spec, restart=not args.no_restart, remap_mode=args.remap_mode)


# the values are YAML as parsed, nested by dotted key: untyped until each node's config checks its own
def parameter_overrides(items: Sequence[str]) -> dict[str, dict[str, Any]]:
    """--param NODE.KEY=VALUE items as {node: {key: value}} (dotted keys nest as in the params files)."""
    overrides: dict[str, dict[str, Any]] = {}
    for item in items:
        name, separator, text = item.partition("=")
        node, dot, key = name.partition(".")
        if not separator or not dot or not node or not key:
            raise CommandError(f"--param {item!r}: expected NODE.KEY=VALUE, e.g. perturber.num_candidates=20000")
        try:
            value = yaml.safe_load(text)
        except yaml.YAMLError as error:
            raise CommandError(f"--param {item!r}: the value is not valid YAML ({error})") from error
        entry = overrides.setdefault(node, {})
        *parents, leaf = key.split(".")
        for parent in parents:
            entry = entry.setdefault(parent, {})
        entry[leaf] = value
    return overrides


class _ProgressPrinter:
    """A tqdm bar over the attack's queries, shown from the first finished query on."""

    def __init__(self, total: int) -> None:
        self.total = total
        self.bars: list[tqdm] = []

    # progress: the attack's progress counts (attack.run passes them as a dict[str, Any])
    def __call__(self, progress: dict[str, Any]) -> None:
        bars = self.bars
        if not bars:
            bars.append(tqdm(total=self.total, unit="query", desc="attack", dynamic_ncols=True))
        bar = bars[0]
        bar.update(progress["journaled"] - bar.n)
        best = progress["best_adversarial_loss"]
        bar.set_postfix(best_L_adv="-" if math.isnan(best) else f"{best:.3f}", failed=progress["failed"])

    def close(self) -> None:
        for bar in self.bars:
            bar.close()


def _run_attack(args: argparse.Namespace) -> int:
    bag_config = bag_params_config(args.bag_params)
    options = AttackOptions(
        bag=args.bag,
        bag_config=bag_config,
        out_dir=args.out,
        stack=stack_spec(args),
        algorithm=args.algo,
        queries=args.queries,
        actors=args.actors,
        seed=args.seed,
        window_start_frame=args.window_start,
        plan_timeout=args.plan_timeout,
        connect_timeout=args.connect_timeout,
        reruns=args.reruns,
        rerun_top=args.rerun_top,
        parameter_overrides=parameter_overrides(args.param),
        loop=args.loop,
        lanes=args.lanes,
        reactive_actors=args.reactive_actors,
        visual_report=not args.no_visuals,
    )
    return _attack_and_report(options)


def _attack_and_report(options: AttackOptions) -> int:
    # the original, the search, the re-runs of the best, then the controls: the original again and the identity
    progress = _ProgressPrinter(options.queries + 1 + options.reruns * (options.rerun_top + 1) + 1)
    try:
        for note in search_notes(options):
            where = f"--algo {options.algorithm} --queries {options.queries}"
            print(f"advsim attack: note: {where}: {note}", file=sys.stderr)
        result = run_attack(options, progress)
    except AttackError as error:
        raise CommandError(str(error)) from error
    finally:
        progress.close()
    summary = result.summary
    print(comparison_table(summary))
    if summary["flaky"]:
        print(f"flaky: queries {summary['flaky']} did not reproduce when re-run (see summary.json 'reproductions')")
    _print_outputs(result.out_dir, summary)
    return _exit_code(options, result.out_dir, summary)


def _print_outputs(out_dir: Path, summary: AttackSummary) -> None:
    """Where to look: only the files this run left (a run whose queries failed has no adversarial bag or report)."""
    outputs = summary["outputs"]
    looks = [(outputs.get("report"), "report"), (outputs.get("bev_animation"), "animation")]
    shown = [f"{path} ({what})" for path, what in looks if path and Path(path).exists()]
    if shown:
        print(f"look at: {', '.join(shown)}")
    files = [outputs.get("adversarial_bag"), str(out_dir / "summary.json"), outputs.get("bev")]
    print(f"outputs: {'  '.join(str(path) for path in files if path and Path(path).exists())}")


def _exit_code(options: AttackOptions, out_dir: Path, summary: AttackSummary) -> int:
    """0 when the work succeeded (attack.verdict); else one line saying why, the stack's log tail, exit code 1."""
    verdict = summary["verdict"]
    if verdict["ok"]:
        return 0
    command = "replay" if options.replay_only else "attack"
    print(f"advsim {command}: error: {verdict['reason']}", file=sys.stderr)
    for line in stack_log_tails(out_dir, options.stack):
        print(line, file=sys.stderr)
    return 1


def _run_replay(args: argparse.Namespace) -> int:
    bag_config = bag_params_config(args.bag_params)
    out = args.out or args.bag.with_name(f"{args.bag.name}-replay")
    options = AttackOptions(
        bag=args.bag,
        bag_config=bag_config,
        out_dir=out,
        stack=stack_spec(args),
        queries=0,
        plan_timeout=args.plan_timeout,
        connect_timeout=args.connect_timeout,
        window_start_frame=0,
        replay_only=True,
        replay_runs=args.runs,
        parameter_overrides=parameter_overrides(args.param),
        loop=args.loop,
        reactive_actors=args.reactive_actors,
        visual_report=not args.no_visuals,
    )
    recorded = recorded_score(args.bag)
    try:
        result = run_attack(options)
    except AttackError as error:
        raise CommandError(str(error)) from error
    replayed = result.summary["replay"]["adversarial_losses"]
    expected = recorded.adversarial_loss if recorded is not None and recorded.ok else None
    reproduced = sum(1 for value in replayed if _same(value, expected, args.tolerance))
    print(f"recorded L_adv {expected}  replayed L_adv {', '.join(str(v) for v in replayed)}")
    print(f"reproduced {reproduced} of {len(replayed)} runs")
    _print_outputs(result.out_dir, result.summary)
    failed = _exit_code(options, result.out_dir, result.summary)
    if failed:
        return failed
    if args.check and reproduced < len(replayed):
        print("advsim replay: the replayed score differs from the recorded one", file=sys.stderr)
        return 3
    return 0


def _same(value: float | None, expected: float | None, tolerance: float) -> bool:
    return value is not None and expected is not None and abs(value - expected) <= tolerance


def _run_demo(args: argparse.Namespace) -> int:
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    bag = out / f"synthetic_{args.family}_seed{args.seed}"
    if not (bag / "metadata.yaml").exists():
        print(f"demo: synthesizing a street log ({args.family}, seed {args.seed}) into {bag}")
        write_synthetic_bag(bag, seed=args.seed, config=SyntheticConfig(family=args.family))
    options = AttackOptions(
        bag=bag,
        out_dir=out / "attack",
        stack=StackSpec.reference(),
        algorithm=args.algo,
        queries=args.queries,
        seed=args.seed,
    )
    print(f"demo: attacking the reference stack on {bag} with {options.algorithm}, {args.queries} queries")
    return _attack_and_report(options)
