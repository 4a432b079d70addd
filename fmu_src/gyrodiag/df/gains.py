"""Observer gains designed once: an in-process memo, seeded by the table a build ships.

Placing an observer's poles (``scipy.signal.place_poles``) takes milliseconds, but
importing ``scipy.signal`` takes 0.7-1.0 s of CPU (it imports ``scipy.stats``): most of
a Diagnoser's start-up with the detection filter, and a stall of the step that ends
its calibration window (the bank is designed there). So
:func:`gyrodiag.df.isolation.place_observer_gain` looks a design up here first:

* every gain it computes is remembered for the rest of the process (a process that
  builds the same bank twice designs it once);
* ``observer_gains.npz`` beside this module, when present and of this
  :data:`FORMAT`, seeds the memo. build_fmu.py
  writes it into the Diagnoser FMU (``resources/gyrodiag/df/observer_gains.npz``) with
  ``python fmu_src/tools/observer_gains.py --out FILE`` (the generator: the bank
  designs of the detection-filter channel with its default model and eigenvalues,
  both decision rules, at the sample periods of its ``DEFAULT_PERIODS_S``). It is a
  build output, never committed; without it every design is computed.

This module only loads and looks up; the generator lives in
``fmu_src/tools/observer_gains.py``.

A design is found by the exact bytes of its inputs (the discrete model, the output
matrix and the poles), so another model, other eigenvalues or a machine whose
discretisation differs in the last bit simply computes its gain as before. The caller
checks the poles of a gain it gets from here as it checks a computed one, and computes
the design when a remembered gain fails that check: a damaged table costs its speed,
never a result.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

#: The table a build ships beside this module (absent in a source checkout).
TABLE_FILE = Path(__file__).with_name("observer_gains.npz")

#: Format entry of a table file; a table of another format (another placement
#: algorithm) is not read.
FORMAT_KEY = "__format__"
FORMAT = "gyrodiag observer designs 1: scipy place_poles YT on the output-space basis"

#: Designs a process remembers at most (a long sweep over models must not grow it
#: without bound; ~0.5 kB each).
MAX_REMEMBERED = 4096

_memo: dict[str, NDArray[np.float64]] | None = None


def design_key(a: NDArray[np.float64], c: NDArray[np.float64], poles: NDArray) -> str:
    """Key of a pole-placement design: a hash of its inputs' shapes and exact bytes."""
    h = hashlib.sha256()
    for arr in (np.asarray(a, dtype=float), np.asarray(c, dtype=float),
                np.asarray(poles).astype(complex)):
        h.update(repr(arr.shape).encode())
        h.update(np.ascontiguousarray(arr).tobytes())
    return h.hexdigest()


def read_table(path: Path | str) -> dict[str, NDArray[np.float64]]:
    """The designs of a table file; empty if it is missing, damaged, of another format,
    or holds an entry that is not a finite 2-D gain (a table costs its speed, never a
    result: the designs are computed then)."""
    try:
        with np.load(path, allow_pickle=False) as table:
            files = set(table.files)
            if FORMAT_KEY not in files or str(table[FORMAT_KEY]) != FORMAT:
                return {}
            gains = {k: _frozen(table[k]) for k in files - {FORMAT_KEY}}
    except Exception:  # any unreadable file (empty, not an npz, truncated): compute
        return {}
    if not all(g.ndim == 2 and np.all(np.isfinite(g)) for g in gains.values()):
        return {}
    return gains


def _loaded() -> dict[str, NDArray[np.float64]]:
    global _memo
    if _memo is None:
        _memo = read_table(TABLE_FILE) if TABLE_FILE.is_file() else {}
    return _memo


def _frozen(gain: NDArray) -> NDArray[np.float64]:
    out = np.array(gain, dtype=float)
    out.setflags(write=False)
    return out


def lookup(key: str) -> NDArray[np.float64] | None:
    """The remembered gain of a design (a copy), or None."""
    gain = _loaded().get(key)
    return None if gain is None else gain.copy()


def remember(key: str, gain: NDArray[np.float64]) -> None:
    """Keep a computed gain for the rest of the process (up to :data:`MAX_REMEMBERED`
    designs; beyond, new ones are computed each time)."""
    memo = _loaded()
    if key in memo or len(memo) < MAX_REMEMBERED:
        memo[key] = _frozen(gain)


def drop(key: str) -> None:
    """Forget one design (a remembered gain that failed its caller's check)."""
    _loaded().pop(key, None)


def designs() -> dict[str, NDArray[np.float64]]:
    """Every design known to this process (the table's and those computed since)."""
    return {k: v.copy() for k, v in _loaded().items()}


def forget() -> None:
    """Drop the memo; the next lookup reads the table file again."""
    global _memo
    _memo = None


def start_empty() -> None:
    """Start an empty memo without reading the table file (a generator collects the
    designs it computes from here on)."""
    global _memo
    _memo = {}
