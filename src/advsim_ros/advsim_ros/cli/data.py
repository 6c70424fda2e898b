"""`advsim convert`, `curate`, `label` and `synth`: scenario bags from logs, data and seeds."""

from __future__ import annotations

import argparse
from pathlib import Path

from advsim_ros.cli.common import print_result
from advsim_ros.io.bag import add_bag_params_option, bag_params_config
from advsim_ros.io.synthetic import write_synthetic_bag
from advsim_ros.io.synthetic_families import FAMILY_NAMES


def add_data_commands(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """`advsim convert kitti|av2` and `advsim curate` (logic in advsim_ros.io.commands)."""
    from advsim_ros.io import commands

    def add_bag_params(parser: argparse.ArgumentParser) -> None:
        parser.add_argument(
            "--params", type=Path, default=None, help="bag topics and frames (default: params/bag.yaml values)"
        )

    convert = subparsers.add_parser("convert", help="convert a driving log into a scenario bag (rosbag2, MCAP)")
    sources = convert.add_subparsers(dest="source", required=True, metavar="SOURCE")

    kitti = sources.add_parser("kitti", help="KITTI tracking sequence (velodyne/, label_02/, calib/, poses/)")
    kitti.add_argument("root", type=Path, help="dataset folder, e.g. ../shared/data/kitti_tracking_0000")
    kitti.add_argument("--seq", default="0000", help="sequence number (default 0000)")
    kitti.add_argument("--poses", type=Path, default=None, help="poses file (default: root/poses/<seq>_*velo*.txt)")
    kitti.add_argument("-o", "--output", type=Path, required=True, help="bag folder to write")
    add_bag_params(kitti)
    kitti.add_argument("--overwrite", action="store_true", help="replace an existing output bag")
    kitti.set_defaults(
        run=lambda args: print_result(
            commands.convert_kitti(
                args.root, args.seq, args.output, poses=args.poses, params=args.params, overwrite=args.overwrite
            ).describe()
        )
    )

    av2 = sources.add_parser("av2", help="Argoverse 2 log (annotations, ego poses, vector map, LiDAR if present)")
    av2.add_argument("log_dir", type=Path, help="log folder, e.g. ../shared/data/av2/<log id>")
    av2.add_argument("-o", "--output", type=Path, required=True, help="bag folder to write")
    add_bag_params(av2)
    av2.add_argument("--overwrite", action="store_true", help="replace an existing output bag")
    av2.add_argument(
        "--lidar",
        choices=("real", "simulate"),
        default="real",
        help="real: the log's own sweeps (1-2 or none); simulate: a ray-cast sweep every frame (docs/data.md)",
    )
    av2.add_argument("--seed", type=int, default=0, help="seed of the simulated LiDAR's noise and ray drop")
    av2.set_defaults(
        run=lambda args: print_result(
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
    add_bag_params_option(curate)
    curate.add_argument("-o", "--output", type=Path, default=None, help="also write the best window as a bag")
    curate.add_argument("--overwrite", action="store_true", help="replace an existing output bag")
    curate.add_argument("--json", action="store_true", help="print the windows as JSON")
    curate.set_defaults(run=_run_curate)


def add_label_commands(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
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
    add_bag_params_option(label)
    label.add_argument("--overwrite", action="store_true", help="replace an existing output bag")
    label.set_defaults(run=_run_label)


def _run_label(args: argparse.Namespace) -> int:
    from advsim_ros.labelling.command import label_bag
    from advsim_ros.labelling.odometry import mount_from_string

    bag_config = bag_params_config(args.bag_params)
    labelled = label_bag(
        args.bag,
        args.output,
        tracks_topic=args.tracks_topic,
        mount=mount_from_string(args.mount) if args.mount is not None else None,
        params=args.params,
        bag_config=bag_config,
        overwrite=args.overwrite,
    )
    return print_result(labelled.describe())


def _run_curate(args: argparse.Namespace) -> int:
    from advsim_ros.io import commands

    bag_config = bag_params_config(args.bag_params)
    curated = commands.curate_bag(
        args.bag, params=args.params, bag_config=bag_config, output=args.output, overwrite=args.overwrite
    )
    return print_result(curated.as_json() if args.json else curated.as_table())


def add_synth_commands(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """`advsim synth`: a synthetic street log as a scenario bag (logic in advsim_ros.io.synthetic)."""
    synth = subparsers.add_parser("synth", help="generate a synthetic street log (meshes, 64-beam LiDAR) as a bag")
    synth.add_argument("-o", "--output", type=Path, required=True, help="bag folder to write")
    synth.add_argument("--seed", type=int, default=0, help="seed of the street, its actors and the sensor noise")
    synth.add_argument("--duration", type=float, default=None, help="log length [s] (default 8)")
    synth.add_argument(
        "--family", default="street", choices=FAMILY_NAMES, help="the staged interaction (default street; docs/data.md)"
    )
    synth.add_argument(
        "--params", type=Path, default=None, help="bag topics and frames (default: params/bag.yaml values)"
    )
    synth.add_argument("--overwrite", action="store_true", help="replace an existing output bag")
    synth.set_defaults(run=_run_synth)


def _run_synth(args: argparse.Namespace) -> int:
    import time

    from advsim_ros.io.bag import load_bag_config
    from advsim_ros.io.synthetic import SyntheticConfig, synthetic_name

    started = time.perf_counter()
    config = SyntheticConfig(family=args.family)
    if args.duration is not None:
        config = SyntheticConfig(duration=args.duration, family=args.family)
    bag_config = load_bag_config(args.params) if args.params is not None else None
    path = write_synthetic_bag(
        args.output, seed=args.seed, config=config, bag_config=bag_config, overwrite=args.overwrite
    )
    name = synthetic_name(args.family, args.seed)
    return print_result(f"wrote {path}: {name}, {config.num_frames} frames in {time.perf_counter() - started:.1f} s")
