"""`advsim stack run|sanity` and `advsim train-il`: the reference stacks on their own."""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

from advsim_ros.cli.common import print_result
from advsim_ros.io.bag import add_bag_params_option, bag_params_config


def add_stack_commands(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """`advsim stack run|sanity` and `advsim train-il` (logic in advsim_ros.stacks.commands)."""
    from advsim_ros.stacks import commands

    kitti_default = Path(__file__).resolve().parents[4] / ".." / "shared" / "data" / "kitti_tracking_0000"
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
    add_bag_params_option(run)
    run.set_defaults(
        run=lambda args: print_result(
            json.dumps(
                dataclasses.asdict(
                    commands.run_on_bag(
                        args.stack, args.bag, args.out, args.params, args.weights, bag_params_config(args.bag_params)
                    )
                ),
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
        run=lambda args: print_result(
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
    train.add_argument(
        "--epochs", type=int, default=None,
        help="override training.epochs (curriculum, robust: training.finetune_epochs)",
    )  # fmt: skip
    train.add_argument(
        "--scheme", default="standard", choices=("standard", "curriculum", "robust"),
        help="standard: from scratch on the logs; curriculum: fine-tune on the logs plus their hardest train "
        "windows by curation rate; robust: fine-tune on the logs plus found scenarios (--adversarial)",
    )  # fmt: skip
    train.add_argument(
        "--adversarial", type=Path, action="append", default=None,
        help="an `advsim export training` folder: its train split is trained on, its validation split joins early "
        "stopping (repeatable)",
    )  # fmt: skip
    train.set_defaults(
        run=lambda args: print_result(
            json.dumps(
                commands.train_il_command(
                    args.out,
                    None if args.no_kitti else args.kitti,
                    args.params,
                    args.epochs,
                    lambda text: print(text, file=sys.stderr),
                    args.scheme,
                    args.adversarial,
                ),
                indent=2,
            )
        )
    )


def add_training_export_command(formats: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """`advsim export training SUITE -o DIR` (logic in advsim_ros.stacks.learned.dataset)."""
    training = formats.add_parser(
        "training", help="found scenarios as learned-stack training samples: one .npz shard each, split by window"
    )
    training.add_argument("suite", type=Path, help="a regression suite: OUTDIR/suite of `advsim campaign`")
    training.add_argument("-o", "--output", type=Path, required=True, help="folder for the shards and index.json")
    training.add_argument("--params", type=Path, default=None, help="learned stack parameters (raster, split)")
    training.set_defaults(run=_run_training_export)


def _run_training_export(args: argparse.Namespace) -> int:
    from advsim_ros.stacks.learned.config import load_learned_config
    from advsim_ros.stacks.learned.dataset import export_training

    config = load_learned_config(args.params)
    written = export_training(args.suite, args.output, config, progress=lambda text: print(text, file=sys.stderr))
    return print_result(written.describe())
