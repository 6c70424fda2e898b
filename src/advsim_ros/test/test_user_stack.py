"""A stack attached the way a user attached theirs: two plain rclpy scripts, one profile, run from anywhere.

The scripts (processes/lidar_clusterer.py, processes/route_planner.py) lie in a folder of the user's
with the planner's route (a GeoJSON line written by `advsim export route`, which it opens relative to its
working directory, named by $ROUTE_FILE);
the clusterer reads the sweeps with sensor_msgs_py.point_cloud2, which the ROS 2 wheels lack. The
profile starts both by path in that folder (`cwd`, `env`) and adapts their GNSS pose and spatial
plan; advsim runs from somewhere else. Without `cwd` the planner never plans, and `advsim doctor`
shows why from the planner's own log.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import yaml

PROCESSES = Path(__file__).resolve().parent / "processes"
DATUM = {"latitude": 49.0, "longitude": 8.4, "altitude": 110.0}


def _users_folder(bag: Path, folder: Path, profile: Path) -> None:
    """The user's folder: the two scripts and the route, the logged drive as `advsim export route` writes it."""
    folder.mkdir()
    for script in ("lidar_clusterer.py", "route_planner.py"):
        shutil.copy(PROCESSES / script, folder / script)
    route = folder / "waypoints.geojson"
    exported = _advsim("export", "route", str(bag), "--stack-profile", str(profile), "-o", str(route))
    assert exported.returncode == 0, exported.stderr


def _profile(path: Path, folder: Path, cwd: bool) -> Path:
    where = {"cwd": folder.name} if cwd else {}
    planner = {"name": "planner", "command": f"$ADVSIM_PYTHON {folder / 'route_planner.py'}", **where}
    clusterer = {"name": "clusterer", "command": f"$ADVSIM_PYTHON {folder / 'lidar_clusterer.py'}", **where}
    pose = {"type": "navsatfix", "topic": "/gps/fix", "datum": DATUM}
    plan = {"type": "spatial_path", "topic": "/route_planner/path", "frame_id": "map", "frame_origin": "first_fix"}
    profile = {
        "profile": 1,
        "name": "users_stack",
        "processes": [clusterer, {**planner, "env": {"ROUTE_FILE": "waypoints.geojson"}}],
        "timing": {"mode": "timer"},
        "inputs": {"lidar": {"topic": "/velodyne_points"}, "pose": pose},
        "outputs": {"plan": plan},
    }
    path.write_text(yaml.safe_dump(profile))
    return path


def _advsim(*arguments: str) -> subprocess.CompletedProcess[str]:
    command = [sys.executable, "-m", "advsim_ros.cli", *arguments]
    return subprocess.run(command, capture_output=True, text=True, timeout=900, check=False)


def test_a_users_two_script_stack_is_attacked_from_a_profile_with_cwd_and_env(
    synthetic_bag: Path, tmp_path: Path
) -> None:
    folder = tmp_path / "my_stack"
    lost_profile = _profile(tmp_path / "lost.yaml", folder, cwd=False)
    _users_folder(synthetic_bag, folder, lost_profile)

    lost = _advsim("doctor", str(synthetic_bag), "--stack-profile", str(lost_profile), "--plan-timeout", "5",
                   "-o", str(tmp_path / "lost"))  # fmt: skip
    assert lost.returncode == 1, lost.stdout[-3000:] + lost.stderr[-2000:]
    report = lost.stdout.splitlines()
    verdict = next(i for i, line in enumerate(report) if line.startswith("verdict: NOT ready"))
    assert any(line.startswith("plans: 0 of") for line in report[:verdict]), lost.stdout
    tail = "\n".join(report[verdict + 1 :])
    assert f"the last lines of the stack's log {tmp_path / 'lost' / 'run' / 'logs' / 'planner.log'}:" in tail
    assert "cannot read the route waypoints.geojson" in tail  # the reason, from the planner's own log

    out = tmp_path / "attack"
    attacked = _advsim(
        "attack", str(synthetic_bag), "--stack-profile", str(_profile(tmp_path / "stack.yaml", folder, True)),
        "--algo", "random", "--queries", "2", "--reruns", "0", "--param", "perturber.num_candidates=20000",
        "-o", str(out),
    )  # fmt: skip
    assert attacked.returncode == 0, attacked.stderr[-3000:]
    summary = json.loads((out / "summary.json").read_text())
    assert {query["score"]["status"] for query in summary["queries"]} == {"ok"}
    logs = out / "run" / "logs"
    assert "route waypoints.geojson: " in (logs / "planner.log").read_text()
    assert "points read with sensor_msgs_py" in (logs / "clusterer.log").read_text()
