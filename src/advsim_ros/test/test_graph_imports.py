"""What the graph's processes import: each only what its own nodes need (memory of an attack)."""

from __future__ import annotations

import subprocess
import sys

HEAVY = ("advsim_ros.nodes.lidar_resim", "open3d", "open3d.pybind", "matplotlib", "torch")


def _imported_after(code: str) -> list[str]:
    probe = f"import sys\n{code}\nprint(sorted(m for m in {HEAVY!r} if m in sys.modules))\n"
    result = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True)
    return list(eval(result.stdout.strip().splitlines()[-1]))


def test_the_light_nodes_container_imports_neither_the_ray_caster_nor_torch_nor_matplotlib() -> None:
    # the ray caster (Open3D, ~170 MB resident) belongs to lidar_resim's process; torch comes with BO only
    code = (
        "from advsim_ros.nodes.container import _factory\n"
        "for name in ('scenario_player', 'scorer', 'perturber', 'search'):\n"
        "    _factory(name)\n"
    )
    assert _imported_after(code) == []


def test_the_container_still_runs_lidar_resim_when_named() -> None:
    assert "advsim_ros.nodes.lidar_resim" in _imported_after(
        "from advsim_ros.nodes.container import _factory\n_factory('lidar_resim')"
    )
