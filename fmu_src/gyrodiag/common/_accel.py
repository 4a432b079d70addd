"""Choice of the per-sample kernels: compiled accelerator or plain-Python fallback.

``gyrodiag.common._ckernels`` is a small C extension (``_ckernels.c``, CPython stable ABI 3.11,
no numpy C API) built by ``pip install`` and by ``build_fmu.py`` into the Diagnoser FMU
for the Python that builds it. ``gyrodiag.common._pykernels`` holds the same kernels in plain
Python floats, giving the same outputs to rounding (tests/test_kernels.py). The
extension is used when it imports; the environment variable ``GYRODIAG_KERNELS=python``
forces the fallback (benchmarks, tests, or a host where the binary misbehaves).

The choice is made once per process, at the first import of this module; the algorithm
classes take :data:`kernels` when they are constructed, so :func:`use` switches the
backend for objects built afterwards (tests and benchmarks compare both in one process).
"""

from __future__ import annotations

import os
from types import ModuleType

from . import _pykernels

__all__ = ["ACCELERATED", "IMPORT_ERROR", "kernels", "use"]

#: Why the compiled kernels are not in use ("" when they are).
IMPORT_ERROR = ""

kernels: ModuleType = _pykernels
if os.environ.get("GYRODIAG_KERNELS", "").strip().lower() == "python":
    IMPORT_ERROR = "GYRODIAG_KERNELS=python"
else:
    try:
        from . import _ckernels as _compiled  # type: ignore[attr-defined]
    except ImportError as exc:  # not built for this Python: the fallback is complete
        IMPORT_ERROR = str(exc)
    else:
        kernels = _compiled

#: True when the compiled kernels are in use.
ACCELERATED = kernels is not _pykernels


def use(name: str) -> ModuleType:
    """Select the kernels for objects constructed from now on: "c" or "python".

    Returns the previously selected module. Raises ImportError if "c" is asked for and
    the extension is not built.
    """
    global kernels, ACCELERATED
    previous = kernels
    if name == "python":
        kernels = _pykernels
    elif name == "c":
        from . import _ckernels  # type: ignore[attr-defined]

        kernels = _ckernels
    else:
        raise ValueError(f"name must be 'c' or 'python', got {name!r}")
    ACCELERATED = kernels is not _pykernels
    return previous
