"""Recorded co-simulation runs: :class:`RunResult`, :class:`FaultWindow`, and their files.

A run directory holds two files:

* ``signals.npz`` — a numpy compressed archive (deflate), one entry per column
  (``time`` first, then one per signal named ``instance.variable``), each stored as
  compactly as its values allow (``run.json`` says how, under ``signal_storage``):

  ========== ==================================================== ======================
  storage    entry                                                 exact?
  ========== ==================================================== ======================
  float64    uint8 (8, N): the 8 byte planes of the float64        every bit
             samples (byte 0 of every sample, then byte 1, ...)
  float32    uint8 (4, N): the 4 byte planes of float32 samples    exact unless the
                                                                   signal is listed in
                                                                   ``rounded_signals``
  int8...64  the samples as integers, shape (N,)                   exact
  constant   float64 (1,): the one value every sample has          exact
  ========== ==================================================== ======================

  ``time`` is always float64.  A signal whose values are all integers (Booleans,
  Integers, codes), one constant value, or float32 numbers is stored exactly in the
  smallest of these.  Any other Real signal is rounded (to nearest) as the
  ``precision`` of the save asks (the scenario's ``[record] precision``):

  ========= ===================================================================
  compact   (default) signals an expectation of the scenario reads (every signal of
            a training scenario): float32, ``|stored − value| ≤ 2⁻²⁴·|value|``
            (6e-8); the other Real signals, recorded for plots and inspection: 13
            significant bits, ``≤ 2⁻¹³·|value|`` (1.2e-4, about 4 significant digits)
  float32   every Real signal to float32 (≤ 2⁻²⁴)
  float64   nothing rounded
  ========= ===================================================================

  Rounding keeps NaN, ±inf and the sign of zeros; a signal whose magnitudes leave
  float32's normal range (1.2e-38 … 3.4e38) stays float64.  ``run.json`` maps each
  rounded signal to its bound (``rounded_signals``).  The main job's scenario runs take
  about a sixth of the space of float64 this way (docs/notes.md).

  Verdicts do not depend on this: a command that runs scenarios judges the run it
  holds in memory at full precision (:func:`gyrodiag_harness.cosim.batch.run_all` hands each
  run's full-precision signals from its worker process over); only ``report`` on saved
  runs, ``learn-signatures --saved`` and reloads read the stored values.  Read a run
  with :meth:`RunResult.load`, or with numpy alone: ``planes = np.load(f)[name]``, then
  ``planes.T.copy().view("<f8" or "<f4").ravel()`` for byte planes; ``python -m gyrodiag_harness
  export-csv`` writes ``signals.csv`` (:meth:`RunResult.export_csv`).
* ``run.json`` — everything else: scenario name, base step, planned duration, wall time,
  error text (``null`` when the run completed), whether a stop request interrupted it,
  fault windows (an open end is written as ``null`` because JSON has no infinity), the
  signal names in column order and how each is stored.  A run whose signals were not
  kept (:func:`drop_signals`: the DTG training runs of ``harness all``) has only this
  file, and ``signals_dropped`` says why.

Runs saved by earlier versions still load: format 2 (every column as float64 byte
planes, lossless) and format 1 (``signals.csv``).

Sample convention (contract): row ``k`` holds time ``t_k`` and the values read from every
FMU after the master stepped all FMUs to ``t_k``; row 0 is the state after initialisation.
"""

from __future__ import annotations

import csv
import difflib
import json
import math
import os
import tempfile
import zipfile
import zlib
from collections.abc import Collection
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

SIGNALS_FILE = "signals.npz"
CSV_FILE = "signals.csv"
META_FILE = "run.json"
_FORMAT_VERSION = 3
_TIME_KEY = "time"
_ENCODING = "per-signal"                 # format 3: storage chosen per column
_V2_ENCODING = "float64-byte-planes"     # format 2: every column float64

#: How Real signals that no exact compact form fits are stored (module doc):
#: ``"compact"`` (what expectations read as float32, the rest to
#: :data:`CONTEXT_SIGNIFICANT_BITS`), ``"float32"`` (all float32) or ``"float64"``.
PRECISIONS = ("compact", "float32", "float64")
DEFAULT_PRECISION = "compact"
#: Bound of ``|stored - value| / |value|`` for a signal rounded to float32: half a unit
#: in the last place of float32's 24-bit significand.
FLOAT32_MAX_RELATIVE_ERROR = 2.0 ** -24
#: Significant bits (implicit leading bit included) of a Real signal that ``"compact"``
#: stores for plots and inspection only (no expectation reads it).
CONTEXT_SIGNIFICANT_BITS = 13
#: Bound of ``|stored - value| / |value|`` for such a signal (about 4 significant digits).
CONTEXT_MAX_RELATIVE_ERROR = 2.0 ** -CONTEXT_SIGNIFICANT_BITS

_FLOAT32_MAX = float(np.finfo(np.float32).max)
_FLOAT32_TINY = float(np.finfo(np.float32).tiny)  # smallest normal: below it the bound fails
_INTEGER_TYPES = ("int8", "int16", "int32", "int64")


@dataclass
class FaultWindow:
    """When and where a scheduled fault acts.

    Attributes
    ----------
    name : str
        Fault name from the scenario, e.g. ``"q_bias"``.
    target : str
        Affected signal or parameter, ``"instance.variable"`` (``"injector.out_3"`` for an
        injector channel, ``"dtg.spin_fraction"`` for a physical fault).
    kind : str
        Fault type name (``"bias"``, ``"gain"``, ...) or ``"physical"``.
    start_s : float
        Start time (s).
    end_s : float
        End time (s); ``math.inf`` when the fault never ends.
    """

    name: str
    target: str
    kind: str
    start_s: float
    end_s: float = math.inf

    def to_json(self) -> dict[str, Any]:
        """Plain dict for ``run.json`` (open end as ``None``)."""
        return {"name": self.name, "target": self.target, "kind": self.kind,
                "start_s": self.start_s,
                "end_s": None if math.isinf(self.end_s) else self.end_s}

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> FaultWindow:
        """Inverse of :meth:`to_json`."""
        end = data.get("end_s")
        return cls(name=str(data["name"]), target=str(data["target"]), kind=str(data["kind"]),
                   start_s=float(data["start_s"]),
                   end_s=math.inf if end is None else float(end))


@dataclass
class RunResult:
    """Signals recorded in one scenario run plus its fault schedule and outcome.

    Attributes
    ----------
    scenario : str
        Scenario name.
    time : ndarray, shape (N,)
        Recorded communication points (s).
    signals : dict of str to ndarray, shape (N,)
        ``"instance.variable"`` → values as float (Booleans 0/1, Integers as float).
    fault_windows : list of FaultWindow
        The scheduled faults.
    step_s : float
        Base communication step (s).
    error : str or None
        ``None`` if the run completed, else what stopped it (with the FMU's log lines).
    wall_time_s : float
        Wall-clock duration of the run (s).
    stop_time_s : float
        Planned simulated duration (s).
    manoeuvre_windows : list of FaultWindow
        The scheduled manoeuvres (``kind`` = manoeuvre kind, ``target`` = the instance that
        flies it); fault-free time for false-alarm counts.
    interrupted : bool
        True if a stop request (Ctrl-C, SIGTERM) ended the run early; ``error`` then
        says by what and where.
    rounded_signals : dict of str to float
        Signals whose samples were rounded when the run was saved (a loaded run), each
        mapped to the bound of ``|stored - value| / |value|`` for its samples
        (:data:`FLOAT32_MAX_RELATIVE_ERROR` or :data:`CONTEXT_MAX_RELATIVE_ERROR`).
        Empty for a run held in memory since it ran.
    """

    scenario: str
    time: np.ndarray
    signals: dict[str, np.ndarray]
    fault_windows: list[FaultWindow] = field(default_factory=list)
    step_s: float = 0.0
    error: str | None = None
    wall_time_s: float = 0.0
    stop_time_s: float = 0.0
    manoeuvre_windows: list[FaultWindow] = field(default_factory=list)
    interrupted: bool = False
    rounded_signals: dict[str, float] = field(default_factory=dict)

    @property
    def completed(self) -> bool:
        """True if the run reached its stop time without an error."""
        return self.error is None

    def signal(self, name: str) -> np.ndarray:
        """Samples of one recorded signal.

        Raises
        ------
        KeyError
            If ``name`` was not recorded; the message lists close names (or all names).
        """
        try:
            return self.signals[name]
        except KeyError:
            raise KeyError(_missing_signal_message(name, list(self.signals))) from None

    def manoeuvre(self, name: str) -> FaultWindow:
        """The manoeuvre window called ``name`` (KeyError listing the known ones)."""
        for window in self.manoeuvre_windows:
            if window.name == name:
                return window
        known = ", ".join(w.name for w in self.manoeuvre_windows) or "none"
        raise KeyError(f"run {self.scenario!r} has no manoeuvre {name!r}; manoeuvres: {known}")

    def fault(self, name: str) -> FaultWindow:
        """The fault window called ``name`` (KeyError listing the known faults)."""
        for window in self.fault_windows:
            if window.name == name:
                return window
        known = ", ".join(w.name for w in self.fault_windows) or "none"
        raise KeyError(f"run {self.scenario!r} has no fault {name!r}; faults: {known}")

    # ------------------------------------------------------------------ files
    def _columns(self) -> tuple[list[str], list[np.ndarray]]:
        names = list(self.signals)
        columns = [np.asarray(self.time, dtype=float)]
        columns += [np.asarray(self.signals[n], dtype=float) for n in names]
        n_rows = len(columns[0])
        for name, col in zip(names, columns[1:], strict=True):
            if col.shape != (n_rows,):
                raise ValueError(f"signal {name!r} has shape {col.shape}, time has ({n_rows},)")
        return names, columns

    def save(self, directory: Path | str, precision: str = DEFAULT_PRECISION,
             judged: Collection[str] = ()) -> None:
        """Write ``signals.npz`` and ``run.json`` into ``directory`` (created if needed).

        Parameters
        ----------
        directory : path
            The run's folder.
        precision : {"compact", "float32", "float64"}
            How to store a Real signal that no exact compact storage fits (module doc):
            ``"compact"`` rounds the signals in ``judged`` to float32 (relative error
            <= 2**-24) and the others to 13 significant bits (<= 2**-13),
            ``"float32"`` rounds every one to float32, ``"float64"`` keeps every bit.
            ``time``, integer-valued, constant and float32-exact signals are stored
            exactly in any case.
        judged : collection of str
            Signals that an expectation reads (kept to float32 by ``"compact"``).

        Each file is written under a temporary name and renamed, so that an interrupted
        save never leaves a truncated file under the real name.
        """
        if precision not in PRECISIONS:
            raise ValueError(f"precision must be one of {', '.join(map(repr, PRECISIONS))}, "
                             f"got {precision!r}")
        if isinstance(judged, str):
            raise TypeError("judged must be a collection of signal names, not a string")
        judged = set(judged)
        directory = Path(directory)
        directory.mkdir(parents=True, exist_ok=True)
        names, columns = self._columns()
        arrays = {_TIME_KEY: _byte_planes(columns[0], "<f8")}
        storage = {_TIME_KEY: "float64"}
        rounded = {n: b for n, b in self.rounded_signals.items() if n in names}
        for name, column in zip(names, columns[1:], strict=True):
            bits = _significant_bits(precision, name in judged)
            kind, array, bound = _encode(column, bits)
            arrays[name], storage[name] = array, kind
            if bound > rounded.get(name, 0.0):
                rounded[name] = bound
        _atomic_write(directory / SIGNALS_FILE, lambda fh: np.savez_compressed(fh, **arrays))
        stale_csv = directory / CSV_FILE
        if stale_csv.exists():  # an export of an earlier run would no longer match
            stale_csv.unlink()
        meta = {
            "format_version": _FORMAT_VERSION,
            "scenario": self.scenario,
            "step_s": self.step_s,
            "stop_time_s": self.stop_time_s,
            "wall_time_s": self.wall_time_s,
            "error": self.error,
            "interrupted": self.interrupted,
            "n_samples": len(columns[0]),
            "signals_encoding": _ENCODING,
            "signals_precision": precision,
            "signals": names,
            "signal_storage": storage,
            "rounded_signals": {n: rounded[n] for n in names if n in rounded},
            "fault_windows": [w.to_json() for w in self.fault_windows],
            "manoeuvre_windows": [w.to_json() for w in self.manoeuvre_windows],
        }
        text = json.dumps(meta, indent=2) + "\n"
        _atomic_write(directory / META_FILE, lambda fh: fh.write(text.encode("utf-8")))

    def export_csv(self, path: Path | str) -> Path:
        """Write the signals as CSV: header ``time,<instance.variable>,...``, one row per
        recorded point, ``nan`` / ``inf`` / ``-inf`` for non-finite values.

        Numbers carry the digits their stored precision has: exact signals the shortest
        decimal that reads back as the same float64 (up to 17 significant digits);
        signals in :attr:`rounded_signals` the shortest that reads back as the same
        float32 (up to 9) when rounded to float32, 5 significant digits when rounded to
        13 bits (parsed and rounded to 13 bits again, they give the stored value)."""
        path = Path(path)
        names, columns = self._columns()
        path.parent.mkdir(parents=True, exist_ok=True)
        texts = [_texts(columns[0], None)]
        texts += [_texts(c, self.rounded_signals.get(n))
                  for n, c in zip(names, columns[1:], strict=True)]

        def write(fh: Any) -> None:
            with open(fh.fileno(), "w", newline="", encoding="utf-8", closefd=False) as text:
                writer = csv.writer(text, lineterminator="\n")
                writer.writerow([_TIME_KEY, *names])
                writer.writerows(zip(*texts, strict=True))

        _atomic_write(path, write)
        return path

    @classmethod
    def load(cls, directory: Path | str) -> RunResult:
        """Read a run written by :meth:`save` (or a format-1 run with ``signals.csv``)."""
        directory = Path(directory)
        meta_path = directory / META_FILE
        if not meta_path.is_file():
            raise FileNotFoundError(f"{meta_path}: no such file (not a saved run directory?)")
        meta = json.loads(meta_path.read_text(encoding="utf-8"))
        version = int(meta.get("format_version", 1))
        if version > _FORMAT_VERSION:
            raise ValueError(f"{meta_path}: format_version {version} is newer than this "
                             f"harness reads ({_FORMAT_VERSION}); update gyrodiag")
        rounded: dict[str, float] = {}
        if meta.get("signals_dropped"):
            raise FileNotFoundError(f"{directory}: the signals of this run were not kept "
                                    f"({meta['signals_dropped']}); only {META_FILE} is "
                                    f"there")
        if version >= 2:
            encoding = meta.get("signals_encoding", _V2_ENCODING)
            names = list(meta.get("signals", []))
            if encoding == _ENCODING:
                storage = meta.get("signal_storage")
                if not isinstance(storage, dict):
                    raise ValueError(f"{meta_path}: no signal_storage table (format 3)")
                table = meta.get("rounded_signals", {})
                if not isinstance(table, dict):
                    raise ValueError(f"{meta_path}: rounded_signals must map signal names "
                                     f"to relative error bounds")
                rounded = {str(n): float(b) for n, b in table.items()}
            elif encoding == _V2_ENCODING:
                storage = dict.fromkeys([_TIME_KEY, *names], "float64")
            else:
                raise ValueError(f"{meta_path}: unknown signals_encoding {encoding!r} "
                                 f"(this version reads {_ENCODING!r} and {_V2_ENCODING!r})")
            time, signals = _load_npz(directory / SIGNALS_FILE, names, storage)
        else:
            time, signals = _load_csv(directory / CSV_FILE)
        return cls(
            scenario=str(meta["scenario"]),
            time=time,
            signals=signals,
            fault_windows=[FaultWindow.from_json(w) for w in meta.get("fault_windows", [])],
            manoeuvre_windows=[FaultWindow.from_json(w)
                               for w in meta.get("manoeuvre_windows", [])],
            step_s=float(meta.get("step_s", 0.0)),
            error=meta.get("error"),
            wall_time_s=float(meta.get("wall_time_s", 0.0)),
            stop_time_s=float(meta.get("stop_time_s", 0.0)),
            interrupted=bool(meta.get("interrupted", False)),
            rounded_signals={n: b for n, b in rounded.items() if n in signals},
        )


def drop_signals(directory: Path | str, reason: str) -> None:
    """Delete a saved run's ``signals.npz``, keeping its ``run.json`` with the reason.

    :meth:`RunResult.load` of the run then raises FileNotFoundError quoting ``reason``;
    ``export-csv`` of a folder passes over it.
    """
    directory = Path(directory)
    meta_path = directory / META_FILE
    meta = json.loads(meta_path.read_text(encoding="utf-8"))
    meta["signals_dropped"] = reason
    text = json.dumps(meta, indent=2) + "\n"
    _atomic_write(meta_path, lambda fh: fh.write(text.encode("utf-8")))
    (directory / SIGNALS_FILE).unlink(missing_ok=True)
    (directory / CSV_FILE).unlink(missing_ok=True)


def signals_dropped(directory: Path | str) -> str | None:
    """Why the run saved in ``directory`` has no signals (None: it has them)."""
    meta_path = Path(directory) / META_FILE
    try:
        reason = json.loads(meta_path.read_text(encoding="utf-8")).get("signals_dropped")
    except (OSError, ValueError):
        return None
    return str(reason) if reason else None


def _byte_planes(column: np.ndarray, dtype: str) -> np.ndarray:
    little = np.ascontiguousarray(column, dtype=dtype)
    return np.ascontiguousarray(little.view(np.uint8).reshape(-1, little.itemsize).T)


def _same_values(a: np.ndarray, b: np.ndarray) -> bool:
    # equal numbers, NaN where NaN, and the sign of zeros (NaN payloads do not count)
    return bool(np.array_equal(a, b, equal_nan=True)
                and np.array_equal(np.signbit(a), np.signbit(b)))


def _significant_bits(precision: str, judged: bool) -> int | None:
    """Significant bits to round a Real signal to (None: keep float64)."""
    if precision == "float64":
        return None
    if precision == "float32" or judged:
        return 24
    return CONTEXT_SIGNIFICANT_BITS


def _round_to_bits(column: np.ndarray, bits: int) -> np.ndarray:
    # round to nearest (ties away from zero) on the float64 bit pattern: clearing the low
    # 53 - bits significand bits after adding half of the last kept one; a carry into the
    # exponent is the right result, and finite values stay finite within float32's range
    drop = 53 - bits
    pattern = np.ascontiguousarray(column, dtype="<f8").view("<u8")
    finite = np.isfinite(column)
    rounded = pattern.copy()
    rounded[finite] = ((pattern[finite] + np.uint64(1 << (drop - 1))) >> np.uint64(drop)) \
        << np.uint64(drop)
    return rounded.view("<f8")


def _encode(column: np.ndarray, bits: int | None) -> tuple[str, np.ndarray, float]:
    """Storage kind, npz entry and relative error bound (0: exact) of a float64 column
    whose Real values may be rounded to ``bits`` significant bits (None: not at all)."""
    n = len(column)
    if n and _same_values(column, np.full(n, column[0])):
        return "constant", column[:1].copy(), 0.0
    if n and np.isfinite(column).all() and not np.signbit(column[column == 0]).any() \
            and np.array_equal(column, np.trunc(column)):
        lo, hi = column.min(), column.max()
        for kind in _INTEGER_TYPES:
            half = 2.0 ** (np.iinfo(kind).bits - 1)  # exact as a float, unlike iinfo.max
            if -half <= lo and hi < half:
                return kind, column.astype(kind), 0.0
    finite = np.abs(column[np.isfinite(column)])
    if finite.size and (finite.max() > _FLOAT32_MAX
                        or finite[finite > 0].min(initial=1.0) < _FLOAT32_TINY):
        return "float64", _byte_planes(column, "<f8"), 0.0
    as32 = column.astype("<f4")
    if _same_values(as32.astype(float), column):
        return "float32", _byte_planes(as32, "<f4"), 0.0
    if bits is None:
        return "float64", _byte_planes(column, "<f8"), 0.0
    if bits < 24:
        narrow = _round_to_bits(column, bits)
        if np.abs(narrow[np.isfinite(narrow)]).max(initial=0.0) > _FLOAT32_MAX:
            return _encode(column, 24)  # rounded up past float32's largest
        return "float32", _byte_planes(narrow.astype("<f4"), "<f4"), 2.0 ** -bits
    return "float32", _byte_planes(as32, "<f4"), FLOAT32_MAX_RELATIVE_ERROR


def _decode(entry: np.ndarray, kind: str, n_rows: int | None, path: Path,
            name: str) -> np.ndarray:
    def bad(expected: str) -> ValueError:
        return ValueError(f"{path}: entry {name!r} stored as {kind} should be {expected} "
                          f"(found dtype {entry.dtype}, shape {entry.shape})")

    if kind in ("float64", "float32"):
        width = 8 if kind == "float64" else 4
        if entry.dtype != np.uint8 or entry.ndim != 2 or entry.shape[0] != width:
            raise bad(f"uint8 byte planes of shape ({width}, N)")
        values = np.ascontiguousarray(entry.T).view(f"<f{width}").ravel()
        return values.astype(float)
    if kind in _INTEGER_TYPES:
        if entry.dtype != np.dtype(kind) or entry.ndim != 1:
            raise bad(f"a 1-d {kind} array")
        return entry.astype(float)
    if kind == "constant":
        if entry.dtype != np.float64 or entry.shape != (1,) or n_rows is None:
            raise bad("a float64 array of shape (1,)")
        return np.full(n_rows, entry[0])
    raise ValueError(f"{path}: signal {name!r} has an unknown storage {kind!r} (this "
                     f"version reads float64, float32, {', '.join(_INTEGER_TYPES)}, "
                     f"constant)")


def _file_mode() -> int:
    # what open() would give a new file: mkstemp makes it private (0600), which would
    # keep results from the colleagues who share the folder
    mask = os.umask(0)
    os.umask(mask)
    return 0o666 & ~mask


_FILE_MODE = _file_mode()


def _atomic_write(path: Path, write: Any) -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".part")
    try:
        os.fchmod(fd, _FILE_MODE)
        with os.fdopen(fd, "wb") as fh:
            write(fh)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _load_npz(path: Path, names: list[str], storage: dict[str, Any]
              ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file (not a saved run directory?)")
    try:
        data = np.load(path, allow_pickle=False)
    except (ValueError, OSError, EOFError, zipfile.BadZipFile) as exc:
        raise ValueError(f"{path}: unreadable signals file, not a numpy .npz archive "
                         f"({exc})") from None
    if not isinstance(data, np.lib.npyio.NpzFile):
        raise ValueError(f"{path}: unreadable signals file, a single array instead of a "
                         f"numpy .npz archive")
    try:
        with data:
            keys = list(data.files)
            if _TIME_KEY not in keys:
                raise ValueError(f"{path}: no 'time' array (not a signals file of a run?)")
            missing = [n for n in names if n not in keys]
            if missing:
                raise ValueError(f"{path}: signals listed in run.json are missing: "
                                 f"{', '.join(missing[:5])}")
            order = names or [k for k in keys if k != _TIME_KEY]
            unlisted = [n for n in [_TIME_KEY, *order] if n not in storage]
            if unlisted:
                raise ValueError(f"{path}: run.json does not say how these are stored: "
                                 f"{', '.join(unlisted[:5])}")
            time = _decode(data[_TIME_KEY], str(storage[_TIME_KEY]), None, path, _TIME_KEY)
            signals = {n: _decode(data[n], str(storage[n]), len(time), path, n)
                       for n in order}
    except (zipfile.BadZipFile, zlib.error, OSError, EOFError) as exc:
        raise ValueError(f"{path}: unreadable signals file ({exc})") from None
    for n, col in signals.items():
        if col.shape != time.shape:
            raise ValueError(f"{path}: signal {n!r} has shape {col.shape}, time has "
                             f"{time.shape}")
    return time, signals


def _load_csv(csv_path: Path) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    if not csv_path.is_file():
        raise FileNotFoundError(f"{csv_path}: no such file (not a saved run directory?)")
    with open(csv_path, newline="", encoding="utf-8") as fh:
        rows = list(csv.reader(fh))
    if not rows or not rows[0] or rows[0][0] != _TIME_KEY:
        raise ValueError(f"{csv_path}: first column must be 'time'")
    header = rows[0]
    body = rows[1:]
    for i, row in enumerate(body, start=2):
        if len(row) != len(header):
            raise ValueError(f"{csv_path}: line {i} has {len(row)} fields, header has "
                             f"{len(header)}")
    table = (np.array([[float(v) for v in row] for row in body], dtype=float)
             if body else np.zeros((0, len(header))))
    signals = {name: table[:, j + 1].copy() for j, name in enumerate(header[1:])}
    return table[:, 0].copy(), signals


def _texts(column: np.ndarray, bound: float | None) -> list[str]:
    # repr of a Python float / str of a numpy float32 is the shortest string that reads
    # back as the same float64 / float32; a p-bit number needs 1 + ceil(p log10 2)
    # significant digits to be told from its neighbours
    if bound is None:
        return [repr(v) for v in column.tolist()]
    bits = round(-math.log2(bound))
    if bits >= 24:
        return [str(v) for v in column.astype(np.float32)]
    digits = 1 + math.ceil(bits * math.log10(2.0))
    return [f"{v:.{digits}g}" for v in column.tolist()]


def _missing_signal_message(name: str, known: list[str]) -> str:
    close = difflib.get_close_matches(name, known, n=5, cutoff=0.5)
    if close:
        hint = "closest: " + ", ".join(close)
    elif len(known) <= 20:
        hint = "recorded: " + (", ".join(known) or "none")
    else:
        hint = f"{len(known)} signals recorded, e.g. " + ", ".join(known[:10])
    return f"signal {name!r} was not recorded; {hint}"
