"""One scenario run in a process of its own: ``python -m gyrodiag_harness.cosim.worker JOB``.

:mod:`gyrodiag_harness.cosim.batch` starts one such process per scenario: pythonfmu FMUs must
not be loaded again into a process that ran them (docs/methods.md §6.11), a crash or abort of
an FMU only ends its own run, and runs can go in parallel.  ``JOB`` is a pickle written
by the batch (:class:`Job`); the run's files are saved into ``Job.out_dir`` as by
:func:`gyrodiag_harness.cosim.master.run_scenario`, and a small status file (JSON) says how the
run ended::

    {"status": "ok" | "failed" | "interrupted" | "crashed", "message": "..."}

``failed`` is a run that stopped on an FMU error (its files are saved); ``crashed`` an
exception of the harness itself (the message holds the traceback).

The saved ``signals.npz`` may hold Real signals rounded to float32 (the scenario's
``record.precision``); the batch must judge the run at full precision, so the worker
also hands the run over as it is in memory: a pickle at ``Job.handover_file`` in the
batch's private temporary folder, read once by the batch and deleted with that folder.

The process runs in a session of its own (the batch forwards Ctrl-C and SIGTERM to it
exactly once) and stops its run, keeping what it recorded, when its parent goes away.
"""

from __future__ import annotations

import json
import logging
import os
import pickle
import sys
import traceback
from dataclasses import dataclass
from typing import Any

from gyrodiag_harness.cosim.interrupt import RunInterrupted, request_stop, stop_on_signals
from gyrodiag_harness.cosim.supervision import ORPHAN_POLL_S, enter_run_process, exit_process

log = logging.getLogger(__name__)


@dataclass
class Job:
    """What one worker process runs (pickled by the batch)."""

    scenario: Any           # gyrodiag_harness.cosim.scenario.Scenario
    out_dir: str
    fmu_dir: str | None
    results_dir: str | None
    status_file: str
    progress: bool
    log_level: int
    parent_pid: int
    precision: str | None = None      # how to save (None: the scenario's record.precision)
    handover_file: str | None = None  # where to pickle the full-precision RunResult


def _stop_orphaned_run() -> None:
    """Orphan action of a batch run: a batch killed with SIGKILL cannot forward anything,
    so the run stops like on SIGTERM and keeps what it recorded."""
    request_stop("the batch that started this run exited")


def _write_status(path: str, status: str, message: str = "") -> None:
    tmp = f"{path}.part"
    with open(tmp, "w", encoding="utf-8") as fh:
        json.dump({"status": status, "message": message}, fh)
    os.replace(tmp, path)


def run_job(job: Job) -> str:
    """Run one job; returns the status written."""
    from gyrodiag_harness.cosim.master import run_scenario

    result = None
    try:
        result = run_scenario(job.scenario, fmu_dir=job.fmu_dir, progress=job.progress,
                              out_dir=job.out_dir, results_dir=job.results_dir,
                              precision=job.precision)
    except RunInterrupted as exc:
        status, message = "interrupted", exc.reason
        result = exc.result
    except Exception:
        status, message = "crashed", traceback.format_exc()
    else:
        status, message = ("ok", "") if result.error is None else ("failed", result.error)
    if result is not None and job.handover_file is not None:
        _hand_over(job.handover_file, result)
    _write_status(job.status_file, status, message)
    return status


def _hand_over(path: str, result: Any) -> None:
    # written before the status file, which the batch reads first: a status without
    # its handover means the saved files are all there is
    tmp = f"{path}.part"
    try:
        with open(tmp, "wb") as fh:
            pickle.dump(result, fh, protocol=pickle.HIGHEST_PROTOCOL)
        os.replace(tmp, path)
    except OSError as exc:  # the saved run is still there, at the stored precision
        log.warning("could not hand the full-precision run over (%s); the batch reads "
                    "the saved files", exc)


def main(argv: list[str]) -> int:
    if len(argv) != 1:
        print("usage: python -m gyrodiag_harness.cosim.worker JOB "
              "(started by gyrodiag_harness.cosim.batch)", file=sys.stderr)
        return 2
    with open(argv[0], "rb") as fh:
        job: Job = pickle.load(fh)  # written by this package's batch, never by a user
    logging.basicConfig(level=job.log_level, format="%(message)s", stream=sys.stderr)
    # first checked after one poll period: the batch is there when it starts a run
    enter_run_process(job.parent_pid, _stop_orphaned_run, first_check_after_s=ORPHAN_POLL_S)
    with stop_on_signals():  # from here on a signal never interrupts mid-call
        run_job(job)
    return 0


if __name__ == "__main__":
    try:
        code = main(sys.argv[1:])
    except KeyboardInterrupt:  # a signal before the run started: nothing to keep
        code = 130
    exit_process(code)
