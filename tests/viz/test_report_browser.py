"""report.html in a real headless Chromium (Debian's chromium + chromedriver, driven by selenium).

It must render without console errors, run its script, show its images, and fetch nothing: every
image is inline. Skips only when chromium or chromedriver is absent (scripts/setup.sh installs
them when it runs as root).
"""

from __future__ import annotations

import io
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from PIL import Image

from advsim_ros.viz.outputs import write_viz_outputs


@pytest.fixture(scope="module")
def report(attack_out: Path) -> Path:
    written = write_viz_outputs(attack_out)
    return Path(written["report"])


def test_the_report_is_self_contained(report: Path) -> None:
    text = report.read_text()
    assert not re.search(r"""(src|href)\s*=\s*["']?(https?:)?//""", text)  # nothing from the network
    assert "<script src" not in text
    assert '<link rel="stylesheet"' not in text
    assert text.count("data:image/gif;base64,") == 1


def test_the_report_renders_in_headless_chromium_without_console_errors(report: Path, chromium: Any) -> None:
    driver = chromium
    driver.get(report.as_uri())
    assert driver.execute_script("return document.readyState") == "complete"
    assert driver.execute_script("return document.body.getAttribute('data-ready')") == "yes"  # the script ran
    sizes = driver.execute_script(
        "return Array.from(document.images).map(function (i) { return [i.id, i.complete, i.naturalWidth]; })"
    )
    assert ["bev-animation", True, 720] in sizes
    assert driver.execute_script("return document.querySelectorAll('#history svg').length") == 1
    assert "collides" in driver.find_element("id", "verdict").text
    reading = driver.find_element("id", "finding-verdict").text  # the controls held; avoidable by braking
    assert reading.startswith("This collision counts as the stack's failure"), reading
    driver.find_element("css selector", "button[data-toggle='queries']").click()
    assert driver.execute_script("return document.getElementById('queries').hasAttribute('hidden')") is False
    errors = [entry for entry in driver.get_log("browser") if entry["level"] in ("SEVERE", "ERROR")]
    assert errors == []
    shot = Image.open(io.BytesIO(driver.get_screenshot_as_png())).convert("RGB")
    pixels = np.asarray(shot).reshape(-1, 3)
    assert shot.size[0] >= 800
    assert pixels.std(axis=0).max() > 20  # not a blank page
    assert len(np.unique(pixels[::7], axis=0)) > 200  # text, tables and the figures, not a flat colour
