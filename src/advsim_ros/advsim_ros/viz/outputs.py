"""The visual outputs of an attack, from its adversarial bag and its summary: OUTDIR/bev.gif and OUTDIR/report.html.

Called by the attack after it wrote OUTDIR/adversarial, summary.json and bev.png, and by
`advsim report OUTDIR` for an attack folder written before (or to draw it again).
"""

from __future__ import annotations

import ctypes
import os
import signal
from pathlib import Path

from advsim_ros.core.attack_summary import AttackSummary, OutputsRecord
from advsim_ros.core.types import ScenarioError
from advsim_ros.io.bag import BagConfig
from advsim_ros.viz.animation import AnimationConfig, write_bev_animation
from advsim_ros.viz.attack_view import AttackView, load_attack_view
from advsim_ros.viz.bev import write_bev_still
from advsim_ros.viz.report import write_report

ADVERSARIAL_BAG = "adversarial"
BEV_ANIMATION = "bev.gif"
REPORT = "report.html"
_PR_SET_PDEATHSIG = 1  # prctl(2)


def write_viz_outputs(
    out_dir: Path,
    summary: AttackSummary | Path | None = None,
    animation: AnimationConfig | None = None,
    bag_config: BagConfig | None = None,
) -> OutputsRecord:
    """Write OUTDIR/bev.gif and OUTDIR/report.html from OUTDIR/adversarial; return their paths as summary.json's
    "outputs" names them.

    ``summary`` is the attack's summary (default: OUTDIR/summary.json); the bag is read in ``bag_config``'s
    layout (--bag-params), else in the one the summary recorded.
    """
    out_dir = Path(out_dir)
    bag = out_dir / ADVERSARIAL_BAG
    if not (bag / "metadata.yaml").is_file():
        raise ScenarioError(f"{out_dir} has no adversarial bag ({bag}): not the output folder of an attack")
    view = load_attack_view(bag, summary if summary is not None else out_dir / "summary.json", bag_config)
    return write_view_outputs(view, out_dir, animation)


def write_view_figures(view: AttackView, out_dir: Path, visuals: bool, fork: bool = False) -> OutputsRecord:
    """OUTDIR/bev.png, and with ``visuals`` bev.gif and report.html (their paths returned as write_view_outputs').

    ``fork``: bev.png is drawn by a child process while this one draws the rest (only in a process without
    Python or DDS threads: the attack's outputs worker). A child that failed is followed by bev.png drawn
    here, which raises its error.
    """
    if not (visuals and fork):
        write_bev_still(view, out_dir / "bev.png")
        return write_view_outputs(view, out_dir) if visuals else {}
    child = os.fork()
    if child == 0:  # pragma: no cover (a child process: coverage does not follow it)
        code = 1
        try:
            ctypes.CDLL(None).prctl(_PR_SET_PDEATHSIG, signal.SIGKILL)  # not outliving the worker
            write_bev_still(view, out_dir / "bev.png")
            code = 0
        finally:
            os._exit(code)
    try:
        written = write_view_outputs(view, out_dir)
    finally:
        _, status = os.waitpid(child, 0)
    if status != 0:
        write_bev_still(view, out_dir / "bev.png")
    return written


def write_view_outputs(view: AttackView, out_dir: Path, animation: AnimationConfig | None = None) -> OutputsRecord:
    """OUTDIR/bev.gif and OUTDIR/report.html of an attack's view; their paths as summary.json's "outputs" names them."""
    write_bev_animation(view, out_dir / BEV_ANIMATION, animation)
    write_report(view, out_dir)
    return {"bev_animation": str(out_dir / BEV_ANIMATION), "report": str(out_dir / REPORT)}
