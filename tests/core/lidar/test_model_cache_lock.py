"""Attacks of one log started at once build its re-simulation model once: the others wait and read it."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

BUILD = """
import json, sys
from pathlib import Path
import numpy as np
from advsim_ros.core.lidar.resim import ResimModel
from advsim_ros.core.lidar.model_cache import scenario_digest
from advsim_ros.core.lidar.config import ResimConfig
from advsim_ros.io.synthetic import generate_synthetic_log
scenario = generate_synthetic_log(np.random.default_rng(2), scenario_id="lock").scenario
cache = Path(sys.argv[1])
path = cache / f"resim-{scenario_digest(scenario, ResimConfig())}.npz"
ResimModel.build(scenario, cache_dir=cache)
print(json.dumps({"inode": path.stat().st_ino, "mtime_ns": path.stat().st_mtime_ns}))
"""


def test_two_processes_building_the_same_model_at_once_build_it_once(tmp_path: Path) -> None:
    builders = [
        subprocess.Popen([sys.executable, "-c", BUILD, str(tmp_path)], stdout=subprocess.PIPE, text=True)
        for _ in range(2)
    ]
    reports = [json.loads(builder.communicate(timeout=600)[0]) for builder in builders]
    assert all(builder.returncode == 0 for builder in builders)
    # a second build would have replaced the file (a new inode): both saw the one file written once
    assert reports[0] == reports[1]
    assert len(list(tmp_path.glob("resim-*.npz"))) == 1
