"""Shared pytest fixtures: FMUs built once per session, FMU scenarios in fresh processes.

* ``fmu_dir`` (session): builds every available FMU with ``python build_fmu.py --out DIR``
  in a subprocess (docs/methods.md §6.4: never build and simulate in one process) unless all FMUs
  in DIR are newer than their sources; returns DIR.  DIR is ``build/fmus`` or
  ``$GYRODIAG_FMU_DIR``.  A file lock serialises concurrent pytest sessions.
* ``run_fmu_script`` (session): runs ``python SCRIPT FMU_DIR OUT.npz [ARGS]`` in a fresh
  process (docs/methods.md §6.11) and returns the arrays saved in OUT.npz.
* :class:`FmuSlave`: a thin fmpy ``FMU2Slave`` loop helper for those scripts
  (``sys.path.insert(0, tests_dir); from conftest import FmuSlave``).  It never unloads
  the shared library, because unloading and reloading a pythonfmu binary in one process
  has crashed before.
"""

from __future__ import annotations

import fcntl
import importlib.util
import os
import subprocess
import sys
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]

# pytester: the gyrodiag pytest plugin is tested by running pytest on scenario projects
pytest_plugins = ["pytester"]


def pytest_sessionstart(session: pytest.Session) -> None:
    """Byte-compile the project once per suite (the controller, before its workers
    start): the suite starts hundreds of Python processes (run processes, CLI commands,
    C hosts), and with PYTHONDONTWRITEBYTECODE set (as in some CI shells) each of them
    would compile every module it imports from source."""
    if hasattr(session.config, "workerinput"):
        return
    import compileall

    for folder in ("harness", "fmu_src", "models"):
        compileall.compile_dir(str(ROOT / folder), quiet=1, workers=1)


#: Modules that take longest (wall seconds on 2 cores, 2026-11-25): started first, so that
#: with xdist's per-module scheduling no long module is left to run alone at the end.
_LONG_MODULES = ("test_harness_results.py", "test_system_diagnosis.py",
                 "test_harness_cli.py", "test_seed_scenarios_hrg_aircraft.py",
                 "test_fmu_hosts.py", "test_seed_scenarios_dtg.py", "test_campaign.py")


#: Fixtures that build FMUs or run co-simulations: a test using one is in the slow tier.
_SLOW_FIXTURES = frozenset({"fmu_dir", "run_fmu_script", "gyrodiag_run",
                            "gyrodiag_fmu_dir", "pytester"})
#: Modules slow without those fixtures (library simulations of many seconds, subprocesses).
_SLOW_MODULES = frozenset(_LONG_MODULES) | {
    "test_benchmarks.py", "test_dtg_torquer_noise.py", "test_harness_interrupt.py",
    "test_harness_parallel.py", "test_campaign_hrg.py", "test_campaign_system.py",
    "test_campaign_sidebyside.py", "test_turbulence_manoeuvres.py",
    "test_isolation_closed_loop.py", "test_dtg_case_rate.py", "test_sample_alignment.py",
    "test_dtg_case_rate_reference.py", "test_distributions.py", "test_gain_table.py",
    "test_harness_reference.py", "test_harness_layout.py", "test_dtg_fast_path.py",
    "test_harness_report.py", "test_ecos_ssp.py", "test_fmu_container.py", "test_df_gust.py",
    "test_sequential_system_chain.py",
}
#: Single slow tests of otherwise fast modules (function names, parameters aside).
_SLOW_TESTS = frozenset({
    "test_no_covariance_windup_over_a_million_quiet_samples",
    "test_grey_predictors_equal_reference", "test_rls_family_equals_reference_on_dtg_data",
    "test_nan_sample_skipped_and_state_round_trip_exact",
    "test_update_floats_equals_update_through_calibration_faults_and_nan",
    "test_persistent_fault_keeps_the_alarm_and_an_intermittent_one_clears",
    "test_thresholds_invert_the_run_length",
    "test_a_bad_state_is_refused_and_leaves_the_channel_as_it_was",
    "test_sequential_rule_detects_a_two_sigma_bias_that_the_paper_rule_misses",
    "test_a_wrong_fixed_alignment_is_what_the_automatic_choice_avoids",
    "test_alignment_is_found_and_the_verdict_does_not_depend_on_it",
})


def pytest_collection_modifyitems(session: pytest.Session, config: pytest.Config,
                                  items: list[pytest.Item]) -> None:
    """Mark the slow tier; longest modules first (a stable sort keeps a module's order)."""
    for item in items:
        fixtures = set(getattr(item, "fixturenames", ()))
        if (fixtures & _SLOW_FIXTURES or item.path.name in _SLOW_MODULES
                or item.name.split("[")[0] in _SLOW_TESTS or item.path.suffix == ".toml"):
            item.add_marker(pytest.mark.slow)
    rank = {name: k for k, name in enumerate(_LONG_MODULES)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))


# ------------------------------------------------------------------ no silent skips
#: Skips that CI accepts (GYRODIAG_STRICT_SKIPS=1, set by .ci/run): a regular expression
#: of the skip reason -> why that skip is no defect on CI. Everything else fails the run.
ALLOWED_SKIPS: dict[str, str] = {
    r"Ecos cannot load: libtbb\.so\.12 missing": (
        "ecospy's binary links TBB, a system library pip cannot install; .ci/run installs "
        "Debian's libtbb12 where apt-get is available (tests/test_ecos_ssp.py)"),
}
_SKIPPED: list[tuple[str, str]] = []
_SKIP_PROBLEM: list[str] = []


def _skip_reason(report: pytest.TestReport) -> str:
    longrepr = report.longrepr
    if isinstance(longrepr, tuple) and len(longrepr) == 3:
        return str(longrepr[2])
    return str(longrepr)


def pytest_runtest_logreport(report: pytest.TestReport) -> None:
    # on the xdist controller too: every worker's reports pass through it
    if report.skipped and not hasattr(report, "wasxfail"):
        _SKIPPED.append((report.nodeid, _skip_reason(report)))


@pytest.hookimpl(tryfirst=True)
def pytest_sessionfinish(session: pytest.Session, exitstatus: int) -> None:
    if hasattr(session.config, "workerinput") or os.environ.get("GYRODIAG_STRICT_SKIPS") != "1":
        return
    import re

    bad = [(node, why) for node, why in _SKIPPED
           if not any(re.search(pattern, why) for pattern in ALLOWED_SKIPS)]
    if bad:
        _SKIP_PROBLEM[:] = [f"{node}: {why}" for node, why in bad]
        session.exitstatus = pytest.ExitCode.TESTS_FAILED


def pytest_terminal_summary(terminalreporter: Any, exitstatus: int, config: pytest.Config) -> None:
    if _SKIP_PROBLEM:
        terminalreporter.section("skips not on the allow-list (tests/conftest.py ALLOWED_SKIPS)",
                                 red=True)
        for line in _SKIP_PROBLEM:
            terminalreporter.line(line)


def load_builder() -> Any:
    """Import build_fmu.py as a module (registry and staleness helpers only)."""
    spec = importlib.util.spec_from_file_location("gd_build_fmu_for_tests", ROOT / "build_fmu.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="session")
def fmu_dir() -> Path:
    """Directory holding every available FMU, freshly built if any is stale."""
    out = Path(os.environ.get("GYRODIAG_FMU_DIR", ROOT / "build" / "fmus")).resolve()
    out.mkdir(parents=True, exist_ok=True)
    builder = load_builder()
    with open(out / ".build.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        stale = builder.stale_fmus(out)
        if stale:
            proc = subprocess.run(
                [sys.executable, str(ROOT / "build_fmu.py"), "--out", str(out)],
                cwd=ROOT, capture_output=True, text=True, timeout=1800,
            )
            if proc.returncode != 0:
                pytest.fail(f"build_fmu.py failed (stale: {stale}):\n{proc.stdout[-4000:]}\n"
                            f"{proc.stderr[-4000:]}")
    return out


@pytest.fixture(scope="session")
def run_fmu_script(fmu_dir: Path, tmp_path_factory: pytest.TempPathFactory):
    """Return ``run(script, *args) -> dict[str, ndarray]`` running SCRIPT in a new process."""

    def run(script: Path | str, *args: str) -> dict[str, np.ndarray]:
        out = tmp_path_factory.mktemp("fmu_run") / "result.npz"
        proc = subprocess.run(
            [sys.executable, str(script), str(fmu_dir), str(out), *args],
            cwd=ROOT, capture_output=True, text=True, timeout=1800,
        )
        if proc.returncode != 0:
            pytest.fail(f"{Path(script).name} failed (exit {proc.returncode}):\n"
                        f"{proc.stdout[-3000:]}\n{proc.stderr[-6000:]}")
        with np.load(out) as data:
            return {k: data[k] for k in data.files}

    return run


class FmuSlave:
    """One co-simulation instance of an FMU through fmpy, addressed by variable name.

    Parameters
    ----------
    fmu : path
        The .fmu file (extracted once per process and path).
    instance_name : str
        FMI instance name.
    parameters : dict
        Start values (parameters or inputs) set before initialisation.
    start_time : float
        Experiment start time (s).
    """

    _extracted: ClassVar[dict[str, str]] = {}

    def __init__(self, fmu: Path | str, instance_name: str = "instance",
                 parameters: dict[str, Any] | None = None, start_time: float = 0.0) -> None:
        from fmpy import extract, read_model_description
        from fmpy.fmi2 import FMU2Slave

        key = str(Path(fmu).resolve())
        if key not in self._extracted:
            self._extracted[key] = extract(key)
        unzipdir = self._extracted[key]
        self.md = read_model_description(unzipdir)
        self.vars = {v.name: v for v in self.md.modelVariables}
        self.fmu = FMU2Slave(guid=self.md.guid, unzipDirectory=unzipdir,
                             modelIdentifier=self.md.coSimulation.modelIdentifier,
                             instanceName=instance_name)
        self.fmu.instantiate(loggingOn=True)
        self.fmu.setupExperiment(startTime=start_time)
        for name, value in (parameters or {}).items():
            self.set(name, value)
        self.fmu.enterInitializationMode()
        self.fmu.exitInitializationMode()
        self.time = start_time

    def set(self, name: str, value: Any) -> None:
        v = self.vars[name]
        if v.type == "Real":
            self.fmu.setReal([v.valueReference], [float(value)])
        elif v.type in ("Integer", "Enumeration"):
            self.fmu.setInteger([v.valueReference], [int(value)])
        elif v.type == "Boolean":
            self.fmu.setBoolean([v.valueReference], [bool(value)])
        else:
            raise TypeError(f"unsupported type {v.type} of {name}")

    def get(self, name: str) -> Any:
        v = self.vars[name]
        if v.type == "Real":
            return self.fmu.getReal([v.valueReference])[0]
        if v.type in ("Integer", "Enumeration"):
            return self.fmu.getInteger([v.valueReference])[0]
        if v.type == "Boolean":
            return bool(self.fmu.getBoolean([v.valueReference])[0])
        raise TypeError(f"unsupported type {v.type} of {name}")

    def get_many(self, names: list[str]) -> list[float]:
        """Real values of several variables in one call."""
        return list(self.fmu.getReal([self.vars[n].valueReference for n in names]))

    def step(self, h: float) -> None:
        self.fmu.doStep(currentCommunicationPoint=self.time, communicationStepSize=h)
        self.time += h

    def close(self) -> None:
        """Terminate and free the instance, keeping the shared library loaded."""
        self.fmu.terminate()
        self.fmu.fmi2FreeInstance(self.fmu.component)


@pytest.fixture(scope="session")
def c_host(tmp_path_factory) -> Path:
    """tests/host/gd_fmi2_host.c, the C host of the host tests, compiled with warnings as
    errors."""
    import shutil

    import fmpy

    cc = shutil.which("cc") or shutil.which("gcc")
    assert cc, "a C compiler (cc) is needed, as for build_fmu.py's status shim"
    exe = tmp_path_factory.mktemp("host") / "gd_fmi2_host"
    headers = Path(fmpy.__file__).parent / "c-code"
    source = Path(__file__).resolve().parent / "host" / "gd_fmi2_host.c"
    proc = subprocess.run([cc, "-std=c11", "-O2", "-Wall", "-Wextra", "-Werror",
                           f"-I{headers}", "-o", str(exe), str(source), "-ldl"],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    return exe

