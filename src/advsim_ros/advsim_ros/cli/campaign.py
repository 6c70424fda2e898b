"""`advsim campaign` (many attacks on Ray, the paper's tables), `advsim campaign-table2` (Table 2 from campaign
folders) and `advsim regress` (a suite as a CI gate)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from tqdm import tqdm

from advsim_ros.cli.common import CommandError
from advsim_ros.io.bag import add_bag_params_option, bag_params_config

if TYPE_CHECKING:
    from advsim_ros.campaign.suite import Verdict


def add_campaign_commands(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    campaign = subparsers.add_parser(
        "campaign", help="attack many scenarios x stacks x algorithms on Ray; report the paper's tables"
    )
    campaign.add_argument("config", type=Path, help="campaign YAML (see params/campaign_smoke.yaml)")
    campaign.add_argument("-o", "--out", type=Path, required=True, help="output folder (re-using it resumes)")
    campaign.add_argument("--workers", type=int, default=1, help="attacks at once (default 1; 2 cores: 1 or 2)")
    campaign.add_argument("--ray-address", default=None, help="join this Ray cluster (default: start one here)")
    campaign.add_argument(
        "--storage", default=None, metavar="URI",
        help="where jobs' inputs and outputs meet when Ray nodes share no folder: s3://BUCKET/PREFIX, gs://..., "
        "file:///... (default: the config's storage:, else OUTDIR itself)",
    )  # fmt: skip
    add_bag_params_option(campaign)
    campaign.set_defaults(run=_run_campaign)

    table2 = subparsers.add_parser(
        "campaign-table2",
        help="Table 2 (each stack against the standard learned stack, per scene family) from campaign folders",
    )
    table2.add_argument(
        "out", type=Path, nargs="+", help="campaign output folders (several: pooled, each paired within its own)"
    )
    table2.add_argument("-o", "--output", type=Path, default=None, help="also write the Markdown here")
    table2.set_defaults(run=_run_table2)

    regress = subparsers.add_parser(
        "regress", help="replay every scenario of a regression suite on a stack; non-zero exit when any fails"
    )
    regress.add_argument("suite", type=Path, help="a campaign's OUTDIR/suite (index.json and scenario bags)")
    regress.add_argument("--stack", default="reference", help='"reference", "learned", or your command line')
    regress.add_argument(
        "--remap", action="append", default=[], metavar="CONTRACT:=YOURS", help="your stack's topic name"
    )
    regress.add_argument("--junit", type=Path, default=None, help="write JUnit XML here")
    regress.add_argument("-o", "--out", type=Path, default=None, help="replays go here (default: <suite>-regress)")
    regress.add_argument("--plan-timeout", type=float, default=10.0, help="longest wait for a plan per frame [s]")
    regress.set_defaults(run=_run_regress)


class _Progress:
    """A tqdm bar over the campaign's attacks, shown from the first progress report on."""

    def __init__(self) -> None:
        self.bars: list[tqdm] = []

    # state: the campaign's progress counts (campaign.schedule)
    def __call__(self, state: dict[str, int]) -> None:
        bars = self.bars
        if not bars:
            bars.append(tqdm(total=state["attacks"], initial=state["done"], unit="attack", desc="campaign"))
        bar = bars[0]
        bar.update(state["done"] - bar.n)
        shown: dict[str, int | str] = {"failures_found": state["failures"], "errors": state["errors"]}
        if state["replays"]:  # found failures replayed on the other stacks (transfer)
            shown["transfer_replays"] = f"{state['replayed']}/{state['replays']}"
        bar.set_postfix(shown)

    def close(self) -> None:
        for bar in self.bars:
            bar.close()


def _note(text: str) -> None:
    print(f"advsim campaign: note: {text}", file=sys.stderr)


def _run_campaign(args: argparse.Namespace) -> int:
    from advsim_ros.campaign.outputs import write_campaign_outputs
    from advsim_ros.campaign.schedule import run_campaign

    bag_config = bag_params_config(args.bag_params)  # for the config's bag | bags without a bag_params of their own
    progress = _Progress()
    try:
        journal = run_campaign(
            args.config, args.out, args.workers, args.ray_address, progress, _note, bag_config, args.storage
        )
    finally:
        progress.close()
    written = write_campaign_outputs(args.config, args.out, journal, bag_config)
    # attacks that could not run, and attacks that ran but whose queries failed (attack.verdict)
    errors = [
        entry
        for entry in journal.of_kind("attack", finished=False)
        if "error" in entry or entry["row"]["status"] != "ok"
    ]
    for entry in errors:
        print(f"attack {entry['row']['attack']} failed: {entry.get('error') or entry['row']['error']}")
    print(f"report: {written['report_md']}  {written['report_html']}  results: {written['results_csv']}")
    print(f"regression suite: {written['suite']} ({written['suite_size']} scenarios)")
    return 1 if errors else 0


def _run_table2(args: argparse.Namespace) -> int:
    from advsim_ros.campaign.table2 import campaign_rows, table2_markdown
    from advsim_ros.core.atomic import write_text_atomically

    text = table2_markdown(campaign_rows(args.out))  # a folder without a journal: one line (CampaignError)
    print(text, end="")
    if args.output is not None:
        write_text_atomically(args.output, text)
    return 0


def _stack_entry(args: argparse.Namespace) -> str | dict[str, object]:
    remap: dict[str, str] = {}
    for item in args.remap:
        source, separator, target = item.partition(":=")
        if not separator or not source or not target:
            raise CommandError(f"--remap {item!r}: expected FROM:=TO")
        remap[source] = target
    stack: str = args.stack
    if stack in ("reference", "learned") and not remap:
        return stack
    return {"name": "stack", "command": stack, "remap": remap}


def _run_regress(args: argparse.Namespace) -> int:
    from advsim_ros.campaign.config import stack_spec
    from advsim_ros.campaign.suite import read_index, regress, write_junit

    suite = args.suite.resolve()
    entry = _stack_entry(args)
    stack_spec(entry, Path.cwd())  # a bad stack is one line before anything runs
    _, scenarios = read_index(suite)
    out = (args.out or suite.with_name(f"{suite.name}-regress")).resolve()
    print(f"regress: {len(scenarios)} scenarios of {suite} on {args.stack}")

    def show(verdict: Verdict) -> None:
        print(f"  {verdict.outcome.upper():7s} {verdict.name}  {verdict.message}", flush=True)

    verdicts = regress(suite, entry, out, args.plan_timeout, show)
    if args.junit is not None:
        write_junit(args.junit, verdicts, suite.name)
    bad = [v for v in verdicts if v.outcome != "passed"]
    print(
        f"regress: {len(verdicts) - len(bad)} passed, {len(bad)} failed"
        + (f"; JUnit: {args.junit}" if args.junit else "")
    )
    return 1 if bad else 0
