"""Running many scenarios: expand folders, load them all, run them in worker processes.

Used by the command line (``run``, ``verify``, ``all``, ``learn-signatures``), the pytest
plugin and anything else that runs a list of scenarios.

:func:`run_all` checks every scenario first (files, FMUs, variable names: an invalid
one stops the batch before anything runs), then runs each scenario in a fresh process
(:mod:`gyrodiag_harness.cosim.worker`; docs/methods.md §6.11: pythonfmu FMUs are not loaded
twice into one process), ``workers`` at a time, the longest first.  Each run saves its files as it
ends; results come back in scenario order and are the same whatever the number of
workers (every run is deterministic and alone in its process).  They are the runs at
full precision, as the worker held them (handed over through the batch's temporary
folder), not the saved files, which may hold Real signals rounded to float32
(``record.precision``, :meth:`RunResult.save`).

Ctrl-C or SIGTERM: no new run starts, the runs in flight get the signal once, stop
between two steps and save what they recorded (marked interrupted), and
:class:`~gyrodiag_harness.cosim.interrupt.BatchInterrupted` is raised with the results so far.
A second signal kills the runs still going (the stop policy
:class:`~gyrodiag_harness.cosim.supervision.SaveThenKill`; the process mechanics are in
:mod:`gyrodiag_harness.cosim.supervision`, shared with the campaigns).
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import pickle
import select
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gyrodiag_harness.cosim.interrupt import BatchInterrupted, stop_on_signals, stop_requested
from gyrodiag_harness.cosim.master import fault_windows, preflight
from gyrodiag_harness.cosim.results import META_FILE, PRECISIONS, RunResult
from gyrodiag_harness.cosim.scenario import Scenario, ScenarioError, load_scenario
from gyrodiag_harness.cosim.supervision import SaveThenKill, Supervised, start_in_session
from gyrodiag_harness.cosim.worker import Job

log = logging.getLogger(__name__)

#: After forwarding a stop request, how long the runs get to stop and save, s.
STOP_GRACE_S = 30.0
#: What the runs in flight get on a stop request: the signal once, SIGKILL after the grace.
_STOP = SaveThenKill(grace_s=STOP_GRACE_S)
_POLL_S = 0.01


def default_workers() -> int:
    """Number of parallel runs by default: the CPUs this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


def scenario_files(paths: Sequence[Path]) -> list[Path]:
    """Expand folders to their ``*.toml`` files (sorted); files are kept as given."""
    files: list[Path] = []
    for p in paths:
        if p.is_dir():
            found = sorted(p.glob("*.toml"))
            if not found:
                raise FileNotFoundError(f"{p}: no .toml scenario files in this folder")
            files += found
        else:
            files.append(p)
    return files


def load_all(paths: Sequence[Path]) -> list[Scenario]:
    """Load every scenario, reporting all invalid files at once (ScenarioError)."""
    scenarios, errors = [], []
    for f in scenario_files(paths):
        try:
            scenarios.append(load_scenario(f))
        except ScenarioError as exc:
            errors.append(exc)
    if errors:
        raise ScenarioError(errors[0].source, errors[0].problems) if len(errors) == 1 else \
            _merged(errors)
    names = [s.name for s in scenarios]
    for s in scenarios:
        if names.count(s.name) > 1:
            others = [o.source for o in scenarios if o.name == s.name and o is not s]
            raise ScenarioError(s.source, [("name", f"scenario name {s.name!r} is also used by "
                                                    f"{', '.join(others)}: results would "
                                                    "overwrite each other")])
    return scenarios


def _merged(errors: list[ScenarioError]) -> ScenarioError:
    merged = ScenarioError(errors[0].source, errors[0].problems)
    merged.args = ("\n".join(str(e) for e in errors),)
    return merged


def summary_line(result: RunResult, out_dir: Path | None) -> str:
    """One line per run: outcome, samples, simulated and wall time, where it was saved."""
    n = len(result.time)
    where = f" -> {out_dir}" if out_dir is not None else ""
    if result.error is None:
        return (f"{result.scenario}: ok, {n} samples of {len(result.signals)} signals, "
                f"{result.stop_time_s:g} s simulated in {result.wall_time_s:.1f} s{where}")
    first = result.error.strip().splitlines()[0] if result.error.strip() else "error"
    t_end = f"{result.time[-1]:g} s" if n else "nothing"
    outcome = "INTERRUPTED" if result.interrupted else "ERROR"
    return (f"{result.scenario}: {outcome} ({t_end} recorded of {result.stop_time_s:g} s): "
            f"{first}{where}")


#: Environment variable: ``0`` starts every run process with ``python -m`` instead of
#: forking it from a pre-imported server (:mod:`gyrodiag_harness.cosim.zygote`).
FORK_SERVER_ENV = "GYRODIAG_FORK_SERVER"


class _ForkedRun:
    """The part of :class:`subprocess.Popen` the batch uses, for a run process forked by
    the server: ``pid``, ``poll()``, ``returncode``, ``send_signal()``
    (:class:`~gyrodiag_harness.cosim.supervision.Supervised`)."""

    def __init__(self, pid: int, server: _RunServer) -> None:
        self.pid = pid
        self.returncode: int | None = None
        self._server = server

    def poll(self) -> int | None:
        if self.returncode is None:
            self.returncode = self._server.exit_code(self.pid)
        return self.returncode

    def send_signal(self, signum: int) -> None:
        os.kill(self.pid, signum)


class _RunServer:
    """Client of :mod:`gyrodiag_harness.cosim.zygote`: forks run processes from a process that
    has imported the harness already (0.2 s of CPU saved per run)."""

    def __init__(self) -> None:
        request_r, self._request_w = os.pipe()
        self._reply_r, reply_w = os.pipe()
        try:
            self.process = start_in_session(
                [sys.executable, "-m", "gyrodiag_harness.cosim.zygote", str(request_r),
                 str(reply_w)],
                pass_fds=(request_r, reply_w), stdin=subprocess.DEVNULL)
        finally:
            os.close(request_r)
            os.close(reply_w)
        self._buffer = b""
        self._pids: list[int] = []
        self._exits: dict[int, int] = {}

    def _read(self, block: bool) -> None:
        """Parse the server's reply lines; wait for one read if ``block``. Unbuffered
        (os.read) so that select() never misses a line already read."""
        fd = self._reply_r
        while block or select.select([fd], [], [], 0)[0]:
            data = os.read(fd, 65536)
            if not data:
                raise OSError("the run-process server (gyrodiag_harness.cosim.zygote) exited")
            self._buffer += data
            *lines, self._buffer = self._buffer.split(b"\n")
            for line in lines:
                kind, number, *rest = line.decode().split()
                if kind == "pid":
                    self._pids.append(int(number))
                elif kind == "exit":
                    self._exits[int(number)] = int(rest[0])
            block = False

    def spawn(self, job_file: Path) -> _ForkedRun:
        os.write(self._request_w, f"{job_file}\n".encode())
        while not self._pids:
            self._read(block=True)
        return _ForkedRun(self._pids.pop(0), self)

    def exit_code(self, pid: int) -> int | None:
        try:
            self._read(block=False)
        except OSError:  # the server is gone; the exits it reported are kept
            pass
        if pid in self._exits:
            return self._exits.pop(pid)
        if self.process.poll() is not None:  # the server died: ask the system
            try:
                os.kill(pid, 0)
            except ProcessLookupError:
                return -signal.SIGKILL  # gone without a report: treated as killed
        return None

    def close(self) -> None:
        """No more runs: the server exits (runs still going on stop as orphans)."""
        try:
            os.close(self._request_w)
        except OSError:
            pass
        try:
            self.process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.process.kill()
        os.close(self._reply_r)


def _run_server(n_runs: int) -> _RunServer | None:
    """A fork server for a batch of several runs, where the system has fork; None (start
    each run with ``python -m``) otherwise or when ``GYRODIAG_FORK_SERVER=0``."""
    if n_runs < 2 or not hasattr(os, "fork") or os.environ.get(FORK_SERVER_ENV) == "0":
        return None
    try:
        return _RunServer()
    except OSError as exc:
        log.warning("run-process server not started (%s); starting each run on its own",
                    exc)
        return None


@dataclass
class _Running:
    index: int
    process: Supervised
    job_file: Path
    status_file: Path
    handover_file: Path
    killed: bool = False


def _cost(s: Scenario) -> float:
    # FMU steps to take: what a run's wall time grows with (longest first packs best)
    return s.n_steps * sum(1.0 / i.step_ratio for i in s.fmus.values())


def run_all(scenarios: Sequence[Scenario], out: Path | Sequence[Path],
            fmu_dir: Path | None = None,
            progress: bool = True, *, workers: int | None = 1,
            results_dir: Path | None = None, precision: str | None = None
            ) -> list[RunResult]:
    """Run scenarios, each in a process of its own, saving each into ``out/<name>``.

    Parameters
    ----------
    scenarios : sequence of Scenario
        Loaded scenarios (:func:`load_all`), names unique.
    out : Path or sequence of Path
        Results folder; ``out/<scenario name>/`` per run. A sequence gives each
        scenario its own folder (e.g. training runs beside seed scenarios in one batch).
    fmu_dir : Path, optional
        Folder of the FMUs (default: per scenario, see
        :func:`gyrodiag_harness.cosim.scenario.resolve_fmu_dir`).
    progress : bool
        Progress bar of the run in flight (one worker, terminal only).
    workers : int, optional
        Runs at the same time, >= 1; None: :func:`default_workers`.
    results_dir : Path, optional
        What ``${out}/`` stands for in ``files`` parameters (default ``out``).
    precision : {"compact", "float32", "float64"}, optional
        How the saved files store Real signals (:meth:`RunResult.save`); default each
        scenario's ``record.precision``.

    Returns
    -------
    list of RunResult
        In scenario order, at full precision whatever ``precision`` saved.

    Raises
    ------
    ScenarioError, FileNotFoundError
        Before anything runs: every problem of every scenario at once.
    BatchInterrupted
        Ctrl-C or SIGTERM (see the module's doc).
    """
    workers, outs = _checked_arguments(scenarios, out, workers, precision)
    results_dir = (outs[0] if outs else Path(".")) if results_dir is None \
        else Path(results_dir)
    preflight_all(scenarios, fmu_dir, results_dir)
    order = sorted(range(len(scenarios)), key=lambda i: -_cost(scenarios[i]))
    results, not_started = _supervise(scenarios, order, outs, fmu_dir, results_dir, workers,
                                      progress, precision)
    reason = stop_requested()
    if reason is not None:
        raise BatchInterrupted(reason, [r for r in results if r is not None],
                               [scenarios[i].name for i in not_started])
    return [r for r in results if r is not None]


def _checked_arguments(scenarios: Sequence[Scenario], out: Path | Sequence[Path],
                       workers: int | None, precision: str | None) -> tuple[int, list[Path]]:
    """:func:`run_all`'s worker count (None: the default) and one results folder per
    scenario; ValueError for a bad worker count, precision or number of folders."""
    if workers is None:
        workers = default_workers()
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ValueError(f"workers must be an integer >= 1, got {workers!r}")
    if precision is not None and precision not in PRECISIONS:
        raise ValueError(f"precision must be one of {', '.join(map(repr, PRECISIONS))} or "
                         f"None, got {precision!r}")
    if isinstance(out, (str, Path)):
        outs = [Path(out)] * len(scenarios)
    else:
        outs = [Path(o) for o in out]
        if len(outs) != len(scenarios):
            raise ValueError(f"out must be one folder or one per scenario ({len(scenarios)}),"
                             f" got {len(outs)}")
    return workers, outs


def _supervise(scenarios: Sequence[Scenario], order: list[int], outs: list[Path],
               fmu_dir: Path | None, results_dir: Path, workers: int, progress: bool,
               precision: str | None) -> tuple[list[RunResult | None], list[int]]:
    """Run the scenarios in ``order``, ``workers`` at a time, until all ended or a stop
    request (module doc) ended those in flight; returns the results by scenario index
    (None: not run) and the indices never started."""
    results: list[RunResult | None] = [None] * len(scenarios)
    running: dict[int, _Running] = {}
    not_started: list[int] = []
    forwarded_at: float | None = None

    def kill_all(signum: int) -> None:
        for r in running.values():
            _STOP.kill(r.process)
            r.killed = True

    server = _run_server(len(scenarios))
    with tempfile.TemporaryDirectory(prefix="gyrodiag-batch-") as tmp, \
            stop_on_signals(on_second=kill_all), contextlib.ExitStack() as stack:
        if server is not None:
            stack.callback(server.close)
        pending = list(order)
        while pending or running:
            reason = stop_requested()
            if reason is not None and forwarded_at is None:
                not_started = sorted(pending)
                pending.clear()
                forwarded_at = _forward_stop(reason, running)
            while pending and len(running) < workers:
                i = pending.pop(0)
                running[i] = _start(scenarios[i], i, outs[i], fmu_dir, results_dir, Path(tmp),
                                    progress and workers == 1, precision, server)
            _collect_ended(scenarios, outs, running, results)
            if forwarded_at is not None and time.monotonic() - forwarded_at > _STOP.grace_s:
                kill_all(signal.SIGKILL)
            if running:
                time.sleep(_POLL_S)
    return results, not_started


def _forward_stop(reason: str, running: dict[int, _Running]) -> float:
    """Give the runs in flight the stop request (its signal, SIGTERM if none); returns
    when, for the grace period."""
    signum = getattr(signal, reason, signal.SIGTERM) if reason.startswith("SIG") \
        else signal.SIGTERM
    for r in running.values():
        _STOP.stop(r.process, signum)
    forwarded_at = time.monotonic()
    if running:
        log.warning("%s: stopping %d run(s) in flight, starting nothing new",
                    reason, len(running))
    return forwarded_at


def _collect_ended(scenarios: Sequence[Scenario], outs: list[Path],
                   running: dict[int, _Running], results: list[RunResult | None]) -> None:
    """Move the runs that ended from ``running`` into ``results``, logging each."""
    for i, r in list(running.items()):
        if r.process.poll() is None:
            continue
        del running[i]
        results[i] = _collect(scenarios[i], outs[i] / scenarios[i].name, r)
        _log_result(results[i], outs[i] / scenarios[i].name)


def preflight_all(scenarios: Sequence[Scenario], fmu_dir: Path | None,
                  results_dir: Path) -> None:
    """:func:`gyrodiag_harness.cosim.master.preflight` of every scenario; raises one ScenarioError
    naming every problem of every scenario (FileNotFoundError for a missing FMU)."""
    errors: list[ScenarioError] = []
    for s in scenarios:
        try:
            preflight(s, fmu_dir, results_dir)
        except ScenarioError as exc:
            errors.append(exc)
    if errors:
        raise errors[0] if len(errors) == 1 else _merged(errors)


def _start(scenario: Scenario, index: int, out: Path, fmu_dir: Path | None,
           results_dir: Path, tmp: Path, progress: bool, precision: str | None,
           server: _RunServer | None = None) -> _Running:
    job_file = tmp / f"job-{index}.pickle"
    status_file = tmp / f"status-{index}.json"
    handover_file = tmp / f"run-{index}.pickle"
    job = Job(scenario=scenario, out_dir=str(out / scenario.name),
              fmu_dir=None if fmu_dir is None else str(fmu_dir),
              results_dir=str(results_dir), status_file=str(status_file), progress=progress,
              log_level=logging.getLogger("gyrodiag_harness").getEffectiveLevel(),
              parent_pid=os.getpid() if server is None else server.process.pid,
              precision=precision,
              handover_file=str(handover_file))
    job_file.write_bytes(pickle.dumps(job))
    log.debug("%s: starting", scenario.name)
    # a session of its own: the terminal's Ctrl-C reaches the batch only, which forwards
    # it exactly once (a second one would be "stop now" inside the run)
    process: Supervised | None = None
    if server is not None:
        try:
            process = server.spawn(job_file)
        except OSError as exc:
            log.warning("%s: the run-process server failed (%s); starting the run on its "
                        "own", scenario.name, exc)
            job.parent_pid = os.getpid()
            job_file.write_bytes(pickle.dumps(job))
    if process is None:
        process = start_in_session([sys.executable, "-m", "gyrodiag_harness.cosim.worker",
                                    str(job_file)], stdin=subprocess.DEVNULL)
    return _Running(index, process, job_file, status_file, handover_file)


def _collect(scenario: Scenario, target: Path, run: _Running) -> RunResult:
    status, message = "", ""
    if run.status_file.is_file():
        data = json.loads(run.status_file.read_text(encoding="utf-8"))
        status, message = str(data.get("status", "")), str(data.get("message", ""))
    if status in ("ok", "failed", "interrupted") and (target / META_FILE).is_file():
        return _handed_over(run.handover_file) or RunResult.load(target)
    if status == "crashed":
        error = f"the harness failed in the run process:\n{message}"
    else:
        code = run.process.returncode
        how = (f"was killed by {signal.Signals(-code).name}" if code < 0 else
               f"exited with status {code}")
        error = f"the run process {how} before saving its run"
        if run.killed:
            error += " (stopped at once on a second stop request)"
    result = RunResult(scenario=scenario.name, time=np.zeros(0), signals={},
                       fault_windows=fault_windows(scenario), step_s=scenario.step_s,
                       error=error, stop_time_s=scenario.duration_s,
                       interrupted=run.killed or stop_requested() is not None)
    result.save(target)
    return result


def _handed_over(path: Path) -> RunResult | None:
    # the worker's full-precision run; written by this batch's own child into the
    # batch's private temporary folder, never by a user
    if not path.is_file():
        return None
    try:
        with open(path, "rb") as fh:
            result = pickle.load(fh)
    except Exception as exc:  # the saved files are still there
        log.warning("%s: unreadable full-precision run (%s); using the saved files", path,
                    exc)
        return None
    path.unlink(missing_ok=True)
    return result if isinstance(result, RunResult) else None


def _log_result(result: RunResult, target: Path) -> None:
    log.info("%s", summary_line(result, target))
    if result.error is not None and not result.interrupted and "\n" in result.error.strip():
        log.error("%s", _indent(result.error))


def _indent(text: str) -> str:
    return "\n".join("    " + line for line in text.strip().splitlines())
