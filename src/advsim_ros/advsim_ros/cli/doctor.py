"""`advsim doctor`: how a stack connects to the contract (logic in advsim_ros.attack.doctor)."""

from __future__ import annotations

import argparse
from pathlib import Path

from advsim_ros.attack import AttackOptions
from advsim_ros.cli.attack import add_stack_arguments, parameter_overrides, stack_spec
from advsim_ros.io.bag import add_bag_params_option, bag_params_config


def add_doctor_commands(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    doctor = subparsers.add_parser(
        "doctor", help="run a stack on one window of a bag and say how it connects (topics, types, QoS, plans)"
    )
    doctor.add_argument("bag", type=Path, help="scenario bag (rosbag2 folder)")
    add_bag_params_option(doctor)
    add_stack_arguments(doctor)
    doctor.add_argument("--window-start", type=int, default=0, help="first frame of the window (default 0)")
    doctor.add_argument("-o", "--out", type=Path, default=None, help="output folder (default: <bag>-doctor)")
    doctor.set_defaults(run=_run_doctor)


def _run_doctor(args: argparse.Namespace) -> int:
    from advsim_ros.attack.doctor import run_doctor

    bag_config = bag_params_config(args.bag_params)
    options = AttackOptions(
        bag=args.bag,
        bag_config=bag_config,
        out_dir=args.out or args.bag.with_name(f"{args.bag.name}-doctor"),
        stack=stack_spec(args),
        queries=0,
        plan_timeout=args.plan_timeout,
        connect_timeout=args.connect_timeout,
        window_start_frame=args.window_start,
        replay_only=True,
        parameter_overrides=parameter_overrides(args.param),
    )
    report = run_doctor(options)
    print(report.as_text())
    return 0 if report.ok else 1
