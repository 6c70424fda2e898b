"""The `advsim` command: one subcommand per job; each parses arguments and calls its module."""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import signal
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import yaml
from tqdm import tqdm

from advsim_ros import __version__
from advsim_ros.attack import AttackError, AttackOptions, StackSpec, run_attack
from advsim_ros.attack.outputs import recorded_score
from advsim_ros.core.search.registry import ALGORITHM_NAMES
from advsim_ros.io.synthetic import write_synthetic_bag
from advsim_ros.ros.launcher import LaunchError


class CommandError(RuntimeError):
    """A command failed for a reason the user can act on; printed without a traceback."""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="advsim",
        description="AdvSim for ROS 2: find safety-critical scenarios for a LiDAR-based autonomy stack.",
    )
    parser.add_argument("--version", action="version", version=f"advsim_ros {__version__}")
    subparsers = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    # each area adds its commands here through _add_<name>_commands(subparsers)
    _add_data_commands(subparsers)
    _add_label_commands(subparsers)
    _add_synth_commands(subparsers)
    _add_attack_commands(subparsers)
    _add_stack_commands(subparsers)
    # issue 17: `advsim report OUTDIR` and `advsim export openscenario BAG -o FILE`
    from advsim_ros.export.command import add_export_commands
    from advsim_ros.viz.command import add_viz_commands

    add_viz_commands(subparsers)
    add_export_commands(subparsers)
    return parser


def _add_data_commands(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """`advsim convert kitti|av2` and `advsim curate` (logic in advsim_ros.io.commands)."""
    from advsim_ros.io import commands

    bag_params = {"type": Path, "default": None, "help": "bag topics and frames (default: params/bag.yaml values)"}
    convert = subparsers.add_parser("convert", help="convert a driving log into a scenario bag (rosbag2, MCAP)")
    sources = convert.add_subparsers(dest="source", required=True, metavar="SOURCE")

    kitti = sources.add_parser("kitti", help="KITTI tracking sequence (velodyne/, label_02/, calib/, poses/)")
    kitti.add_argument("root", type=Path, help="dataset folder, e.g. ../shared/data/kitti_tracking_0000")
    kitti.add_argument("--seq", default="0000", help="sequence number (default 0000)")
    kitti.add_argument("--poses", type=Path, default=None, help="poses file (default: root/poses/<seq>_*velo*.txt)")
    kitti.add_argument("-o", "--output", type=Path, required=True, help="bag folder to write")
    kitti.add_argument("--params", **bag_params)
    kitti.add_argument("--overwrite", action="store_true", help="replace an existing output bag")
    kitti.set_defaults(
        run=lambda args: _report(
            commands.convert_kitti(
                args.root, args.seq, args.output, poses=args.poses, params=args.params, overwrite=args.overwrite
            ).describe()
        )
    )

    av2 = sources.add_parser("av2", help="Argoverse 2 log (annotations, ego poses, vector map, LiDAR if present)")
    av2.add_argument("log_dir", type=Path, help="log folder, e.g. ../shared/data/av2/<log id>")
    av2.add_argument("-o", "--output", type=Path, required=True, help="bag folder to write")
    av2.add_argument("--params", **bag_params)
    av2.add_argument("--overwrite", action="store_true", help="replace an existing output bag")
    av2.add_argument(
        "--lidar",
        choices=("real", "simulate"),
        default="real",
        help="real: the log's own sweeps (1-2 or none); simulate: a ray-cast sweep every frame (docs/data.md)",
    )
    av2.add_argument("--seed", type=int, default=0, help="seed of the simulated LiDAR's noise and ray drop")
    av2.set_defaults(
        run=lambda args: _report(
            commands.convert_av2(
                args.log_dir,
                args.output,
                params=args.params,
                overwrite=args.overwrite,
                lidar=args.lidar,
                seed=args.seed,
            ).describe()
        )
    )

    curate = subparsers.add_parser("curate", help="rank a bag's 6 s windows by the collision rate of sampled plans")
    curate.add_argument("bag", type=Path, help="scenario bag (or a bag of your own, see --bag-params)")
    curate.add_argument("--params", type=Path, default=None, help="curation settings (default: params/curation.yaml)")
    curate.add_argument("--bag-params", **bag_params)
    curate.add_argument("-o", "--output", type=Path, default=None, help="also write the best window as a bag")
    curate.add_argument("--overwrite", action="store_true", help="replace an existing output bag")
    curate.add_argument("--json", action="store_true", help="print the windows as JSON")
    curate.set_defaults(run=_run_curate)


def _add_label_commands(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """`advsim label`: actor tracks (and ego poses if missing) for a LiDAR bag (logic in labelling.command)."""
    label = subparsers.add_parser(
        "label", help="auto-label a bag of LiDAR: actor tracks, and KISS-ICP ego poses when it has none"
    )
    label.add_argument("bag", type=Path, help="rosbag2 folder with a PointCloud2 topic (see --bag-params)")
    label.add_argument("-o", "--output", type=Path, required=True, help="scenario bag to write")
    label.add_argument(
        "--tracks-topic", default=None, help="take the tracks from this topic (ActorTrackArray or MarkerArray cubes)"
    )
    label.add_argument("--mount", default=None, help="LiDAR mount in the ego frame: x,y,z,roll,pitch,yaw [m, rad]")
    label.add_argument("--params", type=Path, default=None, help="labeller settings (default: params/labelling.yaml)")
    label.add_argument("--bag-params", type=Path, default=None, help="bag topics and frames (default: params/bag.yaml)")
    label.add_argument("--overwrite", action="store_true", help="replace an existing output bag")
    label.set_defaults(run=_run_label)


def _run_label(args: argparse.Namespace) -> int:
    from advsim_ros.io.bag import load_bag_config
    from advsim_ros.labelling.command import label_bag
    from advsim_ros.labelling.odometry import mount_from_string

    report = label_bag(
        args.bag,
        args.output,
        tracks_topic=args.tracks_topic,
        mount=mount_from_string(args.mount) if args.mount is not None else None,
        params=args.params,
        bag_config=load_bag_config(args.bag_params) if args.bag_params is not None else None,
        overwrite=args.overwrite,
    )
    return _report(report.describe())


def _run_curate(args: argparse.Namespace) -> int:
    from advsim_ros.io import commands

    report = commands.curate_bag(
        args.bag, params=args.params, bag_params=args.bag_params, output=args.output, overwrite=args.overwrite
    )
    return _report(report.as_json() if args.json else report.as_table())


def _add_synth_commands(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """`advsim synth`: a synthetic street log as a scenario bag (logic in advsim_ros.io.synthetic)."""
    synth = subparsers.add_parser("synth", help="generate a synthetic street log (meshes, 64-beam LiDAR) as a bag")
    synth.add_argument("-o", "--output", type=Path, required=True, help="bag folder to write")
    synth.add_argument("--seed", type=int, default=0, help="seed of the street, its actors and the sensor noise")
    synth.add_argument("--duration", type=float, default=None, help="log length [s] (default 8)")
    synth.add_argument(
        "--params", type=Path, default=None, help="bag topics and frames (default: params/bag.yaml values)"
    )
    synth.add_argument("--overwrite", action="store_true", help="replace an existing output bag")
    synth.set_defaults(run=_run_synth)


def _run_synth(args: argparse.Namespace) -> int:
    import time

    from advsim_ros.io.bag import load_bag_config
    from advsim_ros.io.synthetic import SyntheticConfig

    started = time.perf_counter()
    config = SyntheticConfig() if args.duration is None else SyntheticConfig(duration=args.duration)
    bag_config = load_bag_config(args.params) if args.params is not None else None
    path = write_synthetic_bag(
        args.output, seed=args.seed, config=config, bag_config=bag_config, overwrite=args.overwrite
    )
    return _report(
        f"wrote {path}: synthetic_{args.seed}, {config.num_frames} frames in {time.perf_counter() - started:.1f} s"
    )


def _report(text: str) -> int:
    print(text)
    return 0


def _add_stack_commands(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """`advsim stack run|sanity` and `advsim train-il` (logic in advsim_ros.stacks.commands)."""
    from advsim_ros.stacks import commands

    kitti_default = Path(__file__).resolve().parents[3] / ".." / "shared" / "data" / "kitti_tracking_0000"
    stack = subparsers.add_parser("stack", help="run a reference stack on its own: on a bag, or the sanity table")
    actions = stack.add_subparsers(dest="action", required=True, metavar="ACTION")

    run = actions.add_parser("run", help="replay a scenario bag through a stack; print (and save) plans and metrics")
    run.add_argument("stack", choices=commands.STACK_NAMES, help="modular (= reference) or learned")
    run.add_argument(
        "--bag", type=Path, required=True, help="scenario bag (rosbag2 folder), e.g. from `advsim convert`"
    )
    run.add_argument("-o", "--out", type=Path, default=None, help="folder for plans.npz and summary.json")
    run.add_argument("--params", type=Path, default=None, help="stack parameters (default params/stack_<stack>.yaml)")
    run.add_argument("--weights", type=Path, default=None, help="learned stack weights (default: the packaged ones)")
    run.set_defaults(
        run=lambda args: _report(
            json.dumps(
                dataclasses.asdict(commands.run_on_bag(args.stack, args.bag, args.out, args.params, args.weights)),
                indent=2,
            )
        )
    )

    check = actions.add_parser("sanity", help="both stacks on unperturbed KITTI windows and synthetic logs, Car AP")
    check.add_argument("--kitti", type=Path, default=kitti_default, help="KITTI tracking folder (default: shared data)")
    check.add_argument("--no-kitti", action="store_true", help="synthetic logs only")
    check.add_argument("--synthetic-seeds", type=int, nargs="*", default=[0, 1, 2], help="synthetic logs (held out)")
    check.add_argument("--stride", type=int, default=10, help="frames between decision frames (default 10)")
    check.add_argument("--stacks", nargs="+", default=["modular", "learned"], choices=commands.STACK_NAMES)
    check.add_argument("-o", "--out", type=Path, default=None, help="write the report as JSON (and .md beside it)")
    check.set_defaults(
        run=lambda args: _report(
            commands.save_sanity(
                commands.sanity(
                    None if args.no_kitti else args.kitti,
                    args.synthetic_seeds,
                    args.stride,
                    args.stacks,
                    log=lambda text: print(text, file=sys.stderr),
                ),
                args.out,
            )
        )
    )

    train = subparsers.add_parser("train-il", help="train the learned stack's planner (reproducible, CPU)")
    train.add_argument("-o", "--out", type=Path, required=True, help="weights file to write")
    train.add_argument("--kitti", type=Path, default=kitti_default, help="KITTI tracking folder (default: shared data)")
    train.add_argument("--no-kitti", action="store_true", help="synthetic logs only")
    train.add_argument("--params", type=Path, default=None, help="parameters (default params/stack_learned.yaml)")
    train.add_argument("--epochs", type=int, default=None, help="override training.epochs")
    train.set_defaults(
        run=lambda args: _report(
            json.dumps(
                commands.train_il_command(
                    args.out,
                    None if args.no_kitti else args.kitti,
                    args.params,
                    args.epochs,
                    log=lambda text: print(text, file=sys.stderr),
                ),
                indent=2,
            )
        )
    )


def _add_attack_commands(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    attack = subparsers.add_parser("attack", help="attack a stack on a scenario bag: search, bag out, summary, BEV")
    attack.add_argument("bag", type=Path, help="scenario bag (rosbag2 folder), e.g. from `advsim convert`")
    _add_stack_arguments(attack)
    attack.add_argument("--algo", default="bo", choices=ALGORITHM_NAMES, help="search algorithm (default bo)")
    attack.add_argument("--queries", type=int, default=75, help="search queries (default 75, the paper's BO budget)")
    attack.add_argument("--actors", type=int, default=1, help="actors perturbed at once (default 1)")
    attack.add_argument("--seed", type=int, default=0, help="seed of the search (default 0)")
    attack.add_argument(
        "--window-start", type=int, default=None, help="first frame of the 6 s window (default: the curated one)"
    )
    attack.add_argument(
        "--reruns", type=int, default=2, help="evaluate the best query this many more times (default 2; 0: never)"
    )
    attack.add_argument("--rerun-top", type=int, default=1, help="re-run the N best queries (default 1)")
    attack.add_argument("-o", "--out", type=Path, required=True, help="output folder (re-using it resumes the run)")
    attack.set_defaults(run=_run_attack)

    replay = subparsers.add_parser("replay", help="re-run a stack on a saved adversarial scenario and score it")
    replay.add_argument("bag", type=Path, help="OUTDIR/adversarial of an attack")
    _add_stack_arguments(replay)
    replay.add_argument("-o", "--out", type=Path, default=None, help="output folder (default: <bag>-replay)")
    replay.add_argument(
        "--check", action="store_true", help="exit 3 unless every run reproduces the recorded score (regression test)"
    )
    replay.add_argument("--runs", type=int, default=1, help="how many times to replay (default 1)")
    replay.add_argument("--tolerance", type=float, default=1e-6, help="--check: allowed |L_adv difference|")
    replay.set_defaults(run=_run_replay)

    demo = subparsers.add_parser("demo", help="synthesize a street log and attack the reference stack on it")
    demo.add_argument("-o", "--out", type=Path, default=Path("out/demo"), help="output folder (default out/demo)")
    demo.add_argument("--queries", type=int, default=20, help="search queries (default 20)")
    demo.add_argument("--algo", default="bo", choices=ALGORITHM_NAMES, help="search algorithm (default bo)")
    demo.add_argument("--seed", type=int, default=0, help="seed of the synthetic log and the search")
    demo.set_defaults(run=_run_demo)


def _add_stack_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--stack",
        default="reference",
        help='"reference" (modular), "learned", or a command line that starts your stack',
    )
    parser.add_argument(
        "--remap",
        action="append",
        default=[],
        metavar="FROM:=TO",
        help="topic remapping for the stack, e.g. /sensor/lidar/points:=/points_raw (repeatable)",
    )
    parser.add_argument("--remap-file", type=Path, default=None, help="YAML mapping of contract topic -> your topic")
    parser.add_argument("--no-restart", action="store_true", help="do not restart the stack when it exits")
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


def _stack_spec(args: argparse.Namespace) -> StackSpec:
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
    spec = StackSpec.parse(args.stack, remappings)
    return dataclasses.replace(spec, restart=not args.no_restart)


def _parameter_overrides(items: Sequence[str]) -> dict[str, dict[str, Any]]:
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


def _progress_printer(total: int) -> Any:
    """A tqdm bar over the attack's queries, shown from the first finished query on."""
    bars: list[Any] = []

    def update(progress: dict[str, Any]) -> None:
        if not bars:
            bars.append(tqdm(total=total, unit="query", desc="attack", dynamic_ncols=True))
        bar = bars[0]
        bar.update(progress["journaled"] - bar.n)
        best = progress["best_adversarial_loss"]
        bar.set_postfix(best_L_adv="-" if math.isnan(best) else f"{best:.3f}", failed=progress["failed"])

    def close() -> None:
        for bar in bars:
            bar.close()

    update.close = close  # type: ignore[attr-defined]
    return update


def _run_attack(args: argparse.Namespace) -> int:
    options = AttackOptions(
        bag=args.bag,
        out_dir=args.out,
        stack=_stack_spec(args),
        algorithm=args.algo,
        queries=args.queries,
        actors=args.actors,
        seed=args.seed,
        window_start_frame=args.window_start,
        plan_timeout=args.plan_timeout,
        connect_timeout=args.connect_timeout,
        reruns=args.reruns,
        rerun_top=args.rerun_top,
        parameter_overrides=_parameter_overrides(args.param),
    )
    return _attack_and_report(options)


def _attack_and_report(options: AttackOptions) -> int:
    progress = _progress_printer(options.queries + 1 + options.reruns * options.rerun_top)
    try:
        result = run_attack(options, progress)
    except AttackError as error:
        raise CommandError(str(error)) from error
    finally:
        progress.close()
    summary = result.summary
    original, adversarial = summary["original"] or {}, summary["adversarial"] or {}
    print(f"original    L_adv {original.get('adversarial_loss')}  collision@5s {original.get('collision_5s')}")
    print(f"adversarial L_adv {adversarial.get('adversarial_loss')}  collision@5s {adversarial.get('collision_5s')}")
    if summary["flaky"]:
        print(f"flaky: queries {summary['flaky']} did not reproduce when re-run (see summary.json 'reproductions')")
    print(f"outputs: {result.out_dir}/adversarial  {result.out_dir}/summary.json  {result.out_dir}/bev.png")
    return 0


def _run_replay(args: argparse.Namespace) -> int:
    out = args.out or args.bag.with_name(f"{args.bag.name}-replay")
    options = AttackOptions(
        bag=args.bag,
        out_dir=out,
        stack=_stack_spec(args),
        queries=0,
        plan_timeout=args.plan_timeout,
        connect_timeout=args.connect_timeout,
        window_start_frame=0,
        replay_only=True,
        replay_runs=args.runs,
        parameter_overrides=_parameter_overrides(args.param),
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
    print(f"outputs: {out}/summary.json  {out}/bev.png")
    if args.check and reproduced < len(replayed):
        print("advsim replay: the replayed score differs from the recorded one", file=sys.stderr)
        return 3
    return 0


def _same(value: float | None, expected: float | None, tolerance: float) -> bool:
    return value is not None and expected is not None and abs(value - expected) <= tolerance


def _run_demo(args: argparse.Namespace) -> int:
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    bag = out / f"synthetic_log_seed{args.seed}"
    if not (bag / "metadata.yaml").exists():
        print(f"demo: synthesizing a street log (seed {args.seed}) into {bag}")
        write_synthetic_bag(bag, seed=args.seed)
    options = AttackOptions(
        bag=bag,
        out_dir=out / "attack",
        stack=StackSpec.reference(),
        algorithm=args.algo,
        queries=args.queries,
        seed=args.seed,
    )
    print(f"demo: attacking the reference stack on {bag} with {args.algo}, {args.queries} queries")
    return _attack_and_report(options)


class Terminated(Exception):  # noqa: N818 - named after the signal
    """SIGTERM arrived: stop like Ctrl-C does, with exit code 143."""


def _on_sigterm(signum: int, frame: object) -> None:
    raise Terminated


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    previous = signal.signal(signal.SIGTERM, _on_sigterm)
    try:
        result: int = args.run(args)
    except (CommandError, ValueError, OSError, AttackError, LaunchError) as error:
        print(f"advsim {args.command}: error: {error}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(
            f"advsim {args.command}: interrupted; finished queries are kept (run the same command to resume)",
            file=sys.stderr,
        )
        return 130
    except Terminated:
        print(
            f"advsim {args.command}: terminated; finished queries are kept (run the same command to resume)",
            file=sys.stderr,
        )
        return 143
    finally:
        signal.signal(signal.SIGTERM, previous)
    return result


if __name__ == "__main__":
    sys.exit(main())
