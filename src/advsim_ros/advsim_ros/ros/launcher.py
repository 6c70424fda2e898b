"""A small process launcher for ROS 2 node graphs (ros2 launch is not available from the wheels).

Every node and the stack under test run as separate processes with `--ros-args`, on one isolated
ROS_DOMAIN_ID with discovery kept on loopback. Processes are stopped with SIGINT first (rclpy's
clean shutdown), then SIGTERM, then SIGKILL. Output goes to one log file per process.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

# Fast DDS accepts domain ids 0..232; the low ones are left to the user's own graphs.
_DOMAIN_IDS = range(100, 230)
_LOCK_DIR = Path(tempfile.gettempdir()) / "advsim_ros_domains"
FASTDDS_PROFILES = Path(__file__).resolve().parent / "fastdds_large_data.xml"


class LaunchError(RuntimeError):
    """A process of the graph could not be started or exited unexpectedly."""


@dataclass(frozen=True)
class NodeSpec:
    """One process of the graph: a command plus the ROS arguments it gets."""

    name: str  # node name (__node remapping) and log-file name
    command: tuple[str, ...]  # executable and its own arguments, before --ros-args
    remappings: Mapping[str, str] = field(default_factory=dict)  # topic remappings from:=to
    params_files: tuple[Path, ...] = ()  # YAML files in the /<node>: ros__parameters: shape
    parameters: Mapping[str, str | int | float | bool] = field(default_factory=dict)  # -p overrides
    rename_node: bool = True  # add `-r __node:=name` (off for multi-node stacks)

    def argv(self) -> list[str]:
        ros_args: list[str] = []
        if self.rename_node:
            ros_args += ["-r", f"__node:={self.name}"]
        for source, target in self.remappings.items():
            ros_args += ["-r", f"{source}:={target}"]
        for params_file in self.params_files:
            ros_args += ["--params-file", str(params_file)]
        for key, value in self.parameters.items():
            ros_args += ["-p", f"{key}:={_param_literal(value)}"]
        return [*self.command, "--ros-args", *ros_args] if ros_args else list(self.command)


def _param_literal(value: str | int | float | bool) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    return str(value)


def python_module_command(module: str, *args: str) -> tuple[str, ...]:
    """The command that runs a module of this package with the current interpreter."""
    return (sys.executable, "-m", module, *args)


@contextlib.contextmanager
def reserve_domain_id() -> Iterator[int]:
    """Hold a ROS_DOMAIN_ID no other advsim graph on this machine uses until the block ends."""
    _LOCK_DIR.mkdir(parents=True, exist_ok=True)
    for domain_id in _DOMAIN_IDS:
        handle = open(_LOCK_DIR / f"{domain_id}.lock", "w")  # noqa: SIM115 - held for the whole block
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            handle.close()
            continue
        try:
            yield domain_id
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)
            handle.close()
        return
    raise LaunchError(f"no free ROS_DOMAIN_ID in {_DOMAIN_IDS.start}..{_DOMAIN_IDS.stop - 1}")


def graph_overrides(domain_id: int) -> dict[str, str]:
    """Environment variables that put a process on one isolated graph: own domain, loopback discovery."""
    return {
        "ROS_DOMAIN_ID": str(domain_id),
        "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST",
        "RMW_IMPLEMENTATION": "rmw_fastrtps_cpp",
        # shared memory with large segments for data: LiDAR sweeps are not fragmented over UDP
        "FASTRTPS_DEFAULT_PROFILES_FILE": str(FASTDDS_PROFILES),
        "PYTHONUNBUFFERED": "1",
    }


def graph_environment(domain_id: int, base: Mapping[str, str] | None = None) -> dict[str, str]:
    """Environment for every process of one isolated graph (`base`, default os.environ, plus the overrides)."""
    env = dict(os.environ if base is None else base)
    env.update(graph_overrides(domain_id))
    env.pop("ROS_STATIC_PEERS", None)
    return env


@dataclass
class _Running:
    spec: NodeSpec
    process: subprocess.Popen[bytes]
    log_path: Path
    log_file: IO[bytes]


class Launcher:
    """Starts processes of one graph and stops them all, in reverse order, on exit."""

    def __init__(self, env: Mapping[str, str], log_dir: Path) -> None:
        self._env = dict(env)
        self._log_dir = log_dir
        self._running: list[_Running] = []
        log_dir.mkdir(parents=True, exist_ok=True)

    def start(self, spec: NodeSpec) -> subprocess.Popen[bytes]:
        log_path = self._log_dir / f"{spec.name}.log"
        log_file = open(log_path, "ab")  # noqa: SIM115 - closed in stop()
        try:
            process = subprocess.Popen(
                spec.argv(),
                env=self._env,
                stdin=subprocess.DEVNULL,
                stdout=log_file,
                stderr=subprocess.STDOUT,
                start_new_session=True,  # our own signals reach it only when we send them
            )
        except OSError as error:
            log_file.close()
            raise LaunchError(f"cannot start {spec.name} ({' '.join(spec.command)}): {error}") from error
        self._running.append(_Running(spec, process, log_path, log_file))
        return process

    @property
    def log_dir(self) -> Path:
        return self._log_dir

    def log_path(self, name: str) -> Path:
        return self._log_dir / f"{name}.log"

    def exited(self) -> dict[str, int]:
        """Processes that have already exited, with their return codes."""
        return {r.spec.name: code for r in self._running if (code := r.process.poll()) is not None}

    def stop(self, name: str, timeout: float = 5.0) -> int | None:
        for running in list(self._running):
            if running.spec.name == name:
                self._running.remove(running)
                return _terminate(running, timeout)
        return None

    def stop_all(self, timeout: float = 5.0) -> dict[str, int | None]:
        codes: dict[str, int | None] = {}
        while self._running:
            running = self._running.pop()
            codes[running.spec.name] = _terminate(running, timeout)
        return codes

    def __enter__(self) -> Launcher:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.stop_all()


def _terminate(running: _Running, timeout: float) -> int | None:
    process = running.process
    try:
        for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGKILL):
            if process.poll() is not None:
                break
            with contextlib.suppress(ProcessLookupError):
                os.killpg(process.pid, sig)
            try:
                process.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                continue
        return process.poll()
    finally:
        running.log_file.close()


def wait_for(check: Callable[[], object], timeout: float, poll: float = 0.05) -> bool:
    """Poll `check` until it returns something truthy or `timeout` seconds pass (for tests and start-up)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if check():
            return True
        time.sleep(poll)
    return bool(check())
