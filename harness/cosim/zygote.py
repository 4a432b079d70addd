"""A pre-imported server that forks the run processes of a batch.

``python -m gyrodiag_harness.cosim.zygote REQUEST_FD REPLY_FD`` (started by
:mod:`gyrodiag_harness.cosim.batch`). Starting Python and importing the harness costs about 0.2 s
of CPU per run, as much as a short run itself; this process imports
:mod:`gyrodiag_harness.cosim.worker` once and, for each job file named on ``REQUEST_FD`` (one path
per line), forks a child that starts a session of its own and runs exactly what
``python -m gyrodiag_harness.cosim.worker JOB`` runs. It answers ``pid N`` for every child and
``exit N CODE`` when the child ends (``CODE`` as :attr:`subprocess.Popen.returncode`:
negative for a signal).

The server never loads an FMU, so every child starts without one (pythonfmu FMUs must
not be loaded twice into a process, docs/methods.md §6.11), and it has no thread (children are
reaped by a SIGCHLD handler), so a fork copies a consistent process. It exits when the
request pipe closes, i.e. when its batch is done or has died; children still running
then see their parent change and stop as orphans of a killed batch do
(:func:`gyrodiag_harness.cosim.worker._stop_orphaned_run`).
"""

from __future__ import annotations

import os
import signal
import sys

from gyrodiag_harness.cosim import master, worker
from gyrodiag_harness.cosim.supervision import exit_process

# what a run process imports anyway, once here instead of once per run
_PRELOADED = (master, worker)

#: Children not yet reaped.
_children: set[int] = set()
_reply_fd = -1


def _reap(signum: int, frame: object) -> None:
    while _children:
        try:
            pid, status = os.waitpid(-1, os.WNOHANG)
        except ChildProcessError:
            return
        if pid == 0:
            return
        _children.discard(pid)
        os.write(_reply_fd, f"exit {pid} {os.waitstatus_to_exitcode(status)}\n".encode())


def _run_child(job_file: str, request_fd: int) -> None:
    """In the forked child: what ``python -m gyrodiag_harness.cosim.worker JOB`` does."""
    os.setsid()  # a session of its own, as start_new_session gives the Popen path
    os.close(request_fd)
    os.close(_reply_fd)
    signal.signal(signal.SIGCHLD, signal.SIG_DFL)
    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    code = 1
    try:
        code = worker.main([job_file])
    except KeyboardInterrupt:  # a signal before the run started: nothing to keep
        code = 130
    finally:
        exit_process(code)  # never return into the server's loop


def serve(request_fd: int, reply_fd: int) -> None:
    """Fork a run process for every job file read from ``request_fd``."""
    global _reply_fd
    _reply_fd = reply_fd
    signal.signal(signal.SIGCHLD, _reap)
    with os.fdopen(request_fd, "r", encoding="utf-8", closefd=False) as requests:
        for line in requests:
            job_file = line.rstrip("\n")
            if not job_file:
                continue
            signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGCHLD})
            try:
                pid = os.fork()
                if pid == 0:
                    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGCHLD})
                    _run_child(job_file, request_fd)
                _children.add(pid)
                os.write(reply_fd, f"pid {pid}\n".encode())
            finally:
                signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGCHLD})


def main(argv: list[str]) -> int:
    if len(argv) != 2:
        print("usage: python -m gyrodiag_harness.cosim.zygote REQUEST_FD REPLY_FD (started by "
              "gyrodiag_harness.cosim.batch)", file=sys.stderr)
        return 2
    # the batch forwards Ctrl-C and SIGTERM to the runs itself; the server just ends
    # when its request pipe closes
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    serve(int(argv[0]), int(argv[1]))
    return 0


if __name__ == "__main__":
    exit_process(main(sys.argv[1:]))
