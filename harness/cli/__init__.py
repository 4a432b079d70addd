"""Command line of the harness (``python -m gyrodiag_harness COMMAND``, or the ``gyrodiag``
console script): see :mod:`gyrodiag_harness.cli.commands`."""

import os
import sys

from gyrodiag_harness.cli.commands import main

__all__ = ["console", "main"]


def console() -> None:
    """Run :func:`main` and end the process with ``os._exit`` once output is flushed
    (why: harness/__main__.py)."""
    code = main()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)
