"""Process supervision of campaign runs: each run in a fresh process of its own session
(:func:`execute_run`, the task the pools execute), killed at its timeout or when the
campaign stops, watched for orphaning (:func:`_exit_orphaned`), and the run
process's own entry (``python -m gyrodiag_harness.campaigns.supervise --child``).  The
process mechanics are :mod:`gyrodiag_harness.cosim.supervision`'s, shared with the scenario
batches; this module keeps the campaign's policies (kill the run's group at a stop or
timeout, :class:`~gyrodiag_harness.cosim.supervision.KillGroup`; an orphan kills its runs
and exits) and its hand-over (run dict as JSON in, ``{error, result}`` JSON out)."""

from __future__ import annotations

import importlib
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
import traceback
from collections.abc import Callable
from pathlib import Path
from typing import Any

from gyrodiag_harness.campaigns.records import write_json_atomic
from gyrodiag_harness.cosim.supervision import (
    KillGroup,
    communicate_within,
    enter_run_process,
    exit_process,
    start_in_session,
    watch_parent,
)

#: The repository: the run processes' working folder and first entry of their path.
REPO_ROOT = Path(__file__).resolve().parents[2]


def _child_env() -> dict[str, str]:
    env = dict(os.environ)
    paths = [str(REPO_ROOT), *[p for p in sys.path if p]]
    env["PYTHONPATH"] = os.pathsep.join(dict.fromkeys(paths))
    # the campaign is parallel across runs: BLAS threads inside a run only oversubscribe
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        env.setdefault(var, "1")
    return env


#: Prefix of the temporary folder of each run (input and output JSON of the run process).
RUN_TMP_PREFIX = "gd-campaign-"


def execute_run(run_dict: dict[str, Any], runner: str, timeout_s: float,
                records_dir: str) -> dict[str, Any]:
    """Run one campaign run in a fresh process and write its record; never raises.

    This is the task the pools execute.  ``runner`` is ``"module:function"``, called in
    the child with the run dict; what it returns is merged into the record.  A runner
    that raises, a process that dies, and a run longer than ``timeout_s`` (killed) are
    recorded with ``status`` ``"error"``/``"timeout"`` and the message.
    """
    t0 = time.perf_counter()
    record: dict[str, Any] = {"run": run_dict, "runner": runner}
    with tempfile.TemporaryDirectory(prefix=RUN_TMP_PREFIX) as tmp:
        inp, out = Path(tmp) / "run.json", Path(tmp) / "out.json"
        inp.write_text(json.dumps(run_dict), encoding="utf-8")
        cmd = [sys.executable, "-m", "gyrodiag_harness.campaigns.supervise", "--child", runner,
               str(inp), str(out)]
        env = {**_child_env(), PARENT_PID_ENV: str(os.getpid())}
        proc = start_in_session(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                env=env, cwd=str(REPO_ROOT), text=True)
        _LIVE_RUNS[proc] = tmp
        try:
            output = communicate_within(proc, timeout_s)
            _hold_if_stopping()
        except BaseException:
            # interrupted: the run process lives in its own session, so nobody else will
            # stop it; the run is redone on resume
            _LIVE_RUNS.pop(proc, None)
            _kill_group(proc)
            raise
        _LIVE_RUNS.pop(proc, None)
        if output is None:
            _kill_group(proc)
            record.update(status="timeout",
                          error=f"timeout: run killed after {timeout_s:g} s")
        else:
            stderr = output[1]
            payload = json.loads(out.read_text(encoding="utf-8")) if out.is_file() else None
            if payload is not None and payload.get("error") is None:
                record.update(status="ok", error=None, **payload["result"])
            elif payload is not None:
                record.update(status="error", error=payload["error"])
            else:
                tail = "\n".join(stderr.strip().splitlines()[-20:])
                record.update(status="error", error=f"run process died with exit status "
                                                    f"{proc.returncode}: {tail}")
    record["wall_s"] = time.perf_counter() - t0
    write_json_atomic(Path(records_dir) / f"{run_dict['run_id']}.json", record)
    return record


#: Run processes this process has started and not yet reaped, with their temporary
#: folders (for _worker_terminate and the orphan watch).
_LIVE_RUNS: dict[subprocess.Popen[str], str] = {}
#: Environment variable telling a run process the pid of the worker that started it.
PARENT_PID_ENV = "GYRODIAG_CAMPAIGN_PARENT_PID"


#: What a run gets when its worker stops, times it out or is orphaned: its process group
#: is killed at once (records are all or nothing; the run is redone on resume).
_STOP = KillGroup()


def _kill_group(proc: subprocess.Popen[str]) -> None:
    _STOP.kill(proc)
    proc.communicate()


def _exit_orphaned() -> None:
    """Orphan action of run processes and pool workers (:func:`watch_parent`): the process
    that started this one is gone (a killed pool worker, a closed Dask cluster, a SIGKILL
    of the campaign), so kill the runs this process started and exit: a run process has
    its own session, so no signal of the campaign reaches it, and its result would have
    nobody to read it."""
    _kill_live_runs()
    for folder in _ORPHAN_CLEANUP:
        shutil.rmtree(folder, ignore_errors=True)
    os._exit(3)


#: Folders a run process removes when it finds itself orphaned: its own temporary
#: folder, which the worker that made it can no longer remove when it was killed
#: outright (SIGKILL, a closed Dask cluster).
_ORPHAN_CLEANUP: list[str] = []


#: Set when this worker is stopping: the runs it kills must not be recorded as failed.
_STOPPING = threading.Event()


def _hold_if_stopping() -> None:
    """Called where execute_run would record a run's end: if the run ended because this
    worker is stopping (orphan watch), wait for the watch to exit the process instead of
    writing an "exit status -9" record that a resume would take as a finished run."""
    if _STOPPING.is_set():
        while True:
            time.sleep(3600)


def _kill_live_runs() -> None:
    _STOPPING.set()
    for proc, tmp in list(_LIVE_RUNS.items()):
        _STOP.kill(proc)
        shutil.rmtree(tmp, ignore_errors=True)  # os._exit follows: no with-block cleanup


def _load_runner(runner: str) -> Callable[[dict[str, Any]], dict[str, Any]]:
    module, _, func = runner.partition(":")
    if module == "harness" or module.startswith("harness."):    # records from before the rename
        module = "gyrodiag_" + module
    if not module or not func:
        raise ValueError(f"runner: {runner!r} must be 'module:function'")
    return getattr(importlib.import_module(module), func)


def _child_main(runner: str, inp: str, out: str) -> int:
    parent = int(os.environ.get(PARENT_PID_ENV, os.getppid()))
    folder = Path(inp).parent
    if folder.name.startswith(RUN_TMP_PREFIX):  # only execute_run's own folders
        _ORPHAN_CLEANUP.append(str(folder))
    enter_run_process(parent, _exit_orphaned, name="orphan-watch")
    run_dict = json.loads(Path(inp).read_text(encoding="utf-8"))
    try:
        result = _load_runner(runner)(run_dict)
        payload: dict[str, Any] = {"error": None, "result": result}
    except BaseException as exc:  # everything is recorded, even SystemExit
        payload = {"error": f"{type(exc).__name__}: {exc}\n{traceback.format_exc()}"}
    write_json_atomic(Path(out), payload)
    return 0


def _worker_init(campaign_pid: int) -> None:
    signal.signal(signal.SIGTERM, _worker_terminate)
    # Ctrl-C reaches the whole foreground process group: the campaign process decides
    # (it terminates the workers, see _iter_pool)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    watch_parent(campaign_pid, _exit_orphaned, name="orphan-watch")


def _worker_terminate(signum: int, frame: Any) -> None:
    _kill_live_runs()
    os._exit(128 + signum)


def child_entry(argv: list[str]) -> None:
    """``python -m gyrodiag_harness.campaigns.supervise --child RUNNER IN OUT``: a run process."""
    if len(argv) == 5 and argv[1] == "--child":
        exit_process(_child_main(*argv[2:]))
    print("usage: python -m gyrodiag_harness campaign SPEC.toml (this module's entry is internal)",
          file=sys.stderr)
    sys.exit(2)


if __name__ == "__main__":
    child_entry(sys.argv)
