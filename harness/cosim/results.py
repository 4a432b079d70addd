"""Recorded co-simulation runs: :class:`RunResult`, :class:`FaultWindow`, and their files.

A run directory holds two files:

* ``signals.npz`` — a numpy compressed archive, one entry per column (``time`` first,
  then one per signal named ``instance.variable``).  Each column is float64, stored as
  its 8 byte planes (a ``uint8`` array of shape (8, N): byte 0 of every sample, then
  byte 1, ...) before deflate: the sign, exponent and leading mantissa bytes of a
  signal change slowly and compress well once they are not interleaved with the noisy
  low bytes (16.3 MB instead of 19.8 MB of plain float64 columns for the main job's
  runs; the same numbers as text took 72 MB).  Lossless: every bit of every sample,
  NaN and infinities included.  Read it with :meth:`RunResult.load`, or with numpy
  alone: ``np.load(f)[name].T.copy().view("<f8").ravel()``; ``python -m harness
  export-csv`` writes ``signals.csv`` (:meth:`RunResult.export_csv`).
* ``run.json`` — everything else: scenario name, base step, planned duration, wall time,
  error text (``null`` when the run completed), whether a stop request interrupted it,
  fault windows (an open end is written as ``null`` because JSON has no infinity) and
  the signal names in column order.

Runs saved by earlier versions (``signals.csv``, format 1) still load.

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
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

SIGNALS_FILE = "signals.npz"
CSV_FILE = "signals.csv"
META_FILE = "run.json"
_FORMAT_VERSION = 2
_TIME_KEY = "time"
_ENCODING = "float64-byte-planes"


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

    def save(self, directory: Path | str) -> None:
        """Write ``signals.npz`` and ``run.json`` into ``directory`` (created if needed).

        Each file is written under a temporary name and renamed, so that an interrupted
        save never leaves a truncated file under the real name.
        """
        directory = Path(directory)
        directory.mkdir(parents=True, exist_ok=True)
        names, columns = self._columns()
        arrays = {_TIME_KEY: _byte_planes(columns[0])}
        arrays.update({n: _byte_planes(c) for n, c in zip(names, columns[1:], strict=True)})
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
            "signals": names,
            "fault_windows": [w.to_json() for w in self.fault_windows],
            "manoeuvre_windows": [w.to_json() for w in self.manoeuvre_windows],
        }
        text = json.dumps(meta, indent=2) + "\n"
        _atomic_write(directory / META_FILE, lambda fh: fh.write(text.encode("utf-8")))

    def export_csv(self, path: Path | str) -> Path:
        """Write the signals as CSV: header ``time,<instance.variable>,...``, one row per
        recorded point, floats with 17 significant digits (``repr`` round-trips
        exactly), ``nan`` / ``inf`` / ``-inf`` for non-finite values."""
        path = Path(path)
        names, columns = self._columns()
        path.parent.mkdir(parents=True, exist_ok=True)

        def write(fh: Any) -> None:
            with open(fh.fileno(), "w", newline="", encoding="utf-8", closefd=False) as text:
                writer = csv.writer(text, lineterminator="\n")
                writer.writerow([_TIME_KEY, *names])
                if len(columns[0]):
                    table = np.column_stack(columns)
                    writer.writerows([[_fmt(v) for v in row] for row in table.tolist()])

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
        if int(meta.get("format_version", 1)) >= 2:
            encoding = meta.get("signals_encoding", _ENCODING)
            if encoding != _ENCODING:
                raise ValueError(f"{meta_path}: unknown signals_encoding {encoding!r} "
                                 f"(this version reads {_ENCODING!r})")
            time, signals = _load_npz(directory / SIGNALS_FILE, list(meta.get("signals", [])))
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
        )


def _byte_planes(column: np.ndarray) -> np.ndarray:
    little = np.ascontiguousarray(column, dtype="<f8")
    return np.ascontiguousarray(little.view(np.uint8).reshape(-1, 8).T)


def _from_byte_planes(planes: np.ndarray, path: Path, name: str) -> np.ndarray:
    if planes.dtype != np.uint8 or planes.ndim != 2 or planes.shape[0] != 8:
        raise ValueError(f"{path}: entry {name!r} is not a column of 8 byte planes "
                         f"(dtype {planes.dtype}, shape {planes.shape})")
    return np.ascontiguousarray(planes.T).view("<f8").ravel().astype(float, copy=False)


def _atomic_write(path: Path, write: Any) -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".part")
    try:
        with os.fdopen(fd, "wb") as fh:
            write(fh)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _load_npz(path: Path, names: list[str]) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file (not a saved run directory?)")
    try:
        with np.load(path, allow_pickle=False) as data:
            keys = list(data.files)
            if _TIME_KEY not in keys:
                raise ValueError(f"{path}: no 'time' array (not a signals file of a run?)")
            missing = [n for n in names if n not in keys]
            if missing:
                raise ValueError(f"{path}: signals listed in run.json are missing: "
                                 f"{', '.join(missing[:5])}")
            order = names or [k for k in keys if k != _TIME_KEY]
            time = _from_byte_planes(data[_TIME_KEY], path, _TIME_KEY)
            signals = {n: _from_byte_planes(data[n], path, n) for n in order}
    except (zipfile.BadZipFile, OSError, EOFError) as exc:
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


def _fmt(value: float) -> str:
    # repr of a Python float is the shortest string that round-trips exactly
    return repr(float(value))


def _missing_signal_message(name: str, known: list[str]) -> str:
    close = difflib.get_close_matches(name, known, n=5, cutoff=0.5)
    if close:
        hint = "closest: " + ", ".join(close)
    elif len(known) <= 20:
        hint = "recorded: " + (", ".join(known) or "none")
    else:
        hint = f"{len(known)} signals recorded, e.g. " + ", ".join(known[:10])
    return f"signal {name!r} was not recorded; {hint}"
