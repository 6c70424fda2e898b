"""A small process launcher for ROS 2 node graphs (ros2 launch is not available from the wheels).

Every node and the stack under test run as separate processes with `--ros-args`, on one isolated
ROS_DOMAIN_ID whose DDS runs over shared memory only (no network socket). Output goes to one log file per process.

No process outlives its graph, however the orchestrator ends (kill -9 included): each process
runs in a process group of its own with the parent-death signal set (it gets SIGKILL when the
orchestrator dies), and a reaper process (ros.reaper) kills every group of the graph, the
stack's children included, once the orchestrator is gone. The ROS-domain lock is inherited by
every process of the graph, so the domain stays reserved until the last of them has exited.
Processes are stopped with SIGINT first (rclpy's clean shutdown), then SIGKILL.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import random
import secrets
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

from advsim_ros.core.errors import UserError
from advsim_ros.ros.identity import RUN_MARKER, RUN_PIDS

# Fast DDS accepts domain ids 0..232; the low ones are left to the user's own graphs.
_DOMAIN_IDS = range(100, 230)
_LOCK_DIR = Path(tempfile.gettempdir()) / "advsim_ros_domains"
FASTDDS_PROFILES = Path(__file__).resolve().parent / "fastdds_graph.xml"


class LaunchError(UserError, RuntimeError):
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
    cwd: Path | None = None  # working folder (None: the orchestrator's)
    env: Mapping[str, str] = field(default_factory=dict)  # extra environment; the graph's own variables win

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


@dataclass(frozen=True)
class DomainLease:
    """A reserved ROS_DOMAIN_ID and the open lock file that holds it (inherited by the graph's processes)."""

    domain_id: int
    lock_fd: int


@contextlib.contextmanager
def reserve_domain_id() -> Iterator[DomainLease]:
    """Hold a ROS_DOMAIN_ID no other advsim graph on this machine uses while any holder of the lease lives.

    The lock is an flock on a file per domain; processes started by a Launcher with this lease
    inherit the open file, so the lock is released only when the orchestrator *and* every
    process of its graph have exited (never unlocked explicitly, which would release it for all).
    Free domains are tried in a random order: which one an attack gets cannot be predicted.
    """
    _LOCK_DIR.mkdir(parents=True, exist_ok=True)
    for domain_id in random.SystemRandom().sample(_DOMAIN_IDS, len(_DOMAIN_IDS)):
        fd = os.open(_LOCK_DIR / f"{domain_id}.lock", os.O_WRONLY | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            continue
        try:
            yield DomainLease(domain_id, fd)
        finally:
            os.close(fd)
        return
    raise LaunchError(f"no free ROS_DOMAIN_ID in {_DOMAIN_IDS.start}..{_DOMAIN_IDS.stop - 1}")


def die_with_parent(argv: list[str]) -> list[str]:
    """argv run through util-linux's setpriv so that the process gets SIGKILL when the orchestrator dies.

    (prctl(PR_SET_PDEATHSIG) survives the exec; setpriv sets it without a Python pre-exec hook,
    which is unsafe in a process that already runs DDS threads.)
    """
    setpriv = shutil.which("setpriv")
    if setpriv is None:
        raise LaunchError(
            "setpriv (util-linux) is not installed: it is needed to tie the graph's processes to this one"
        )
    return [setpriv, "--pdeathsig", "KILL", "--", *argv]


def start_reaper(
    log: Path, env: Mapping[str, str], pass_fds: tuple[int, ...] = (), marker: str | None = None
) -> subprocess.Popen[bytes]:
    """A reaper (ros.reaper) in a session of its own: what it is told on its stdin dies when this process does.

    With ``marker`` it also ends every process that carries the marker in its environment, wherever
    it went (its own session, a daemon's double fork); the reaper itself runs without it.
    """
    reaper_env = {key: value for key, value in env.items() if key != RUN_MARKER}
    with open(log, "ab") as reaper_log:
        reaper = subprocess.Popen(
            python_module_command("advsim_ros.ros.reaper"),
            stdin=subprocess.PIPE,
            stdout=subprocess.DEVNULL,
            stderr=reaper_log,
            pass_fds=pass_fds,
            start_new_session=True,
            env={**reaper_env, "_ROS_WHEELS_BOOTSTRAP_COMPLETE": "1"},  # it needs no ROS libraries: no re-exec
        )
    if marker:
        assert reaper.stdin is not None
        reaper.stdin.write(f"marker {marker}\n".encode())
        reaper.stdin.flush()
    return reaper


def graph_overrides(domain_id: int) -> dict[str, str]:
    """Environment variables that put a process on one isolated graph: own domain, shared memory only.

    The profile gives Fast DDS no network transport at all (discovery and data over shared memory,
    segments large enough for whole sweeps), so the graph is reachable from this machine only and
    opens no socket. SYSTEM_DEFAULT keeps rmw_fastrtps from adding a UDP transport of its own (it
    does for LOCALHOST, bound to every interface). Publishing is synchronous (sent before publish
    returns), which the player's ordering of /clock after a frame's inputs relies on.
    """
    return {
        "ROS_DOMAIN_ID": str(domain_id),
        "ROS_AUTOMATIC_DISCOVERY_RANGE": "SYSTEM_DEFAULT",
        "RMW_IMPLEMENTATION": "rmw_fastrtps_cpp",
        "FASTRTPS_DEFAULT_PROFILES_FILE": str(FASTDDS_PROFILES),
        "RMW_FASTRTPS_PUBLICATION_MODE": "SYNCHRONOUS",
        "PYTHONUNBUFFERED": "1",
    }


_NETWORK_SETTINGS = ("ROS_STATIC_PEERS", "ROS_LOCALHOST_ONLY", "FASTDDS_BUILTIN_TRANSPORTS", "ROS_DISCOVERY_SERVER")
# What keeps a process on its graph and tells its publishers apart: a stack's own env never sets these
GRAPH_VARIABLES = frozenset((*graph_overrides(0), *_NETWORK_SETTINGS, RUN_MARKER))


def graph_environment(domain_id: int, base: Mapping[str, str] | None = None) -> dict[str, str]:
    """Environment for every process of one isolated graph (`base`, default os.environ, plus the overrides)."""
    env = dict(os.environ if base is None else base)
    env.update(graph_overrides(domain_id))
    for variable in _NETWORK_SETTINGS:  # a user's network settings would bring UDP back (graph_overrides)
        env.pop(variable, None)
    return env


def join_graph(domain_id: int) -> None:
    """Put this process's own ROS participants (created after this call) on the graph, as graph_environment does."""
    os.environ.update(graph_overrides(domain_id))
    for variable in _NETWORK_SETTINGS:
        os.environ.pop(variable, None)


@dataclass
class _Running:
    spec: NodeSpec
    process: subprocess.Popen[bytes]
    log_path: Path
    log_file: IO[bytes]


class Launcher:
    """Starts the processes of one graph (each in its own process group) and stops them all on exit.

    Every process gets the graph's marker in its environment (a new one per launcher): the graph's
    nodes tell its own publishers from foreign ones by it (ros.identity), and the reaper finds by
    it whatever the stack started outside its process group.
    """

    def __init__(self, env: Mapping[str, str], log_dir: Path, lease: DomainLease) -> None:
        self.marker = secrets.token_hex(16)
        self._started = log_dir / "pids"  # every pid this launcher started (ros.identity: a crashed stack's too)
        self._env = {**env, RUN_MARKER: self.marker, RUN_PIDS: str(self._started)}
        self._log_dir = log_dir
        self._lease = lease
        self._running: list[_Running] = []
        self._stopped_resources: dict[str, dict[str, float]] = {}
        log_dir.mkdir(parents=True, exist_ok=True)
        self._started.write_text("")  # this graph's processes only (a resumed attack's folder has the last run's)
        # The reaper first: from now on nothing this launcher starts can outlive the orchestrator.
        self._reaper = start_reaper(log_dir / "reaper.log", self._env, (lease.lock_fd,), self.marker)
        assert self._reaper.stdin is not None
        self._tell_reaper = self._reaper.stdin

    def start(self, spec: NodeSpec) -> subprocess.Popen[bytes]:
        log_path = self._log_dir / f"{spec.name}.log"
        log_file = open(log_path, "ab")  # noqa: SIM115 - closed in stop()
        kept = sorted(GRAPH_VARIABLES.intersection(spec.env))
        if kept:  # said where the user looks when the stack misbehaves: its own log
            log_file.write(f"advsim: env {', '.join(kept)} of {spec.name} not set: the graph sets them\n".encode())
            log_file.flush()
        env = {**self._env, **{key: value for key, value in spec.env.items() if key not in GRAPH_VARIABLES}}
        try:
            process = subprocess.Popen(
                die_with_parent(spec.argv()),
                env=env,
                cwd=spec.cwd,
                stdin=subprocess.DEVNULL,
                stdout=log_file,
                stderr=subprocess.STDOUT,
                start_new_session=True,  # a process group of its own: our signals reach it only when we send them
                pass_fds=(self._lease.lock_fd,),
            )
        except OSError as error:
            log_file.close()
            raise LaunchError(f"cannot start {spec.name} ({' '.join(spec.command)}): {error}") from error
        self._tell_reaper.write(f"{process.pid}\n".encode())  # its process group id is its pid (setsid)
        with self._started.open("a") as started:
            started.write(f"{process.pid}\n")
        self._tell_reaper.flush()
        self._running.append(_Running(spec, process, log_path, log_file))
        return process

    @property
    def log_dir(self) -> Path:
        return self._log_dir

    def log_path(self, name: str) -> Path:
        return self._log_dir / f"{name}.log"

    def resources(self) -> dict[str, dict[str, float]]:
        """Peak resident memory [MB] and CPU time [s] of every process (running ones so far, from /proc)."""
        used = dict(self._stopped_resources)
        for running in self._running:
            try:
                status = Path(f"/proc/{running.process.pid}/status").read_text()
                fields = Path(f"/proc/{running.process.pid}/stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            peak_kb = next((int(line.split()[1]) for line in status.splitlines() if line.startswith("VmHWM:")), 0)
            ticks = int(fields[11]) + int(fields[12])  # utime + stime
            used[running.spec.name] = {"peak_rss_mb": peak_kb / 1024.0, "cpu_s": ticks / os.sysconf("SC_CLK_TCK")}
        return used

    def exited(self) -> dict[str, int]:
        """Processes that have already exited, with their return codes."""
        return {r.spec.name: code for r in self._running if (code := r.process.poll()) is not None}

    def stop(self, name: str, timeout: float = 5.0) -> int | None:
        used = self.resources().get(name)
        if used is not None:
            self._stopped_resources[name] = used
        for running in list(self._running):
            if running.spec.name == name:
                self._running.remove(running)
                return _terminate(running, timeout)
        return None

    def stop_all(self, timeout: float = 5.0) -> dict[str, int | None]:
        """SIGINT to every group at once, SIGKILL to what is left after ``timeout``; returns the exit codes."""
        running, self._running = self._running, []
        for item in running:
            _signal_group(item.process, signal.SIGINT)
        deadline = time.monotonic() + timeout
        for item in running:
            with contextlib.suppress(subprocess.TimeoutExpired):
                item.process.wait(timeout=max(0.0, deadline - time.monotonic()))
        codes: dict[str, int | None] = {}
        for item in running:
            _signal_group(item.process, signal.SIGKILL)  # the group: children of a stack's shell included
            codes[item.spec.name] = item.process.wait()
            item.log_file.close()
        return codes

    def close(self) -> None:
        """Stop everything, then let the reaper check that nothing of the graph is left and exit."""
        self.stop_all()
        self._tell_reaper.close()
        self._reaper.wait()

    def __enter__(self) -> Launcher:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()


def _signal_group(process: subprocess.Popen[bytes], sig: int) -> None:
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(process.pid, sig)


def _terminate(running: _Running, timeout: float) -> int | None:
    """Stop one process's group: SIGINT, then SIGKILL after ``timeout``."""
    try:
        _signal_group(running.process, signal.SIGINT)
        with contextlib.suppress(subprocess.TimeoutExpired):
            running.process.wait(timeout=timeout)
        _signal_group(running.process, signal.SIGKILL)
        return running.process.wait()
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
