"""The attack's outputs made by a process of its own, most of their inputs ready before the graph ends.

Started once the graph's first query is journaled (until then the graph's start-up has the CPU), it
reads the window's sweeps and the drivable area and imports the drawing libraries while the graph
searches; once the search's last query is journaled it loads the re-simulation model and
re-simulates the best searched query's sweeps (what the recorded query, the last re-run of the
best, shows: a re-run has the same tracks) while the graph re-runs it. When the graph is over the
orchestrator hands it the journal's records and ends the graph while this process writes the bag;
the resources of the graph's processes follow, then summary.json, bev.png (drawn by a forked child
beside bev.gif) and report.html. The outputs are those `write_outputs` writes in the orchestrator,
byte for byte (a speculation that missed is re-simulated again).

The process is tied to the orchestrator (setpriv's parent-death signal): a killed attack leaves
nothing behind, and the journal makes the outputs again when the command runs again. Requests and
answers are pickled over a socket pair; the process's own output goes to its log.
"""

from __future__ import annotations

import contextlib
import pickle
import resource
import socket
import subprocess
import sys
from collections.abc import Sequence
from io import BufferedIOBase
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

from advsim_ros.attack.checks import Preflight
from advsim_ros.attack.options import AttackOptions
from advsim_ros.attack.summary import recorded_query
from advsim_ros.core.attack_summary import AttackSummary, Resources
from advsim_ros.core.journal import QueryRecord
from advsim_ros.core.search.driver import NOT_SEARCHED, RERUN
from advsim_ros.ros.launcher import die_with_parent, python_module_command
from advsim_ros.ros.trace import Trace

if TYPE_CHECKING:
    from advsim_ros.attack.outputs import OutputsInputs


def search_done(records: Sequence[QueryRecord], queries: int) -> bool:
    """Whether the search's own queries are journaled: its budget's worth, or a re-run already came."""
    searched = sum(record.algorithm not in NOT_SEARCHED for record in records)
    return searched >= queries or any(record.algorithm == RERUN for record in records)


class OutputsWorkerLostError(RuntimeError):
    """The worker process ended without an answer (killed, out of memory): the caller writes the outputs itself."""


class OutputsWorker:
    """The orchestrator's end: start the process, tell it what to prepare, have it write the outputs."""

    def __init__(self, options: AttackOptions, checked: Preflight, log: Path) -> None:
        self._options, self._checked, self._log = options, checked, log
        self._started = self._speculated = False

    def journaled(self, records: Sequence[QueryRecord]) -> None:
        """Follow the journal: the process starts once the first query is in (the graph's start-up has the CPU
        until then); once the search's own queries are in, it re-simulates the best of them."""
        self._start()
        if self._speculated or self._options.replay_only or not search_done(records, self._options.queries):
            return
        self._speculated = True
        best = recorded_query([record for record in records if record.algorithm not in NOT_SEARCHED])
        if best is not None and best.tracks:
            self._send("speculate", best.tracks)

    def start_writing(self, records: list[QueryRecord], journal_path: Path, wall_time: float, *rest: Any) -> None:
        """Begin the outputs (`write_outputs`' arguments after the checks, resources aside): they come later."""
        self._start()
        self._send("write", records, journal_path, wall_time, *rest)

    def _start(self) -> None:
        if self._started:
            return
        self._started = True
        ours, theirs = socket.socketpair()
        self._log.parent.mkdir(parents=True, exist_ok=True)
        with open(self._log, "ab") as output:
            command = die_with_parent(list(python_module_command(__name__, str(theirs.fileno()))))
            self._process = subprocess.Popen(
                command, pass_fds=(theirs.fileno(),), stdin=subprocess.DEVNULL, stdout=output, stderr=output
            )
        theirs.close()
        self._socket = ours
        self._stream = ours.makefile("rwb")
        self._send("prepare", self._options, self._checked)

    def finish(self, resources: Resources) -> tuple[AttackSummary, float, float]:
        """The graph's resources; returns the summary, the worker's peak resident memory [MB] and CPU time [s]."""
        self._send("resources", resources)
        try:
            answer = pickle.load(self._stream)
        except (EOFError, pickle.UnpicklingError, OSError) as error:
            raise OutputsWorkerLostError(f"the outputs process ended ({self._process.wait()}): {error}") from None
        if answer[0] == "error":
            raise answer[1]
        return answer[1], answer[2], answer[3]

    def close(self) -> None:
        if not self._started:
            return
        with contextlib.suppress(OSError):  # what is still buffered for a worker that is gone
            self._stream.close()
        self._socket.close()  # the worker reads the end of its requests and exits
        try:
            self._process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self._process.kill()
            self._process.wait()

    def _send(self, *request: Any) -> None:
        try:
            pickle.dump(request, self._stream)
            self._stream.flush()
        except OSError:  # the process is gone: finish() says so
            pass


def serve(stream: BufferedIOBase) -> None:
    """The worker's loop: prepare, speculate and write as asked, in the order asked, until the socket closes."""
    # here only: the orchestrator does not import the re-simulation (open3d) while its graph runs
    from advsim_ros.attack.outputs import adversarial_sweeps, read_outputs_inputs, write_outputs

    trace = Trace("advsim_outputs")  # ADVSIM_TRACE_DIR: when each step was done (bench/bench_attack.py)
    options: AttackOptions | None = None
    checked: Preflight | None = None
    inputs: OutputsInputs | None = None
    while True:
        try:
            request = pickle.load(stream)
        except EOFError:
            return
        if request[0] == "prepare":
            _, options, checked = request
            inputs = read_outputs_inputs(checked)
            import advsim_ros.viz.outputs  # noqa: F401  (the drawing's imports, off the outputs' clock)

            trace("prepared")
        elif request[0] == "speculate" and inputs is not None and checked is not None:
            adversarial_sweeps(inputs, checked, request[1])
            trace("speculated")
            print("re-simulated the best searched query's sweeps ahead", flush=True)
        elif request[0] == "write" and options is not None and checked is not None:
            records, journal_path, wall_time, crashes, domain_id = request[1:]

            def resources() -> Resources:
                answer = pickle.load(stream)
                assert answer[0] == "resources", answer[0]
                return cast(Resources, answer[1])  # the orchestrator's run._resources, pickled

            try:
                summary = write_outputs(
                    options, checked, records, journal_path, wall_time, crashes, domain_id, resources, inputs, fork=True
                )
                used = resource.getrusage(resource.RUSAGE_SELF)
                print(f"outputs written; sweeps re-simulated for {len(inputs.made) if inputs else 0} set(s) of tracks")
                pickle.dump(("ok", summary, used.ru_maxrss / 1024.0, used.ru_utime + used.ru_stime), stream)
            except Exception as error:  # the orchestrator raises it (user errors keep their one line)
                pickle.dump(("error", error), stream)
            stream.flush()
            return


def main() -> None:
    with socket.socket(fileno=int(sys.argv[1])) as connection, connection.makefile("rwb") as stream:
        serve(stream)


if __name__ == "__main__":
    main()
