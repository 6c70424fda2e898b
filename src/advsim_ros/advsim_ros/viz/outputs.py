"""The visual outputs of an attack, from its adversarial bag and its summary: OUTDIR/bev.gif and OUTDIR/report.html.

Called by the attack after it wrote OUTDIR/adversarial, summary.json and bev.png, and by
`advsim report OUTDIR` for an attack folder written before (or to draw it again).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from advsim_ros.core.types import Plan, Scenario, ScenarioError
from advsim_ros.io.bag import BagConfig
from advsim_ros.viz.animation import AnimationConfig, write_bev_animation
from advsim_ros.viz.attack_view import load_attack_view
from advsim_ros.viz.report import write_report

ADVERSARIAL_BAG = "adversarial"
BEV_ANIMATION = "bev.gif"
REPORT = "report.html"


def write_viz_outputs(
    out_dir: Path,
    summary: Mapping[str, Any] | Path | None = None,
    animation: AnimationConfig | None = None,
    bag_config: BagConfig | None = None,
    original: Scenario | None = None,
    written: tuple[Scenario, Plan | None] | None = None,
) -> dict[str, str]:
    """Write OUTDIR/bev.gif and OUTDIR/report.html; return their paths as summary.json's "outputs" names them.

    ``summary`` is the attack's summary (default: OUTDIR/summary.json); the bag is OUTDIR/adversarial, read
    in ``bag_config``'s layout (--bag-params), else in the one the summary recorded. ``original`` is the
    attacked window of the source log when the caller holds it (else read from the source bag); ``written``
    the adversarial scenario and plan the caller has just written to the bag (else read from it).
    """
    out_dir = Path(out_dir)
    bag = out_dir / ADVERSARIAL_BAG
    if not (bag / "metadata.yaml").is_file():
        raise ScenarioError(f"{out_dir} has no adversarial bag ({bag}): not the output folder of an attack")
    summary = summary if summary is not None else out_dir / "summary.json"
    view = load_attack_view(bag, summary, bag_config, original, written)
    write_bev_animation(view, out_dir / BEV_ANIMATION, animation)
    write_report(view, out_dir)
    return {"bev_animation": str(out_dir / BEV_ANIMATION), "report": str(out_dir / REPORT)}
