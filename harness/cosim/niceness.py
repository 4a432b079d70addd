"""Run processes keep the priority their master was started with.

Every run process starts a session of its own (so that a stop can kill its process
group). On Linux with automatic scheduler groups (``kernel.sched_autogroup_enabled``,
the default of most distributions) a new session is also a new *autogroup*, and CPU
time is shared between autogroups before ``nice`` is looked at: a campaign started with
``nice -n 10`` then took as much CPU as anything else on the machine (docs/notes.md,
harness niceness). Writing
the process's nice value into ``/proc/self/autogroup`` gives the new group that weight.
"""

from __future__ import annotations

import os

__all__ = ["keep_niceness"]

AUTOGROUP = "/proc/self/autogroup"


def keep_niceness() -> int | None:
    """Give this process's autogroup its nice value; call after ``setsid``.

    Returns the nice value written, or None where there is nothing to do (nice 0, no
    autogroups, not Linux) or the kernel refused (a lower value needs privileges).
    Never raises: a run must not fail over its priority.
    """
    try:
        nice = os.nice(0)
    except OSError:
        return None
    if nice <= 0 or not os.path.exists(AUTOGROUP):
        return None
    try:
        with open(AUTOGROUP, "w", encoding="ascii") as fh:
            fh.write(str(nice))
    except OSError:
        return None
    return nice
