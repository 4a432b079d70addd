"""Recorded co-simulation runs: :class:`RunResult`, :class:`FaultWindow`, and their files.

A run directory holds two files:

* ``signals.csv`` — header ``time,<instance.variable>,...``; one row per recorded
  communication point, floats written with 17 significant digits (``repr`` round-trips
  exactly), ``nan`` / ``inf`` / ``-inf`` for non-finite values.
* ``run.json`` — everything else: scenario name, base step, planned duration, wall time,
  error text (``null`` when the run completed), fault windows (an open end is written as
  ``null`` because JSON has no infinity) and the signal names in column order.

Sample convention (contract): row ``k`` holds time ``t_k`` and the values read from every
FMU after the master stepped all FMUs to ``t_k``; row 0 is the state after initialisation.
"""

from __future__ import annotations

import csv
import difflib
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

SIGNALS_FILE = "signals.csv"
META_FILE = "run.json"
_FORMAT_VERSION = 1


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
    def save(self, directory: Path | str) -> None:
        """Write ``signals.csv`` and ``run.json`` into ``directory`` (created if needed)."""
        directory = Path(directory)
        directory.mkdir(parents=True, exist_ok=True)
        names = list(self.signals)
        columns = [np.asarray(self.time, dtype=float)]
        columns += [np.asarray(self.signals[n], dtype=float) for n in names]
        n_rows = len(columns[0])
        for name, col in zip(names, columns[1:], strict=True):
            if col.shape != (n_rows,):
                raise ValueError(f"signal {name!r} has shape {col.shape}, time has ({n_rows},)")
        with open(directory / SIGNALS_FILE, "w", newline="", encoding="utf-8") as fh:
            writer = csv.writer(fh, lineterminator="\n")
            writer.writerow(["time", *names])
            if n_rows:
                table = np.column_stack(columns)
                writer.writerows([[_fmt(v) for v in row] for row in table.tolist()])
        meta = {
            "format_version": _FORMAT_VERSION,
            "scenario": self.scenario,
            "step_s": self.step_s,
            "stop_time_s": self.stop_time_s,
            "wall_time_s": self.wall_time_s,
            "error": self.error,
            "n_samples": n_rows,
            "signals": names,
            "fault_windows": [w.to_json() for w in self.fault_windows],
            "manoeuvre_windows": [w.to_json() for w in self.manoeuvre_windows],
        }
        (directory / META_FILE).write_text(json.dumps(meta, indent=2) + "\n", encoding="utf-8")

    @classmethod
    def load(cls, directory: Path | str) -> RunResult:
        """Read a run written by :meth:`save`."""
        directory = Path(directory)
        meta_path, csv_path = directory / META_FILE, directory / SIGNALS_FILE
        for path in (meta_path, csv_path):
            if not path.is_file():
                raise FileNotFoundError(f"{path}: no such file (not a saved run directory?)")
        meta = json.loads(meta_path.read_text(encoding="utf-8"))
        with open(csv_path, newline="", encoding="utf-8") as fh:
            rows = list(csv.reader(fh))
        if not rows or not rows[0] or rows[0][0] != "time":
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
        return cls(
            scenario=str(meta["scenario"]),
            time=table[:, 0].copy(),
            signals=signals,
            fault_windows=[FaultWindow.from_json(w) for w in meta.get("fault_windows", [])],
            manoeuvre_windows=[FaultWindow.from_json(w)
                               for w in meta.get("manoeuvre_windows", [])],
            step_s=float(meta.get("step_s", 0.0)),
            error=meta.get("error"),
            wall_time_s=float(meta.get("wall_time_s", 0.0)),
            stop_time_s=float(meta.get("stop_time_s", 0.0)),
        )


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
