"""The campaign's report.html in a real headless Chromium (Debian's chromium + chromedriver, driven by selenium).

It must render without console errors, show every picture (figures and gallery, all inline) and
fetch nothing. Skips only when chromium or chromedriver is absent (scripts/setup.sh installs them
when it runs as root).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from PIL import Image

from advsim_ros.campaign.report import write_report
from advsim_ros.campaign.results import attack_row, best_curve


def _summary(rng: np.random.Generator, collided: bool, queries: int) -> dict[str, Any]:
    def score(hit: bool) -> dict[str, Any]:
        return {"status": "ok", "adversarial_loss": float(rng.normal()) + 4.0 * hit, "collision_3s": float(hit),
                "collision_5s": float(hit), "l2_human_3s": float(rng.uniform(0.5, 2)), "l2_human_5s": 3.0,
                "lateral_acceleration": 1.2, "jerk": float(rng.uniform(1, 6)), "detection_ap": math.nan}  # fmt: skip

    history = [{"query_id": i, "algorithm": "original" if i == 0 else "ga", "score": score(False)}
               for i in range(queries)]  # fmt: skip
    history.append({"query_id": queries, "algorithm": "ga", "score": score(collided)})
    return {"original": history[0]["score"], "adversarial": history[-1]["score"], "queries": history, "flaky": []}


@pytest.fixture(scope="module")
def report(tmp_path_factory: pytest.TempPathFactory) -> Path:
    rng = np.random.default_rng(11)
    out = tmp_path_factory.mktemp("campaign")
    rows, curves, gallery = [], {}, []
    for i in range(8):
        key = f"attack-{i}"
        summary = _summary(rng, collided=i % 3 == 0, queries=6 + i)
        identity = {"attack": key, "scenario": "kitti_0000", "window_start": 20, "stack": ("modular", "learned")[i % 2],
                    "algorithm": ("bo", "ga")[i // 4], "budget": 50, "actors": 1 + i % 2, "objective": "M0",
                    "seed": i, "bag": "/data/bag"}  # fmt: skip
        rows.append(attack_row(identity, summary, {"wall_s": 600.0, "cpu_s": 1800.0}, f"attacks/{key}"))
        curves[key] = best_curve(summary)
        if i % 3 == 0:
            png = out / "attacks" / key / "bev.png"
            png.parent.mkdir(parents=True)
            Image.new("RGB", (160, 120), (30, 90, 200)).save(png)
            (png.parent / "adversarial_bag").mkdir()
            gallery.append({"attack": key, "bev_png": png, "bag": f"attacks/{key}/adversarial_bag", "title": key})
    transfers = [{"attack": r["attack"], "source_stack": r["stack"], "target_stack": "modular", "collision_5s": 1.0,
                  "adversarial_loss": 2.0, "status": "ok", "out_dir": "t"} for r in rows]  # fmt: skip
    return write_report(out, rows, transfers, curves, gallery, seed=1)["html"]


def test_the_campaign_report_renders_in_headless_chromium_without_console_errors(report: Path, chromium: Any) -> None:
    driver = chromium
    driver.get(report.as_uri())
    assert driver.execute_script("return document.readyState") == "complete"
    images = driver.execute_script(
        "return Array.from(document.images).map(function (i) { return [i.id, i.complete, i.naturalWidth]; })"
    )
    links = driver.execute_script(
        "return Array.from(document.querySelectorAll('[src], [href]'))"
        ".map(function (e) { return e.getAttribute('src') || e.getAttribute('href'); })"
    )
    tables = driver.execute_script("return Array.from(document.querySelectorAll('h2')).map(h => h.id)")
    errors = [entry for entry in driver.get_log("browser") if entry["level"] in ("SEVERE", "ERROR")]
    assert errors == []
    assert {i[0] for i in images} == {"table1-figure", "curves-figure", "gallery-0", "gallery-1", "gallery-2"}
    assert all(complete and width > 0 for _, complete, width in images)  # every picture loaded
    assert [i[2] for i in images if i[0].startswith("gallery")] == [160, 160, 160]
    assert not [link for link in links if link.lower().startswith(("http:", "https:", "//"))]
    assert "attacks/attack-0/adversarial_bag" in links
    assert tables == ["table1", "table2", "table2-families", "table3", "table4", "table5", "curves", "gallery"]
