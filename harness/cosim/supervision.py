"""Process supervision shared by scenario batches and campaign runs.

Both run every run in a child process of its own session (a Ctrl-C of the terminal
reaches the supervisor only, which decides what the run gets), keep the supervisor's
niceness there (:func:`~gyrodiag_harness.cosim.niceness.keep_niceness`), watch the
parent from the child (a supervisor killed outright cannot stop anything) and leave the
child with ``os._exit`` (pythonfmu's exit-time destructors, see harness/__main__.py).

What differs is passed in, not switched on flags:

- the *stop policy* (:class:`StopPolicy`): a scenario batch forwards the stop signal
  once and the run saves what it recorded (:class:`SaveThenKill`); a campaign keeps no
  partial run and kills the run's process group at once (:class:`KillGroup`);
- the *timeout*: ``timeout_s`` of :func:`communicate_within` (campaigns; batches have none);
- the *orphan action*: the callable given to :func:`watch_parent`;
- the *hand-over* (job in, result out), which stays with each side:
  :mod:`gyrodiag_harness.cosim.batch` and :mod:`gyrodiag_harness.campaigns.supervise`.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, NoReturn, Protocol

from gyrodiag_harness.cosim.niceness import keep_niceness

__all__ = [
    "ORPHAN_POLL_S",
    "KillGroup",
    "SaveThenKill",
    "StopPolicy",
    "Supervised",
    "communicate_within",
    "enter_run_process",
    "exit_process",
    "kill_group",
    "signal_if_running",
    "start_in_session",
    "watch_parent",
]

#: How often a run process checks that the process that started it is still there, s.
ORPHAN_POLL_S = 0.5


class Supervised(Protocol):
    """What a supervisor needs of a run process: :class:`subprocess.Popen` or a process
    forked by the batch's run server."""

    pid: int
    returncode: int | None

    def poll(self) -> int | None: ...

    def send_signal(self, signum: int) -> None: ...


# ------------------------------------------------------------------ supervisor side
def start_in_session(cmd: Sequence[str], **popen: Any) -> subprocess.Popen[Any]:
    """Start ``cmd`` in a session of its own (``popen``: further Popen arguments), so that
    no signal of the terminal or of the supervisor's group reaches it unasked."""
    return subprocess.Popen(list(cmd), start_new_session=True, **popen)


def signal_if_running(process: Supervised, signum: int) -> None:
    """Send ``signum`` to ``process`` unless it has ended already."""
    if process.poll() is None:
        try:
            process.send_signal(signum)
        except ProcessLookupError:
            pass


def kill_group(pid: int) -> None:
    """SIGKILL the process group ``pid`` leads (a run and whatever it started)."""
    try:
        os.killpg(pid, signal.SIGKILL)
    except ProcessLookupError:
        pass


def communicate_within(process: subprocess.Popen[Any], timeout_s: float | None
                       ) -> tuple[Any, Any] | None:
    """``process``'s (stdout, stderr) once it ends, or None when it is still running
    after ``timeout_s`` (None: no limit); what happens then is the caller's policy."""
    try:
        return process.communicate(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        return None


class StopPolicy(Protocol):
    """How a supervisor stops its run processes: first when asked (``stop``), then for
    good (``kill``) once ``grace_s`` has passed or on a second request."""

    grace_s: float

    def stop(self, process: Supervised, signum: int) -> None: ...

    def kill(self, process: Supervised) -> None: ...


@dataclass(frozen=True)
class SaveThenKill:
    """Scenario batches: the stop signal is forwarded once, the run stops between two
    steps and saves what it recorded; SIGKILL (the run process) after ``grace_s``."""

    grace_s: float = 30.0

    def stop(self, process: Supervised, signum: int) -> None:
        """Forward ``signum`` (SIGINT or SIGTERM) to the run."""
        signal_if_running(process, signum)

    def kill(self, process: Supervised) -> None:
        """SIGKILL the run process."""
        signal_if_running(process, signal.SIGKILL)


@dataclass(frozen=True)
class KillGroup:
    """Campaign runs: records are all or nothing, so a stopped run is killed with its
    whole process group at once and redone on resume."""

    grace_s: float = 0.0

    def stop(self, process: Supervised, signum: int = signal.SIGKILL) -> None:
        """SIGKILL the run's process group, whatever the stop signal was."""
        kill_group(process.pid)

    def kill(self, process: Supervised) -> None:
        """SIGKILL the run's process group."""
        kill_group(process.pid)


# ------------------------------------------------------------------ run process side
def watch_parent(parent_pid: int, on_orphaned: Callable[[], None], *,
                 first_check_after_s: float = 0.0, poll_s: float = ORPHAN_POLL_S,
                 name: str | None = None) -> threading.Thread:
    """Start a daemon thread that calls ``on_orphaned`` once, when this process's parent is
    no longer ``parent_pid`` (passed down by the parent, so that a parent gone before the
    thread started is noticed too); checked every ``poll_s`` after ``first_check_after_s``."""

    def watch() -> None:
        if first_check_after_s > 0:
            time.sleep(first_check_after_s)
        while True:
            if os.getppid() != parent_pid:
                on_orphaned()
                return
            time.sleep(poll_s)

    thread = threading.Thread(target=watch, daemon=True, name=name)
    thread.start()
    return thread


def enter_run_process(parent_pid: int, on_orphaned: Callable[[], None], *,
                      first_check_after_s: float = 0.0, name: str | None = None
                      ) -> threading.Thread:
    """First thing of a run process in its own session: its autogroup gets the niceness
    (a new session is a new autogroup), and the orphan watch starts (:func:`watch_parent`)."""
    keep_niceness()
    return watch_parent(parent_pid, on_orphaned, first_check_after_s=first_check_after_s,
                        name=name)


def exit_process(code: int) -> NoReturn:
    """Leave a run process: flush the output, then ``os._exit`` (pythonfmu's exit-time
    destructors must not run; see harness/__main__.py)."""
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)
