"""A second master: run a scenario, or an SSP file, with libcosim (libcosimpy).

libcosim (the Open Simulation Platform's co-simulation library) is a C++ master: it loads
each FMU's binary itself, sets start values, propagates the connections through a few
iterations in initialisation mode, then steps every FMU with a fixed step and transfers
the outputs to the inputs after each step, i.e. Jacobi coupling. It checks that the
project's FMUs work in a master other than fmpy, and that the Diagnoser gives the same
verdicts there (issue 13; the harness's own ``coupling = "jacobi"`` runs the same
coupling).

:func:`run_scenario_libcosim` runs a :class:`~gyrodiag_harness.cosim.scenario.Scenario` (its
connections, parameters, injector faults as FaultInjector parameters, physical faults as
overrides of the tunable parameter at their start and end, the recorded signals) and
returns a :class:`~gyrodiag_harness.cosim.results.RunResult` like the harness's master, so that
metrics and expectations apply unchanged. :func:`run_ssp_libcosim` runs an SSP package
(e.g. from :mod:`gyrodiag_harness.cosim.ssp`) and records outputs by name.

Limits: libcosim couples by Jacobi whatever the scenario's ``coupling`` says; every FMU
steps at the base step (``step_ratio`` 1: libcosimpy exposes no decimation factor).
libcosimpy is an optional dependency (``pip install -e ".[ssp]"``).
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from gyrodiag_harness.cosim.plan import fault_windows, model_info, recorded_signals
from gyrodiag_harness.cosim.results import RunResult
from gyrodiag_harness.cosim.scenario import (
    ModelInfo,
    PhysicalFault,
    Scenario,
    ScenarioError,
    VariableInfo,
    check_against_models,
    load_scenario,
    resolve_file_parameters,
    resolve_fmu_dir,
    resolve_fmu_file,
    split_name,
)
from gyrodiag_harness.cosim.timing import fill_timing_parameters

#: libcosim counts time in nanoseconds.
NS = 1_000_000_000


def _libcosim() -> Any:
    try:
        from libcosimpy import (
            CosimEnums,
            CosimExecution,
            CosimManipulator,
            CosimObserver,
            CosimSlave,
        )
    except ImportError as exc:  # an optional dependency
        raise ImportError(
            "libcosimpy is not installed: pip install -e \".[ssp]\" (or pip install "
            f"libcosimpy) to run scenarios with libcosim ({exc})") from None
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level

    log_output_level(CosimLogLevel.WARNING)  # its debug log costs more than the FMUs
    return CosimEnums, CosimExecution, CosimManipulator, CosimObserver, CosimSlave


def _model_info(fmu: Path) -> ModelInfo:
    """The model of an FMU file (read from the archive, not extracted)."""
    from fmpy import read_model_description

    return model_info(read_model_description(str(fmu)))


def to_ns(seconds: float) -> int:
    """Seconds → libcosim's integer nanoseconds (rounded)."""
    return round(seconds * NS)


@dataclass
class _Slaves:
    """libcosim slave indices and model descriptions by instance name."""

    index: dict[str, int]
    info: dict[str, ModelInfo]

    def var(self, qualified: str) -> tuple[int, VariableInfo]:
        inst, name = split_name(qualified)
        return self.index[inst], self.info[inst].variables[name]


class _Values:
    """Typed set/get of slave variables through a libcosim override manipulator and a
    last-value observer."""

    def __init__(self, execution: Any) -> None:
        enums, _, manipulator_cls, observer_cls, _ = _libcosim()
        self.types = enums.CosimVariableType
        self.observer = observer_cls.CosimObserver.create_last_value()
        execution.add_observer(self.observer)
        self.manipulator = manipulator_cls.CosimManipulator.create_override()
        execution.add_manipulator(self.manipulator)

    def read(self, index: int, variables: Sequence[VariableInfo]) -> list[float]:
        """Last values of ``variables`` of one slave, as floats, one call per type."""
        out = [math.nan] * len(variables)
        readers = {"Real": self.observer.last_real_values,
                   "Integer": self.observer.last_integer_values,
                   "Enumeration": self.observer.last_integer_values,
                   "Boolean": self.observer.last_boolean_values}
        for kind, reader in readers.items():
            pos = [j for j, v in enumerate(variables) if v.type == kind]
            if pos:
                got = reader(index, [variables[j].value_reference for j in pos])
                for j, x in zip(pos, got, strict=True):
                    out[j] = float(x)
        strings = [v.name for v in variables if v.type not in readers]
        if strings:
            raise ScenarioError("record", [("", f"cannot record String variables {strings}")])
        return out

    def override(self, index: int, v: VariableInfo, value: Any) -> None:
        vr = [v.value_reference]
        if v.type == "Real":
            ok = self.manipulator.slave_real_values(index, vr, [float(value)])
        elif v.type in ("Integer", "Enumeration"):
            ok = self.manipulator.slave_integer_values(index, vr, [round(value)])
        elif v.type == "Boolean":
            ok = self.manipulator.slave_boolean_values(index, vr, [bool(value)])
        else:
            ok = self.manipulator.slave_string_values(index, vr, [str(value)])
        if ok is False:
            raise RuntimeError(f"libcosim refused to set {v.name} of slave {index}")


def _initial_value(execution: Any, index: int, v: VariableInfo, value: Any) -> None:
    vr = v.value_reference
    if v.type == "Real":
        ok = execution.real_initial_value(index, vr, float(value))
    elif v.type in ("Integer", "Enumeration"):
        ok = execution.integer_initial_value(index, vr, int(value))
    elif v.type == "Boolean":
        ok = execution.boolean_initial_value(index, vr, bool(value))
    else:
        ok = execution.string_initial_value(index, vr, str(value))
    if ok is False:
        raise ScenarioError("libcosim", [(v.name, f"start value {value!r} refused")])


def _connect(execution: Any, src: tuple[int, VariableInfo], dst: tuple[int, VariableInfo]) -> None:
    (si, sv), (di, dv) = src, dst
    if sv.type != dv.type:
        raise ScenarioError("libcosim", [("connections", f"{sv.name} -> {dv.name}: "
                                                           f"{sv.type} to {dv.type}")])
    fn = {"Real": execution.connect_real_variables,
          "Integer": execution.connect_integer_variables,
          "Enumeration": execution.connect_integer_variables,
          "Boolean": execution.connect_boolean_variables,
          "String": execution.connect_string_variables}[sv.type]
    if fn(si, sv.value_reference, di, dv.value_reference) is False:
        raise ScenarioError("libcosim", [("connections",
                                           f"{sv.name} -> {dv.name} refused")])


def run_scenario_libcosim(scenario: Scenario | Path | str, fmu_dir: Path | str | None = None,
                          results_dir: Path | str | None = None) -> RunResult:
    """Run a scenario with libcosim (Jacobi coupling) and return what was recorded.

    Parameters
    ----------
    scenario : Scenario or path
        A validated scenario or its TOML file. Every ``step_ratio`` must be 1.
    fmu_dir : path, optional
        Folder of the ``<Name>.fmu`` files (as for the harness's master).
    results_dir : path, optional
        What ``${out}/`` stands for in the instances' ``files``.

    Returns
    -------
    RunResult
        Rows at 0, h, 2h, ... as the harness records them (``record.decimation``
        honoured); ``error`` holds libcosim's message if a step failed.

    Raises
    ------
    ScenarioError
        Unknown variables, a ``step_ratio`` other than 1, a value libcosim refuses.
    ImportError
        libcosimpy is not installed.
    """
    _, execution_cls, _, _, slave_cls = _libcosim()
    s = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
    _check_step_ratios(s)
    files = resolve_file_parameters(s, results_dir)
    paths, info = _checked_models(s, fmu_dir)
    execution = execution_cls.CosimExecution.from_step_size(step_size=to_ns(s.step_s))
    slaves = _Slaves(_add_slaves(execution, slave_cls, s, paths), info)
    values = _Values(execution)
    for n, ps in _start_values(s, files, info).items():
        for name, value in ps.items():
            _initial_value(execution, slaves.index[n], info[n].variables[name], value)
    for c in s.connections:
        _connect(execution, slaves.var(c.from_), slaves.var(c.to))

    names = [r.name for r in recorded_signals(s, info)]
    events = sorted([(f.start_s, 0, i, f) for i, f in enumerate(s.physical_faults)]
                    + [(f.end_s, 1, i, f) for i, f in enumerate(s.physical_faults)
                       if not math.isinf(f.end_s)])
    originals: dict[str, float] = {}

    def before_step(k: int) -> None:
        # the first step initialises every slave; a physical fault due at t = 0 is set
        # as a start value (the override manipulator acts on running slaves)
        while events and k * s.step_s >= events[0][0] - 1e-9 * s.step_s:
            _, is_end, _, fault = events.pop(0)
            _apply_physical(values, slaves, fault, is_end, originals, execution, k)

    return _simulate(execution, values, slaves, names, s.name, s.step_s, s.n_steps,
                     s.record.decimation, before_step, fault_windows(s))


def _check_step_ratios(s: Scenario) -> None:
    """libcosimpy exposes no decimation factor: every instance must step at the base step."""
    ratios = {n: i.step_ratio for n, i in s.fmus.items() if i.step_ratio != 1}
    if ratios:
        raise ScenarioError(s.source, [(f"fmus.{n}.step_ratio", f"{r}: libcosim runs every "
                                        "FMU at the base step here") for n, r in ratios.items()])


def _checked_models(s: Scenario, fmu_dir: Path | str | None
                    ) -> tuple[dict[str, Path], dict[str, ModelInfo]]:
    """FMU file and model of every instance, the scenario checked against the models."""
    folder = resolve_fmu_dir(s, fmu_dir)
    paths = {n: resolve_fmu_file(s, n, folder) for n in s.fmus}
    for n, p in paths.items():
        if not p.is_file():
            raise FileNotFoundError(f"{s.source}: fmus.{n}.fmu: FMU file {p} not found")
    info = {n: _model_info(p) for n, p in paths.items()}
    check_against_models(s, info)
    return paths, info


def _add_slaves(execution: Any, slave_cls: Any, s: Scenario,
                paths: dict[str, Path]) -> dict[str, int]:
    """Add one local slave per instance; its index by instance name."""
    index = {}
    for n, p in paths.items():
        index[n] = execution.add_local_slave(
            slave_cls.CosimLocalSlave(fmu_path=str(p.resolve()), instance_name=n))
        if index[n] < 0:
            raise ScenarioError(s.source, [(f"fmus.{n}.fmu", f"libcosim could not load {p}")])
    return index


def _start_values(s: Scenario, files: dict[str, dict[str, str]],
                  info: dict[str, ModelInfo]) -> dict[str, dict[str, Any]]:
    """Start values per instance: the scenario's, the injector faults', the files, and the
    Diagnoser's sample alignment of a Jacobi plan unless the scenario sets it."""
    params: dict[str, dict[str, Any]] = {n: dict(i.parameters) for n, i in s.fmus.items()}
    for f in s.injector_faults:
        params[f.injector].update(f.injector_parameters())
    for n, p in files.items():
        params[n].update(p)
    # libcosim steps every FMU on the outputs of the step before (Jacobi)
    fill_timing_parameters(params, s, s.connections, {n: i.variables for n, i in info.items()})
    return params


def _simulate(execution: Any, values: _Values, slaves: _Slaves, names: list[str],
              scenario: str, h: float, n_steps: int, decimation: int,
              before_step: Any, windows: list[Any]) -> RunResult:
    """Step ``execution`` n_steps times, recording ``names`` like the harness."""
    by_slave: dict[int, tuple[list[int], list[VariableInfo]]] = {}
    for col, q in enumerate(names):
        i, v = slaves.var(q)
        by_slave.setdefault(i, ([], []))[0].append(col)
        by_slave[i][1].append(v)

    def row() -> list[float]:
        out = [math.nan] * len(names)
        for i, (cols, variables) in by_slave.items():
            for col, x in zip(cols, values.read(i, variables), strict=True):
                out[col] = x
        return out

    times: list[float] = []
    rows: list[list[float]] = []
    error = None
    wall0 = time.perf_counter()
    try:
        for k in range(n_steps):
            if before_step is not None:
                before_step(k)
            if not execution.step(1):
                raise RuntimeError(_last_error())
            if k == 0:
                # libcosimpy cannot stop between initialisation and the first step: the
                # values after initialisation are unknown (NaN)
                times.append(0.0)
                rows.append([math.nan] * len(names))
            if (k + 1) % decimation == 0 or k + 1 == n_steps:
                times.append((k + 1) * h)
                rows.append(row())
    except RuntimeError as exc:
        error = f"libcosim: {exc}"
    table = np.array(rows, dtype=float) if rows else np.zeros((0, len(names)))
    return RunResult(
        scenario=scenario, time=np.array(times),
        signals={q: table[:, j].copy() for j, q in enumerate(names)},
        fault_windows=windows, step_s=h, error=error,
        wall_time_s=time.perf_counter() - wall0, stop_time_s=n_steps * h)


def run_ssp_libcosim(ssp: Path | str, record: Sequence[str],
                     duration_s: float | None = None) -> RunResult:
    """Load an SSP package with libcosim (``CosimExecution.from_ssp_file``) and run it.

    Parameters
    ----------
    ssp : path
        The ``.ssp`` file (its DefaultExperiment must give the stop time and the OSP
        fixed-step annotation the base step, as :func:`gyrodiag_harness.cosim.ssp.export_ssp`
        writes).
    record : sequence of str
        ``"component.variable"`` names to record after every step.
    duration_s : float, optional
        Run this long instead of the DefaultExperiment's stop time.

    Returns
    -------
    RunResult
        Named after the SSP's system; row 0 is NaN (see :func:`run_scenario_libcosim`).
    """
    _, execution_cls, _, _, _ = _libcosim()
    ssp = Path(ssp)
    name, h, stop, sources = _read_ssd(ssp)
    if duration_s is not None:
        stop = duration_s
    execution = execution_cls.CosimExecution.from_ssp_file(str(ssp.resolve()))
    import tempfile
    import zipfile

    info = {}
    with tempfile.TemporaryDirectory(prefix="gyrodiag-ssp-run-") as tmp, \
            zipfile.ZipFile(ssp) as zf:
        for comp, source in sources.items():
            fmu = Path(tmp) / f"{comp}.fmu"
            fmu.write_bytes(zf.read(source))
            info[comp] = _model_info(fmu)
    index = {comp: execution.slave_index_from_instance_name(comp) for comp in sources}
    slaves = _Slaves(index, info)
    values = _Values(execution)
    return _simulate(execution, values, slaves, list(record), name, h, round(stop / h), 1,
                     None, [])


def _read_ssd(ssp: Path) -> tuple[str, float, float, dict[str, str]]:
    """System name, base step, stop time and component FMU paths of an SSP."""
    import zipfile

    from lxml import etree as ET

    ssd_ns = "http://ssp-standard.org/SSP1/SystemStructureDescription"
    with zipfile.ZipFile(ssp) as zf:
        root = ET.fromstring(zf.read("SystemStructure.ssd"))
    experiment = root.find(f"{{{ssd_ns}}}DefaultExperiment")
    steps = [e.get("baseStepSize") for e in root.iter("{*}FixedStepAlgorithm")]
    if experiment is None or experiment.get("stopTime") is None or not steps:
        raise ScenarioError(str(ssp), [("SystemStructure.ssd", "no DefaultExperiment stopTime "
                                         "or OSP FixedStepAlgorithm baseStepSize")])
    sources = {c.get("name"): c.get("source") for c in root.iter(f"{{{ssd_ns}}}Component")}
    return (root.get("name", ssp.stem), float(steps[0]), float(experiment.get("stopTime")),
            sources)


def _apply_physical(values: _Values, slaves: _Slaves, fault: PhysicalFault, is_end: int,
                    originals: dict[str, float], execution: Any, k: int) -> None:
    i, v = slaves.var(fault.set)
    if is_end:
        values.override(i, v, originals[fault.name])
        return
    if k == 0:
        _initial_value(execution, i, v, fault.value)
        return
    originals[fault.name] = values.read(i, [v])[0]
    values.override(i, v, fault.value)


def _last_error() -> str:
    from libcosimpy._internal import get_last_error_message

    return str(get_last_error_message()) or "a step failed (see libcosim's log)"
