"""A session's run cache: each scenario runs once, whoever asks first, in any process.

Several pytest items and fixtures may want the run of one scenario, in one process or in
several (pytest-xdist workers).  :class:`RunCache` runs a scenario at most once per
results folder: under a file lock per scenario, the first asker runs it (in a worker
process of its own, :func:`gyrodiag_harness.cosim.batch.run_all`) and writes a marker with the
scenario's fingerprint; later askers, in this process or another, load the saved run.
A scenario edited since (other fingerprint) runs again.

The cache saves every signal bit-exactly (``precision="float64"``, whatever the
scenario's ``record.precision``): a test in another process that loads the run must see
the same values as the process that ran it.
"""

from __future__ import annotations

import fcntl
import hashlib
import json
import os
from dataclasses import dataclass, field
from pathlib import Path

from gyrodiag_harness.cosim.batch import run_all
from gyrodiag_harness.cosim.results import META_FILE, RunResult
from gyrodiag_harness.cosim.scenario import Scenario

__all__ = ["RunCache"]

_MARKER = ".gyrodiag-run.json"
_PRECISION = "float64"


def fingerprint(scenario: Scenario, fmu_dir: Path | None) -> str:
    """What decides a run's outcome: the validated scenario, its file, the FMU folder."""
    payload = json.dumps({"scenario": scenario.model_dump(mode="json", by_alias=True),
                          "path": str(scenario.path), "fmu_dir": str(fmu_dir),
                          "precision": _PRECISION},
                         sort_keys=True, default=str)
    return hashlib.sha256(payload.encode()).hexdigest()[:20]


@dataclass
class RunCache:
    """Runs of one session, saved in ``results`` (``results/<scenario name>/``).

    Parameters
    ----------
    results : Path
        The session's results folder (shared by every process of the session).
    fmu_dir : Path, optional
        Folder of the FMUs.
    """

    results: Path
    fmu_dir: Path | None = None
    _memory: dict[str, tuple[str, RunResult]] = field(default_factory=dict)

    def run(self, scenario: Scenario) -> RunResult:
        """The scenario's run: from memory, from the results folder, or run now.

        Raises
        ------
        ScenarioError, FileNotFoundError
            The scenario cannot run (a file, an FMU or a variable name is missing).
        """
        key = fingerprint(scenario, self.fmu_dir)
        cached = self._memory.get(scenario.name)
        if cached is not None and cached[0] == key:
            return cached[1]
        folder = self.results / scenario.name
        self.results.mkdir(parents=True, exist_ok=True)
        with open(self.results / f".{scenario.name}.lock", "w") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)   # another process may be running it now
            result = self._saved(folder, key)
            if result is None:
                (folder / _MARKER).unlink(missing_ok=True)
                (result,) = run_all([scenario], self.results, self.fmu_dir, progress=False,
                                    workers=1, precision=_PRECISION)
                self._mark(folder, key)
        self._memory[scenario.name] = (key, result)
        return result

    def run_many(self, scenarios: list[Scenario], workers: int | None = None
                 ) -> list[RunResult]:
        """The runs of several scenarios, in order; those nobody has run yet run in one
        batch, ``workers`` at a time (default: the CPUs); those another process is
        running now are waited for."""
        results: dict[str, RunResult] = {}
        todo: list[tuple[Scenario, str, object]] = []
        self.results.mkdir(parents=True, exist_ok=True)
        try:
            for s in scenarios:
                key = fingerprint(s, self.fmu_dir)
                cached = self._memory.get(s.name)
                if cached is not None and cached[0] == key:
                    results[s.name] = cached[1]
                    continue
                lock = open(self.results / f".{s.name}.lock", "w")
                try:
                    fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
                except BlockingIOError:  # another process runs it: wait for it below
                    lock.close()
                    continue
                saved = self._saved(self.results / s.name, key)
                if saved is not None:
                    lock.close()
                    self._memory[s.name] = (key, saved)
                    results[s.name] = saved
                    continue
                (self.results / s.name / _MARKER).unlink(missing_ok=True)
                todo.append((s, key, lock))
            if todo:
                runs = run_all([s for s, _, _ in todo], self.results, self.fmu_dir,
                               progress=False, workers=workers, precision=_PRECISION)
                for (s, key, _), result in zip(todo, runs, strict=True):
                    self._mark(self.results / s.name, key)
                    self._memory[s.name] = (key, result)
                    results[s.name] = result
        finally:
            for _, _, lock in todo:
                lock.close()  # type: ignore[attr-defined]
        return [results[s.name] if s.name in results else self.run(s) for s in scenarios]

    def _mark(self, folder: Path, key: str) -> None:
        tmp = folder / f"{_MARKER}.{os.getpid()}"
        tmp.write_text(json.dumps({"fingerprint": key}), encoding="utf-8")
        os.replace(tmp, folder / _MARKER)

    def _saved(self, folder: Path, key: str) -> RunResult | None:
        marker = folder / _MARKER
        if not (marker.is_file() and (folder / META_FILE).is_file()):
            return None
        if json.loads(marker.read_text(encoding="utf-8")).get("fingerprint") != key:
            return None
        return RunResult.load(folder)
