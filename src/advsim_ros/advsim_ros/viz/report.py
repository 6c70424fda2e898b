"""OUTDIR/report.html: one self-contained page per attack (inline CSS, JS and images; nothing fetched).

It shows the scenario and the stack, the perturbed actors (logged vs perturbed start, speed and
how far their paths moved), the query history (L_adv of every query and the best so far), the
original vs adversarial metrics with the terms of L_adv, the re-runs of the best query, the
animated bird's-eye view (bev.gif) and the still one (bev.png), and relative links to the bag,
summary.json and the journal with the commands that replay and export the scenario.
"""

from __future__ import annotations

import base64
import html
import io
import math
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from advsim_ros.contract.tracks import TrackRecord
from advsim_ros.core.atomic import write_text_atomically
from advsim_ros.core.attack_summary import AttackSummary, QueryEntry, Score
from advsim_ros.core.search.driver import NOT_SEARCHED
from advsim_ros.core.types import ActorTrack
from advsim_ros.viz.attack_view import AttackView, number

# (key in a QueryScore JSON object, label, unit): the rows of the metrics table
METRIC_ROWS: tuple[tuple[str, str, str], ...] = (
    ("status", "status", ""),
    ("adversarial_loss", "L_adv (higher: more safety-critical)", "1"),
    ("imitation_loss", "  imitation term l_IL", "m"),
    ("collision_loss", "  collision term", "1"),
    ("comfort_loss", "  comfort / rule term", "1"),
    ("collision_3s", "collision within 3 s", "1"),
    ("collision_5s", "collision within 5 s", "1"),
    ("l2_human_3s", "L2 to the human trajectory at 3 s", "m"),
    ("l2_human_5s", "L2 to the human trajectory at 5 s", "m"),
    ("lateral_acceleration", "max lateral acceleration", "m/s²"),
    ("jerk", "max longitudinal jerk", "m/s³"),
    ("detection_ap", "detection AP (BEV IoU 0.7)", "1"),
    ("prediction_l2_3s", "prediction L2 at 3 s", "m"),
    ("prediction_l2_5s", "prediction L2 at 5 s", "m"),
    ("sweeps_delivered", "sweeps delivered", "1"),
    ("plans_received", "plans received", "1"),
)

REPORT_CSS = """
body { font-family: system-ui, -apple-system, "Segoe UI", sans-serif; margin: 2rem auto; max-width: 72rem;
       color: #1d2327; padding: 0 1rem; }
h1 { font-size: 1.5rem; margin-bottom: .2rem; } h2 { font-size: 1.15rem; margin-top: 2rem;
     border-bottom: 1px solid #ccd0d4; padding-bottom: .2rem; }
table { border-collapse: collapse; margin: .5rem 0; font-size: .9rem; }
th, td { border: 1px solid #dcdcde; padding: .25rem .6rem; text-align: right; }
th:first-child, td:first-child { text-align: left; white-space: pre; }
thead th { background: #f0f0f1; }
.worse { background: #fde8e8; font-weight: 600; } .verdict { font-size: 1.1rem; padding: .6rem 1rem;
         border-radius: .3rem; background: #f0f6fc; display: inline-block; }
.verdict.fail { background: #fde8e8; color: #8a1f11; }
figure { margin: .5rem 0; } img { max-width: 100%; border: 1px solid #dcdcde; }
code { background: #f6f7f7; padding: .05rem .3rem; border-radius: .2rem; }
.muted { color: #646970; font-size: .85rem; } button { font-size: .85rem; margin: .3rem 0; }
"""

_JS = """
document.querySelectorAll('button[data-toggle]').forEach(function (button) {
  var target = document.getElementById(button.getAttribute('data-toggle'));
  button.addEventListener('click', function () {
    var hidden = target.hasAttribute('hidden');
    if (hidden) { target.removeAttribute('hidden'); } else { target.setAttribute('hidden', ''); }
    button.textContent = (hidden ? 'hide ' : 'show ') + button.getAttribute('data-label');
  });
});
document.body.setAttribute('data-ready', 'yes');
"""


def esc(value: object) -> str:
    return html.escape(str(value), quote=True)


def data_uri(path: Path, mime: str) -> str | None:
    if not path.is_file():
        return None
    return f"data:{mime};base64,{base64.b64encode(path.read_bytes()).decode('ascii')}"


def html_table(
    header: Sequence[str], rows: Sequence[Sequence[str]], classes: Sequence[Sequence[str]] | None = None
) -> str:
    head = "".join(f"<th>{esc(cell)}</th>" for cell in header)
    body = []
    for r, row in enumerate(rows):
        cells = []
        for c, cell in enumerate(row):
            css = classes[r][c] if classes is not None else ""
            cells.append(f'<td class="{css}">{esc(cell)}</td>' if css else f"<td>{esc(cell)}</td>")
        body.append("<tr>" + "".join(cells) + "</tr>")
    return f"<table><thead><tr>{head}</tr></thead><tbody>{''.join(body)}</tbody></table>"


def history_svg(queries: Sequence[QueryEntry]) -> str:
    """The query history as inline SVG: L_adv of every query (failed ones at the bottom) and the best so far."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ids: list[int] = []
    values: list[float] = []
    failed: list[bool] = []
    for query in queries:
        score = query.get("score") or {}
        loss = score.get("adversarial_loss")
        ok = score.get("status") == "ok" and loss is not None
        if query.get("algorithm") in NOT_SEARCHED and query["query_id"] != 0:
            continue  # re-runs and controls repeat or control a query: the history is the search's, from the original
        ids.append(int(query["query_id"]))
        values.append(float(loss) if ok and loss is not None else math.nan)
        failed.append(not ok)
    figure, axis = plt.subplots(figsize=(7.0, 3.0), dpi=96)
    try:
        array = np.array(values, dtype=np.float64)
        best = np.fmax.accumulate(np.where(np.isnan(array), -np.inf, array)) if array.size else array
        best = np.where(np.isinf(best), np.nan, best)
        axis.plot(ids, array, "o", color="tab:blue", ms=4, label="L_adv of the query")
        axis.step(ids, best, where="post", color="tab:red", lw=2, label="best so far")
        if any(failed):
            floor = np.nanmin(array) if np.any(np.isfinite(array)) else 0.0
            axis.plot([i for i, f in zip(ids, failed, strict=True) if f], [floor] * sum(failed), "x", color="0.3",
                      label="failed query")  # fmt: skip
        axis.set_xlabel("query (0 = the original log)")
        axis.set_ylabel("L_adv")
        axis.grid(alpha=0.3)
        axis.legend(fontsize=8)
        figure.tight_layout()
        buffer = io.StringIO()
        # no date and ids from a fixed salt: the same attack gives the same report, byte for byte
        with matplotlib.rc_context({"svg.hashsalt": "advsim_ros"}):
            figure.savefig(buffer, format="svg", metadata={"Date": None})
    finally:
        plt.close(figure)
    text = buffer.getvalue()
    return text[text.index("<svg") :]  # drop the XML prologue: the SVG is inlined in HTML


def _actor_rows(view: AttackView) -> list[list[str]]:
    rows = []
    for actor_id in view.perturbed_ids:
        try:
            moved = view.adversarial.actor(actor_id)
        except KeyError:
            continue
        logged: ActorTrack | None = None
        if view.original is not None:
            try:
                logged = view.original.actor(actor_id)
            except KeyError:
                logged = None
        speed = TrackRecord.from_actor_track(moved).velocity
        row = [actor_id, moved.actor_class.value, "×".join(f"{v:.1f}" for v in moved.size)]
        row.append(f"{moved.centers[0, 0]:.1f}, {moved.centers[0, 1]:.1f}")
        row.append(f"{speed[0]:.1f}")
        if logged is not None:
            logged_speed = TrackRecord.from_actor_track(logged).velocity
            common = np.intersect1d(logged.stamps_ns, moved.stamps_ns)
            shift = np.linalg.norm(
                moved.centers[np.isin(moved.stamps_ns, common), :2]
                - logged.centers[np.isin(logged.stamps_ns, common), :2],
                axis=1,
            )
            row += [f"{logged.centers[0, 0]:.1f}, {logged.centers[0, 1]:.1f}", f"{logged_speed[0]:.1f}"]
            row.append(f"{shift.max():.2f}" if shift.size else "n/a")
        else:
            row += ["n/a", "n/a", "n/a"]
        rows.append(row)
    return rows


def _metric_rows(original: Score | None, adversarial: Score | None) -> tuple[list[list[str]], list[list[str]]]:
    rows, classes = [], []
    for key, label, unit in METRIC_ROWS:
        a = (original or {}).get(key)
        b = (adversarial or {}).get(key)
        rows.append([label, unit, number(a, 4), number(b, 4)])
        worse = (
            isinstance(a, int | float)
            and isinstance(b, int | float)
            and key in ("adversarial_loss", "collision_3s", "collision_5s")
            and b > a
        )
        classes.append(["", "", "", "worse" if worse else ""])
    return rows, classes


def _verdict(view: AttackView) -> tuple[str, bool]:
    adversarial = view.summary.get("adversarial") or {}
    original = view.summary.get("original") or {}
    if adversarial.get("collision_5s") == 1.0 and view.adversarial_collision_ns is not None:
        seconds = (view.adversarial_collision_ns - view.decision_ns) / 1e9
        before = "collides too" if original.get("collision_5s") == 1.0 else "no collision"
        return f"The stack's plan collides {seconds:.1f} s after the decision in the adversarial scenario "\
            f"(original: {before}).", True  # fmt: skip
    if adversarial.get("collision_5s") == 1.0:
        return "The stack's plan collides within 5 s in the adversarial scenario.", True
    return (
        f"No collision found; L_adv {number(original.get('adversarial_loss'))} (original) -> "
        f"{number(adversarial.get('adversarial_loss'))} (adversarial).",
        False,
    )


def _yes(value: bool | None) -> str:
    return "-" if value is None else ("yes" if value else "no")


def finding_rows(summary: AttackSummary) -> tuple[list[list[str]], str]:
    """The controls and the class of the finding (attack.controls), as table rows, and the one-line conclusion."""
    controls, found = summary.get("controls"), summary.get("finding")
    gap = (controls.get("sim_gap") if controls else None) or {}
    original = controls.get("original") if controls else None
    fault = found.get("fault") if found else None
    contact: Mapping[str, object] = (fault.get("contact") if fault else None) or {}
    rows = [
        ["the found scenario reproduced when re-run", _yes(found.get("reproduced") if found else None)],
        ["the original reproduced when re-run", _yes(None if not original else original.get("reproduced"))],
        ["identity control: L_adv minus the original's", number(gap.get("adversarial_loss"), 4)],
        [
            "identity control: plan moved at 3 s / 5 s [m]",
            f"{number(gap.get('plan_l2_3s'))} / {number(gap.get('plan_l2_5s'))}",
        ],
        ["gain of the finding over the original (L_adv)", number(found.get("gain") if found else None, 4)],
        [
            "sim-dominated (gain within the margin of the identity control)",
            _yes(found.get("sim_dominated") if found else None),
        ],
    ]
    if fault:
        escape = f" (e.g. {fault['escape']})" if fault.get("escape") else ""
        rows.append(["could an ego within its limits avoid it", f"{fault.get('class')}{escape}"])
        speeds = f"ego {number(contact.get('ego_speed'))} m/s, actor {number(contact.get('actor_speed'))} m/s"
        rows.append([
            "first contact",
            f"actor {contact.get('actor_id')} at {number(contact.get('time_s'))} s, on the ego's "
            f"{contact.get('side')}: {str(contact.get('mover', '')).replace('_', ' ')} (towards the other: {speeds})",
        ])  # fmt: skip
    if not found:
        return rows, "Nothing was found to read."
    if found.get("counts_as_failure"):
        return rows, "This collision counts as the stack's failure: it reproduced, the controls held, it was avoidable."
    excluded = "; ".join(found.get("excluded") or []) or "it is not a collision"
    return rows, f"Not counted as the stack's failure: {excluded}."


def render_report(view: AttackView, out_dir: Path) -> str:
    """The report page as HTML text; images are read from ``out_dir`` (bev.gif, bev.png) and inlined."""
    summary = view.summary
    scenario = summary.get("scenario", {})
    stack = summary.get("stack", {})
    search = summary.get("search", {})
    verdict, failed = _verdict(view)
    reading, conclusion = finding_rows(summary)
    gif = data_uri(out_dir / "bev.gif", "image/gif")
    png = data_uri(out_dir / "bev.png", "image/png")
    metric_rows, metric_classes = _metric_rows(summary.get("original"), summary.get("adversarial"))
    queries = summary.get("queries") or []
    query_rows = []
    for query in queries:
        score = query.get("score") or {}
        query_rows.append([
            str(query.get("query_id")), str(query.get("algorithm")), str(score.get("status")),
            number(score.get("adversarial_loss"), 4), number(score.get("collision_5s")),
            number(score.get("l2_human_5s")),
            ", ".join(query.get("actor_ids") or []) or "-",
        ])  # fmt: skip
    reproductions = [
        [str(item.get("query_id")), ", ".join(str(v) for v in item.get("rerun_query_ids", [])),
         ", ".join(number(v, 6) for v in item.get("adversarial_losses", [])), number(item.get("spread")),
         number(item.get("reproduced")), number(item.get("inputs_identical")), number(item.get("plans_identical"))]
        for item in summary.get("reproductions") or []
    ]  # fmt: skip
    bag_name = view.bag.name
    mcaps = sorted(view.bag.glob("*.mcap"))
    links = [f'<a href="{esc(bag_name)}/">{esc(bag_name)}/</a> (the scenario bag)']
    links += [
        f'<a href="{esc(bag_name)}/{esc(m.name)}">{esc(bag_name)}/{esc(m.name)}</a> (open in Foxglove)' for m in mcaps
    ]
    links += [f'<a href="{name}">{name}</a>' for name in ("summary.json", "queries.jsonl", "bev.png", "bev.gif")
              if (out_dir / name).is_file()]  # fmt: skip
    perturbed = _actor_rows(view)
    parts = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        '<meta name="viewport" content="width=device-width, initial-scale=1">',
        '<link rel="icon" href="data:,">',  # no favicon request
        f"<title>advsim attack: {esc(scenario.get('scenario_id', ''))}</title>",
        f"<style>{REPORT_CSS}</style></head><body>",
        f"<h1>Attack on {esc(stack.get('name', 'the stack'))}: {esc(scenario.get('scenario_id', ''))}</h1>",
        f'<p class="muted">source bag <code>{esc(scenario.get("bag", ""))}</code>, window from frame '
        f"{esc(scenario.get('window_start_frame'))} ({esc(scenario.get('history_frames'))} history + "
        f"{esc(scenario.get('future_frames'))} future frames); search <code>{esc(search.get('algorithm'))}</code>, "
        f"{esc(search.get('queries'))} queries, seed {esc(search.get('seed'))}; wall time "
        f"{number(summary.get('wall_time_s'))} s</p>",
        f'<p class="verdict{" fail" if failed else ""}" id="verdict">{esc(verdict)}</p>',
        "<h2>Bird's-eye view, original vs adversarial</h2>",
        f'<figure><img id="bev-animation" alt="animated bird\'s-eye view" src="{gif}"></figure>'
        if gif
        else '<p class="muted">bev.gif was not written.</p>',
        '<p class="muted">Red: perturbed actors (dashed: their paths); blue: other actors; green: the SDV as logged '
        "and "
        "the human trajectory; orange: the stack's plan of the decision frame and the SDV following it (red star: "
        "the first collision); grey: the LiDAR the stack saw (history, then the decision sweep).</p>",
        "<h2>Original vs adversarial</h2>",
        html_table(["metric", "unit", "original", "adversarial"], metric_rows, metric_classes),
        '<p class="muted">L_adv = imitation term + collision term + comfort term (weights in params/scorer.yaml); '
        "adversarial = the recorded query (the last re-run of the best).</p>",
        '<h2 id="finding">Reading the finding</h2>',
        html_table(["control or question", "answer"], reading),
        f'<p class="verdict" id="finding-verdict">{esc(conclusion)}</p>',
        '<p class="muted">The identity control re-inserts the perturbed actors on their logged tracks through the '
        "same re-simulation: what it changes is what the simulator alone does to the stack (docs/attack.md, "
        '"Reading a finding").</p>',
        "<h2>Perturbed actors</h2>",
        html_table(
            [
                "actor",
                "class",
                "size l×w×h [m]",
                "perturbed start x, y [m]",
                "perturbed speed [m/s]",
                "logged start x, y [m]",
                "logged speed [m/s]",
                "max shift [m]",
            ],
            perturbed,
        )
        if perturbed
        else '<p class="muted">No actor was perturbed.</p>',
        "<h2>Query history</h2>",
        f'<figure id="history">{history_svg(queries)}</figure>' if queries else "<p>No query finished.</p>",
        '<button data-toggle="queries" data-label="every query">show every query</button>',
        '<div id="queries" hidden>'
        + html_table(["query", "algorithm", "status", "L_adv", "collision@5s", "L2@5s [m]", "actors"], query_rows)
        + "</div>",
        "<h2>Re-runs of the best</h2>",
        html_table(
            ["query", "re-runs", "L_adv of each", "spread", "reproduced", "inputs identical", "plans identical"],
            reproductions,
        )
        if reproductions
        else '<p class="muted">No re-runs.</p>',
        "<h2>Still view</h2>",
        f'<figure><img id="bev-still" alt="bird\'s-eye view" src="{png}"></figure>' if png else "<p>No bev.png.</p>",
        "<h2>Files</h2><ul>" + "".join(f"<li>{link}</li>" for link in links) + "</ul>",
        f"<p>Replay it against the stack: <code>advsim replay {esc(view.bag)} --stack ... --check</code>; as "
        f"OpenSCENARIO: <code>advsim export openscenario {esc(view.bag)} -o scenario.xosc</code>; in Foxglove: open "
        "the .mcap file and import <code>docs/foxglove/advsim.json</code>; in RViz2: <code>ros2 bag play</code> the "
        "bag with <code>rviz2 -d docs/rviz/advsim.rviz</code>.</p>",
        f"<script>{_JS}</script>",
        "</body></html>",
    ]
    return "\n".join(parts)


def write_report(view: AttackView, out_dir: Path) -> Path:
    """Write OUTDIR/report.html atomically; return its path."""
    path = Path(out_dir) / "report.html"
    write_text_atomically(path, render_report(view, Path(out_dir)))
    return path
