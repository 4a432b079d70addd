"""pytest plugin: scenario files as pytest tests (entry point ``pytest11``: ``gyrodiag``).

Off unless asked: ``pytest --gyrodiag [PATHS]``, or ``gyrodiag = true`` in the ini
file (``[tool.pytest.ini_options]`` of pyproject.toml).  Then every ``.toml`` file with an
``[fmus]`` table under the paths pytest collects is a scenario, and

* **one item per scenario** (not per expectation): a scenario is one run, and its
  ``[[expect]]`` tables are one verdict about it.  The item fails when any expectation
  fails, with one line per failing expectation, the sentence the report gives
  (expected, measured, where); a scenario that cannot run (a missing FMU or file, a
  variable the FMU does not have, an FMU error during the run) is an **error**, said
  once.  An invalid file is a collection error naming the file and the key.
* the item's doc is the scenario's ``description`` (``pytest --collect-only -v``, and a
  ``description`` property in ``--junitxml``);
* markers: ``gyrodiag`` on every scenario; by channel ``aircraft``, ``dtg``, ``hrg``
  (which plant FMUs it runs: Aircraft, DTG, HRG) or ``system`` (more than one of them);
  by kind ``fault`` (it schedules faults) or ``nominal``.  ``-m "dtg and fault"``,
  ``-k aircraft_q`` select as usual.
* scenarios with a ``[training]`` table are not items: they are the inputs of the DTG
  libraries, learned once per session when a scenario reads them: the signature library
  ``${out}/dtg_signatures.json`` from the ``training/`` folder beside the scenarios (or
  ``--gyrodiag-training``), the pattern library ``${out}/dtg_patterns.json`` from its
  ``patterns/`` subfolder.

Options (``pytest --help``, group "gyrodiag"): ``--gyrodiag``, ``--gyrodiag-fmu-dir DIR``
(default: ``$GYRODIAG_FMU_DIR``, else ``build/fmus`` of the source checkout, built once
per session when stale), ``--gyrodiag-results DIR`` (signals of every run, and at the
end ``report.html`` and the harness's ``junit.xml``; without it the runs go to a folder
in pytest's temporary directory and no report is written), ``--gyrodiag-training DIR``.

Fixtures for users' own tests (available whenever the package is installed):
``gyrodiag_fmu_dir``, ``gyrodiag_results``, ``gyrodiag_scenario`` (load a scenario file),
``gyrodiag_run`` (the run of a scenario, run once per session whoever asks first, also
across pytest-xdist workers).

Runs happen in worker processes (:func:`gyrodiag_harness.cosim.batch.run_all`), never in the
pytest process; with ``pytest -n auto`` (pytest-xdist) scenarios run in parallel.
"""

from __future__ import annotations

import fcntl
import importlib.util
import json
import os
import subprocess
import sys
import tomllib
import types
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from gyrodiag_harness.campaigns.signatures import (
    check_training_scenarios,
    learn_pattern_library,
    learn_signatures,
)
from gyrodiag_harness.cosim.batch import load_all
from gyrodiag_harness.cosim.results import RunResult
from gyrodiag_harness.cosim.scenario import FMU_DIR_ENV, Scenario, ScenarioError, load_scenario
from gyrodiag_harness.testing.runs import RunCache

__all__ = ["ScenarioFile", "ScenarioItem", "ScenarioRuns"]

SIGNATURES = "dtg_signatures.json"
PATTERNS = "dtg_patterns.json"
#: Plant FMUs that name a channel marker.
CHANNEL_OF_FMU = {"Aircraft": "aircraft", "DTG": "dtg", "HRG": "hrg"}
MARKERS = {
    "gyrodiag": "a gyrodiag scenario file run as a test",
    "aircraft": "gyrodiag scenario with the Aircraft plant FMU",
    "dtg": "gyrodiag scenario with the DTG plant FMU",
    "hrg": "gyrodiag scenario with the HRG plant FMU",
    "system": "gyrodiag scenario with more than one plant FMU",
    "fault": "gyrodiag scenario that schedules faults",
    "nominal": "gyrodiag scenario without faults",
}
_REPO_ROOT = Path(__file__).resolve().parents[2]
_STATE = pytest.StashKey["_Session"]()


# --------------------------------------------------------------------------- options
def pytest_addoption(parser: pytest.Parser) -> None:
    group = parser.getgroup("gyrodiag", "gyrodiag scenario files as tests")
    group.addoption("--gyrodiag", action="store_true", default=None,
                    help="collect gyrodiag scenario .toml files as tests (or ini "
                         "gyrodiag = true)")
    group.addoption("--gyrodiag-fmu-dir", default=None, metavar="DIR",
                    help="folder of the built FMUs (default: $GYRODIAG_FMU_DIR, else "
                         "build/fmus of the source checkout, built when stale)")
    group.addoption("--gyrodiag-results", default=None, metavar="DIR",
                    help="where runs and the report go (default: in pytest's temporary "
                         "folder)")
    group.addoption("--gyrodiag-training", default=None, metavar="DIR",
                    help="DTG training scenarios for the signature library (default: "
                         "training/ beside the scenarios)")
    parser.addini("gyrodiag", type="bool", default=False,
                  help="collect gyrodiag scenario .toml files as tests")
    parser.addini("gyrodiag_fmu_dir", default="", help="folder of the built FMUs")
    parser.addini("gyrodiag_results", default="", help="where runs and the report go")


def _enabled(config: pytest.Config) -> bool:
    flag = config.getoption("gyrodiag")
    return bool(flag) if flag is not None else bool(config.getini("gyrodiag"))


def pytest_configure(config: pytest.Config) -> None:
    for name, text in MARKERS.items():
        config.addinivalue_line("markers", f"{name}: {text}")
    config.stash[_STATE] = _Session(config)


@pytest.hookimpl(optionalhook=True)
def pytest_configure_node(node: Any) -> None:
    # pytest-xdist controller: every worker writes into the controller's results folder
    node.workerinput["gyrodiag_results"] = str(node.config.stash[_STATE].results)


# --------------------------------------------------------------------------- session
class _Session:
    """Folders, FMUs and runs of one pytest session (one per process)."""

    def __init__(self, config: pytest.Config) -> None:
        self.config = config
        #: the results folder was asked for: the report is written there at the end
        self.report = bool(config.getoption("gyrodiag_results")
                           or config.getini("gyrodiag_results"))
        self._results: Path | None = None
        self._fmu_dir: Path | None = None
        self._runs: RunCache | None = None

    @property
    def is_worker(self) -> bool:
        return hasattr(self.config, "workerinput")

    @property
    def results(self) -> Path:
        if self._results is None:
            given = (self.config.getoption("gyrodiag_results")
                     or self.config.getini("gyrodiag_results"))
            if self.is_worker:
                given = self.config.workerinput["gyrodiag_results"]
            if given:
                path = Path(given)
                if not path.is_absolute():
                    path = self.config.rootpath / path
            else:
                path = self.config._tmp_path_factory.getbasetemp() / "gyrodiag-results"
            path.mkdir(parents=True, exist_ok=True)
            self._results = path
        return self._results

    @property
    def fmu_dir(self) -> Path:
        if self._fmu_dir is None:
            given = (self.config.getoption("gyrodiag_fmu_dir")
                     or self.config.getini("gyrodiag_fmu_dir") or os.environ.get(FMU_DIR_ENV))
            if given:
                path = Path(given)
                if not path.is_absolute():
                    path = self.config.rootpath / path
                if not path.is_dir():
                    raise FileNotFoundError(f"--gyrodiag-fmu-dir {path}: not a folder")
            else:
                path = _build_fmus(_REPO_ROOT / "build" / "fmus")
            self._fmu_dir = path.resolve()
        return self._fmu_dir

    @property
    def runs(self) -> RunCache:
        if self._runs is None:
            self._runs = RunCache(self.results, self.fmu_dir)
        return self._runs

    def run(self, scenario: Scenario) -> RunResult:
        self.ensure_files(scenario)
        return self.runs.run(scenario)

    def run_many(self, scenarios: list[Scenario]) -> list[RunResult]:
        for s in scenarios:
            self.ensure_files(s)
        return self.runs.run_many(scenarios)

    def ensure_files(self, scenario: Scenario) -> None:
        """Learn the DTG libraries once per session if the scenario reads them: the
        signature library (``training/``) and the pattern library (``training/patterns``)."""
        specs = [s for inst in scenario.fmus.values() for s in inst.files.values()]
        for name, sub in ((SIGNATURES, ""), (PATTERNS, "patterns")):
            if f"${{out}}/{name}" in specs and not (self.results / name).is_file():
                self._learn(scenario, name, sub)

    def _learn(self, scenario: Scenario, name: str, sub: str) -> None:
        training = self.config.getoption("gyrodiag_training")
        folder = Path(training) if training else (
            scenario.path.parent / "training" if scenario.path is not None else None)
        if folder is not None and sub:
            folder = folder / sub
        if folder is None or not folder.is_dir():
            return  # the run's own check names the missing file
        with open(self.results / f".{name}.lock", "w") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)   # one process learns, the others wait
            if (self.results / name).is_file():
                return
            scenarios = load_all([folder])
            check_training_scenarios(scenarios)
            runs = RunCache(self.results / "training", self.fmu_dir).run_many(scenarios)
            failed = [r.scenario for r in runs if r.error is not None]
            if failed:
                raise ScenarioError(str(folder), [("", f"training runs failed: {failed}")])
            tmp = self.results / f".{name}.{os.getpid()}"
            if name == PATTERNS:
                _, content = learn_pattern_library(scenarios, runs)
                tmp.write_text(json.dumps(content, indent=1) + "\n", encoding="utf-8")
            else:
                learn_signatures(scenarios, runs).write(tmp)
            os.replace(tmp, self.results / name)


def _build_fmus(out: Path) -> Path:
    builder_path = _REPO_ROOT / "build_fmu.py"
    if not builder_path.is_file():
        raise FileNotFoundError("no FMU folder: pass --gyrodiag-fmu-dir (or set "
                                f"${FMU_DIR_ENV}); build_fmu.py is not beside this package")
    spec = importlib.util.spec_from_file_location("gd_build_fmu_plugin", builder_path)
    builder = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(builder)
    out.mkdir(parents=True, exist_ok=True)
    with open(out / ".build.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)   # one session builds, concurrent ones wait
        stale = builder.stale_fmus(out)
        if stale:
            # a fresh process: the builder imports the model scripts (docs/methods.md §6.4)
            proc = subprocess.run([sys.executable, str(builder_path), "--out", str(out)],
                                  cwd=_REPO_ROOT, capture_output=True, text=True, timeout=1800)
            if proc.returncode != 0:
                raise RuntimeError(f"build_fmu.py failed (stale: {stale}):\n"
                                   f"{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}")
    return out


# ------------------------------------------------------------------------- collection
def _is_scenario(path: Path) -> bool:
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError, OSError):
        return path.suffix == ".toml" and "[fmus" in path.read_text(errors="replace")
    return isinstance(data.get("fmus"), dict) and "training" not in data


def pytest_collect_file(file_path: Path, parent: pytest.Collector) -> pytest.Collector | None:
    if file_path.suffix != ".toml" or not _enabled(parent.config):
        return None
    if not _is_scenario(file_path):
        return None
    return ScenarioFile.from_parent(parent, path=file_path)


class ScenarioFile(pytest.File):
    """A scenario ``.toml`` file: one :class:`ScenarioItem`."""

    def collect(self) -> Iterator[ScenarioItem]:
        try:
            scenario = load_scenario(self.path)
        except ScenarioError as exc:
            raise self.CollectError(str(exc)) from None
        if not scenario.expect:  # a test that checks nothing passes whatever the product does
            raise self.CollectError(f"{self.path}: the scenario has no [[expect]] table; a "
                                    "scenario collected as a test must state what it checks")
        yield ScenarioItem.from_parent(self, name=scenario.name, scenario=scenario)


class ScenarioItem(pytest.Item):
    """One scenario: its run (setup; cannot run → error) and its verdict (call)."""

    def __init__(self, *, scenario: Scenario, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.scenario = scenario
        # --collect-only -v prints obj's doc: the scenario's description
        self.obj = types.SimpleNamespace(__doc__=scenario.description or None)
        self.user_properties.append(("description", scenario.description))
        for marker in markers_of(scenario):
            self.add_marker(marker)
        self.result: RunResult | None = None

    def setup(self) -> None:
        state = self.config.stash[_STATE]
        problem = None
        try:
            self.result = state.run(self.scenario)
        except (ScenarioError, FileNotFoundError) as exc:
            problem = str(exc)
        if problem is not None:  # outside the handler: the reason once, not chained
            pytest.fail(f"cannot run: {problem}", pytrace=False)
        assert self.result is not None
        self.user_properties.append(("results", str(state.results / self.scenario.name)))
        self.user_properties.append(("scenario_file", str(self.path)))
        if self.result.error is not None:
            pytest.fail(f"the run did not complete: {self.result.error}", pytrace=False)

    def runtest(self) -> None:
        from gyrodiag_harness.verification.expectations import verify_results

        assert self.result is not None
        (verdict,) = verify_results([self.result], [self.scenario])
        failed = [e for e in verdict.expectations if not e.passed]
        if failed:
            lines = [f"{e.name}: {e.message}" for e in failed]
            pytest.fail(f"{len(failed)} of {len(verdict.expectations)} expectations of "
                        f"{self.scenario.name} failed:\n" + "\n".join(lines), pytrace=False)
        known = [e for e in verdict.expectations if e.is_known_limitation]
        if known:  # every plain expectation passed; the known limitations still hold
            pytest.xfail("; ".join(f"{e.name}: {e.known_limitation}" for e in known))

    def reportinfo(self) -> tuple[Path, int | None, str]:
        return self.path, None, f"scenario {self.scenario.name}"


def markers_of(scenario: Scenario) -> list[pytest.MarkDecorator]:
    """``gyrodiag``, the channel (aircraft, dtg, hrg or system) and the kind (fault or
    nominal) of a scenario."""
    plants = sorted({CHANNEL_OF_FMU[Path(i.fmu).stem] for i in scenario.fmus.values()
                     if Path(i.fmu).stem in CHANNEL_OF_FMU})
    marks = [pytest.mark.gyrodiag]
    if len(plants) > 1:
        marks.append(pytest.mark.system)
    elif plants:
        marks.append(getattr(pytest.mark, plants[0]))
    marks.append(pytest.mark.fault if scenario.faults else pytest.mark.nominal)
    return marks


# ----------------------------------------------------------------------------- report
@pytest.hookimpl(tryfirst=True)
def pytest_runtest_logreport(report: pytest.TestReport) -> None:
    # on the xdist controller too: which scenarios ran, for the report at the end
    props = dict(report.user_properties)
    if "results" in props and "scenario_file" in props and report.when == "call":
        _REPORTS.setdefault(report.nodeid, (props["results"], props["scenario_file"]))


# filled by the hook above (which has no config); emptied by the session that reads it
_REPORTS: dict[str, tuple[str, str]] = {}


def pytest_sessionstart(session: pytest.Session) -> None:
    _REPORTS.clear()


def pytest_sessionfinish(session: pytest.Session) -> None:
    config = session.config
    state = config.stash.get(_STATE, None)
    reported = dict(_REPORTS)
    _REPORTS.clear()
    if state is None or state.is_worker or not state.report or not reported:
        return
    from gyrodiag_harness.reporting.report import write_report
    from gyrodiag_harness.verification.expectations import verify_results

    scenarios, results = [], []
    for folder, source in sorted(set(reported.values())):
        try:
            run, scenario = RunResult.load(folder), load_scenario(source)
        except (FileNotFoundError, ScenarioError, ValueError):
            continue
        results.append(run)
        scenarios.append(scenario)
    if not scenarios:
        return
    paths = write_report(verify_results(results, scenarios), results, state.results,
                         scenarios=scenarios)
    config._gyrodiag_report = paths.html  # type: ignore[attr-defined]


def pytest_terminal_summary(terminalreporter: Any, exitstatus: int,
                            config: pytest.Config) -> None:
    html = getattr(config, "_gyrodiag_report", None)
    if html is not None:
        terminalreporter.write_line(f"gyrodiag report: {html}")


# ---------------------------------------------------------------------------- fixtures
@pytest.fixture(scope="session")
def gyrodiag_fmu_dir(pytestconfig: pytest.Config) -> Path:
    """The folder of the built FMUs (``--gyrodiag-fmu-dir``, or built once)."""
    return pytestconfig.stash[_STATE].fmu_dir


@pytest.fixture(scope="session")
def gyrodiag_results(pytestconfig: pytest.Config) -> Path:
    """The session's results folder (``--gyrodiag-results``): ``<name>/`` per run."""
    return pytestconfig.stash[_STATE].results


@pytest.fixture(scope="session")
def gyrodiag_scenario(pytestconfig: pytest.Config) -> Callable[[str | Path], Scenario]:
    """``load(path)``: a validated scenario (a relative path is from the rootdir)."""

    def load(path: str | Path) -> Scenario:
        p = Path(path)
        return load_scenario(p if p.is_absolute() else pytestconfig.rootpath / p)

    return load


class ScenarioRuns:
    """``run(scenario or path)``: the scenario's :class:`~harness.RunResult`;
    ``run.many([...])``: several, those not run yet in parallel worker processes."""

    def __init__(self, state: _Session, load: Callable[[str | Path], Scenario]) -> None:
        self._state = state
        self._load = load

    def _scenario(self, scenario: Scenario | str | Path) -> Scenario:
        return scenario if isinstance(scenario, Scenario) else self._load(scenario)

    def __call__(self, scenario: Scenario | str | Path) -> RunResult:
        return self._state.run(self._scenario(scenario))

    def many(self, scenarios: list[Scenario | str | Path]) -> list[RunResult]:
        return self._state.run_many([self._scenario(s) for s in scenarios])


@pytest.fixture(scope="session")
def gyrodiag_run(pytestconfig: pytest.Config,
                 gyrodiag_scenario: Callable[[str | Path], Scenario]) -> ScenarioRuns:
    """``gyrodiag_run(scenario or path)``: the scenario's :class:`~harness.RunResult`,
    run once per session whoever asks first (scenario items and other tests, in any
    xdist worker); ``gyrodiag_run.many([...])`` runs those not run yet in parallel."""
    return ScenarioRuns(pytestconfig.stash[_STATE], gyrodiag_scenario)
