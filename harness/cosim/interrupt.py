"""Stop requests: Ctrl-C and SIGTERM end a run between two steps, never inside an FMU.

pythonfmu FMUs run their Python code in the host's interpreter, so Python's default
SIGINT handler raises KeyboardInterrupt wherever the main thread happens to be, most of
the time inside an FMU's doStep, which turns it into fmi2Fatal and loses the instance.
While :func:`stop_on_signals` is active, SIGINT and SIGTERM only *record* a stop request;
the master looks at it between steps (:func:`stop_requested`), stops the run there,
frees its FMUs, keeps the partial record and raises :class:`RunInterrupted`.

A second signal while a stop is already requested is taken as "stop now": in a process
that runs FMUs it raises KeyboardInterrupt at once (the user insisted; an FMU may see
it), in a process that only supervises runs (:mod:`gyrodiag_harness.cosim.batch`) it kills them.

Outside the main thread no handler can be installed; :func:`request_stop` sets the same
request from code (a test, a pytest plugin, an orphan watch).
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Callable, Iterator
from typing import Any

__all__ = [
    "EXIT_INTERRUPTED",
    "BatchInterrupted",
    "RunInterrupted",
    "clear_stop",
    "request_stop",
    "stop_on_signals",
    "stop_requested",
]

#: Exit status of a command stopped by a signal (the shell's 128 + SIGINT).
EXIT_INTERRUPTED = 130

_SIGNALS = tuple(s for s in (getattr(signal, "SIGINT", None), getattr(signal, "SIGTERM", None))
                 if s is not None)
_reason: str | None = None
_depth = 0
_on_second: Callable[[int], None] | None = None


class RunInterrupted(KeyboardInterrupt):
    """A run stopped on request between two steps; ``result`` holds what it recorded.

    A KeyboardInterrupt, so that a script that does not catch it stops as on Ctrl-C.
    """

    def __init__(self, reason: str, result: Any = None) -> None:
        super().__init__(reason)
        self.reason = reason
        self.result = result


class BatchInterrupted(KeyboardInterrupt):
    """A batch of runs stopped on request.

    Attributes
    ----------
    reason : str
        What stopped it (``"SIGINT"``, ``"SIGTERM"``, ...).
    results : list of RunResult
        The runs that finished plus the partial runs in flight, in scenario order.
    not_started : list of str
        Names of the scenarios that were not started.
    """

    def __init__(self, reason: str, results: list[Any], not_started: list[str]) -> None:
        super().__init__(reason)
        self.reason = reason
        self.results = results
        self.not_started = not_started


def stop_requested() -> str | None:
    """What requested a stop (``"SIGINT"``, ``"SIGTERM"``, ...), or None."""
    return _reason


def request_stop(reason: str = "stop requested") -> None:
    """Ask the runs of this process to stop at their next step (thread-safe)."""
    global _reason
    if _reason is None:
        _reason = reason


def clear_stop() -> None:
    """Forget a stop request (before starting new work on purpose)."""
    global _reason
    _reason = None


def _handler(signum: int, frame: Any) -> None:
    global _reason
    if _reason is not None:
        if _on_second is not None:
            _on_second(signum)
            return
        raise KeyboardInterrupt(f"{signal.Signals(signum).name} again: stopping now")
    _reason = signal.Signals(signum).name


@contextlib.contextmanager
def stop_on_signals(on_second: Callable[[int], None] | None = None) -> Iterator[None]:
    """While active (main thread only), SIGINT and SIGTERM record a stop request.

    Nested uses keep the outer handlers. The request itself is not cleared on exit: the
    caller decides what a request means once it has stopped (see :func:`clear_stop`).

    Parameters
    ----------
    on_second : callable, optional
        Called with the signal number when a signal arrives while a stop is already
        requested; default: raise KeyboardInterrupt.
    """
    global _depth, _on_second
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    if _depth:
        _depth += 1
        try:
            yield
        finally:
            _depth -= 1
        return
    # a signal ignored on purpose (nohup, a background job of a non-interactive shell)
    # stays ignored, as Python's own SIGINT handling does
    previous = {s: h for s in _SIGNALS if (h := signal.getsignal(s)) is not signal.SIG_IGN}
    _on_second = on_second
    _depth = 1
    try:
        for s in previous:
            signal.signal(s, _handler)
        yield
    finally:
        for s, h in previous.items():
            signal.signal(s, h if h is not None else signal.SIG_DFL)
        _depth = 0
        _on_second = None
