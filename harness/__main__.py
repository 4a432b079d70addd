"""``python -m harness``: see :mod:`harness.cli`.

The process ends with ``os._exit`` once the command has finished and its output is
flushed: the interpreter's own shutdown, with pythonfmu FMUs loaded, has aborted now
and then (glibc "corrupted double-linked list", after every result file had been
written, DESIGN §6.11), which would turn a passing run into exit status 134.
"""

import os
import sys

from harness.cli import main

if __name__ == "__main__":
    code = main()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)
