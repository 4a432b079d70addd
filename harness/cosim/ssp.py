"""Export a scenario as an SSP package (System Structure and Parameterization, SSP 1.0).

``python -m gyrodiag_harness export-ssp SCENARIO --out FILE.ssp`` (or :func:`export_ssp`) writes
one ``.ssp`` file that any SSP tool can load and run without the harness:

* ``SystemStructure.ssd``: one component per scenario instance (its FMU in
  ``resources/``), connectors for every connected or parameterised variable (type and
  unit from the FMU's modelDescription), the connections, and the default experiment
  (start 0, stop ``duration_s``) with the Open Simulation Platform annotation that
  gives libcosim its fixed base step (``step_s``) and each component's step
  (``step_ratio``, as a step-size hint);
* ``resources/<instance>.ssv``: the instance's parameter values, bound to it by its one
  ParameterBinding. Injector faults are parameter values of the FaultInjector
  (``fault_type_i``, ``t_start_i``, ``t_end_i``, ...), so they are carried completely.
  Every ``.ssv`` names the same parameter set, :data:`PARAMETER_SET`: libcosim applies
  each component's first binding whatever its name; Ecos merges the components' sets by
  name and applies one set, only when the host names it (``--parameterSet`` or
  ``init(parameter_set=...)``), so one shared name makes that one choice apply every
  value;
* ``resources/<Name>.fmu``: the FMUs. A ``files`` parameter (e.g. the DTG signature
  library) is packed into the FMU copy's own resources and the parameter set to that
  relative name, which the Diagnoser resolves in its resources; the SSP is then
  self-contained.

What SSP cannot carry is listed in :attr:`SspExport.not_carried` (the CLI prints it) and
in an annotation of the system: physical faults (a tunable parameter changed at a time:
SSP has no time events), the coupling order (SSP describes no master algorithm; the OSP
annotation asks for libcosim's fixed-step algorithm, which couples by Jacobi), and what
the harness records and expects.

The files are written with pyssp-standard (and checked against the SSP XSDs it ships),
not by hand.
"""

from __future__ import annotations

import io
import math
import shutil
import sys
import tempfile
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from gyrodiag_harness.cosim.plan import fmu_path, model_info
from gyrodiag_harness.cosim.scenario import (
    ModelInfo,
    Scenario,
    ScenarioError,
    VariableInfo,
    check_against_models,
    load_scenario,
    resolve_file_parameters,
    resolve_fmu_dir,
    split_name,
)
from gyrodiag_harness.cosim.timing import fill_timing_parameters

#: Annotation type understood by libcosim (fixed-step algorithm, step-size hints).
OSP_ANNOTATION = "com.opensimulationplatform"
OSP_NAMESPACE = "https://opensimulationplatform.com/SSP/OSPAnnotations"
#: Name of the one parameter set that every ``.ssv`` of an export belongs to (Ecos's
#: own SSP examples use this name; Ecos applies a set only when a host names it).
PARAMETER_SET = "initialValues"
#: Annotation type of the list of what the export could not carry.
NOT_CARRIED_ANNOTATION = "org.gyrodiag.not-carried"
#: Folder inside an FMU copy's resources that holds the packed ``files`` parameters.
PACKED_FILES = "gyrodiag-files"


@dataclass
class SspExport:
    """What :func:`export_ssp` wrote.

    Attributes
    ----------
    path : Path
        The ``.ssp`` file.
    components : list of str
        Instance names, one SSP component each.
    parameters : int
        Parameter values written (injector faults included).
    not_carried : list of str
        Parts of the scenario that SSP cannot express, one sentence each.
    """

    path: Path
    components: list[str]
    parameters: int
    not_carried: list[str] = field(default_factory=list)


def _pyssp() -> Any:
    try:
        import pyssp_standard
    except ImportError as exc:  # an optional dependency
        raise ImportError("pyssp-standard is not installed: pip install -e \".[ssp]\" (or pip "
                          f"install pyssp-standard) to export SSP files ({exc})") from None
    return pyssp_standard


def _model_info(fmu: Path) -> ModelInfo:
    """The model of an FMU file (read from the archive, not extracted)."""
    from fmpy import read_model_description

    return model_info(read_model_description(str(fmu)))


def _units(fmu: Path) -> tuple[dict[str, str], dict[str, dict[str, float]]]:
    """Unit of every Real variable that declares one; SI exponents of every unit."""
    from fmpy import read_model_description

    md = read_model_description(str(fmu))
    of_variable = {v.name: v.unit for v in md.modelVariables if v.type == "Real" and v.unit}
    keys = ("kg", "m", "s", "A", "K", "mol", "cd", "rad", "factor", "offset")
    definitions = {}
    for u in md.unitDefinitions:
        b = u.baseUnit
        exps = {} if b is None else {k: getattr(b, k) for k in keys}
        definitions[u.name] = {k: x for k, x in exps.items()
                               if x and not (k == "factor" and x == 1.0)}
    return of_variable, definitions


def _xml_value(v: VariableInfo, value: Any) -> str:
    """A parameter value as SSV writes it (xs:double / xs:int / xs:boolean / string)."""
    if v.type == "Real":
        x = float(value)
        if math.isinf(x):  # libcosim reads numbers with C++ streams, which take no "INF"
            return repr(math.copysign(sys.float_info.max, x))
        if math.isnan(x):
            return "NaN"
        return repr(x)
    if v.type in ("Integer", "Enumeration"):
        return str(int(value))
    if v.type == "Boolean":
        return "true" if bool(value) else "false"
    return str(value)


def _type(pyssp: Any, v: VariableInfo, unit: str | None) -> Any:
    from pyssp_standard.common_content_ssc import (
        TypeBoolean,
        TypeInteger,
        TypeReal,
        TypeString,
    )

    del pyssp
    if v.type == "Real":
        return TypeReal(unit)
    if v.type in ("Integer", "Enumeration"):
        return TypeInteger()
    if v.type == "Boolean":
        return TypeBoolean()
    return TypeString()


def _kind(v: VariableInfo) -> str:
    return {"input": "input", "output": "output", "parameter": "parameter",
            "calculatedParameter": "calculatedParameter"}.get(v.causality, "parameter")


def export_ssp(scenario: Scenario | Path | str, out: Path | str,
               fmu_dir: Path | str | None = None,
               results_dir: Path | str | None = None) -> SspExport:
    """Write ``scenario`` as an SSP package.

    Parameters
    ----------
    scenario : Scenario or path
        A validated scenario or its TOML file.
    out : path
        The ``.ssp`` file to write (replaced if it exists).
    fmu_dir : path, optional
        Folder of the ``<Name>.fmu`` files (as for the harness's master).
    results_dir : path, optional
        What ``${out}/`` stands for in the instances' ``files``.

    Returns
    -------
    SspExport
        What was written and what could not be carried.

    Raises
    ------
    ScenarioError
        Invalid scenario or unknown variable names.
    FileNotFoundError
        A missing FMU or ``files`` file.
    ImportError
        pyssp-standard is not installed.
    """
    pyssp = _pyssp()
    s = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
    out = Path(out)
    if out.suffix != ".ssp":
        raise ScenarioError("export-ssp", [("--out", f"{out}: an SSP file ends in .ssp")])
    files = resolve_file_parameters(s, results_dir)
    folder = resolve_fmu_dir(s, fmu_dir)
    paths = {n: fmu_path(s, n, folder) for n in s.fmus}
    info = {n: _model_info(p) for n, p in paths.items()}
    check_against_models(s, info)
    values, packed = _parameter_values(s, files, info, paths)
    not_carried = _not_carried(s)
    fmu_names = _fmu_names(paths)
    out.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="gyrodiag-ssp-") as tmp:
        staging = Path(tmp)
        target = staging / out.name
        with pyssp.SSP(target, mode="w") as ssp:
            for p, name in fmu_names.items():
                copy = staging / name
                _copy_fmu(p, copy, packed.get(p, {}))
                ssp.add_resource(copy)
            n_parameters = _write_ssvs(pyssp, ssp, staging, values, info)
            with ssp.system_structure as ssd:
                _write_ssd(pyssp, ssd, s, _Parts(paths, info, values, fmu_names,
                                                 not_carried))
        _finish_ssd(target, s)
        check_ssp(target)
        shutil.move(str(target), out)
    return SspExport(out, list(s.fmus), n_parameters, not_carried)


@dataclass
class _Parts:
    """What the system structure is written from: FMU files, models, parameter values,
    FMU names inside the package, what cannot be carried."""

    paths: dict[str, Path]
    info: dict[str, ModelInfo]
    values: dict[str, dict[str, Any]]
    fmu_names: dict[Path, str]
    not_carried: list[str]


def _parameter_values(s: Scenario, files: dict[str, dict[str, str]],
                      info: dict[str, ModelInfo], paths: dict[str, Path]
                      ) -> tuple[dict[str, dict[str, Any]], dict[Path, dict[str, Path]]]:
    """Parameter values per instance (the scenario's, the injector faults', the Jacobi
    sample alignment, packed files) and the files to pack into each FMU copy."""
    values: dict[str, dict[str, Any]] = {n: dict(i.parameters) for n, i in s.fmus.items()}
    for f in s.injector_faults:
        values[f.injector].update(f.injector_parameters())
    # SSP tools step every FMU in parallel (libcosim's fixed-step algorithm: Jacobi), so
    # the Diagnoser's sample alignment is that of a Jacobi plan
    fill_timing_parameters(values, s, s.connections,
                           {n: i.variables for n, i in info.items()})
    packed: dict[Path, dict[str, Path]] = {}  # FMU file -> {name in its resources: file}
    for inst, params in files.items():
        for name, file_path in params.items():
            inside = f"{PACKED_FILES}/{inst}/{name}{Path(file_path).suffix}"
            packed.setdefault(paths[inst], {})[inside] = Path(file_path)
            values[inst][name] = inside
    return values, packed


def _connector_names(s: Scenario, values: dict[str, dict[str, Any]]) -> dict[str, list[str]]:
    """Every connected or parameterised variable of each instance, in first-use order."""
    used: dict[str, list[str]] = {n: [] for n in s.fmus}
    for c in s.connections:
        for q in (c.from_, c.to):
            inst, var = split_name(q)
            if var not in used[inst]:
                used[inst].append(var)
    for inst, params in values.items():
        used[inst] += [p for p in params if p not in used[inst]]
    return used


def _fmu_names(paths: dict[str, Path]) -> dict[Path, str]:
    """A distinct file name inside the package for every distinct FMU file."""
    fmu_names: dict[Path, str] = {}
    for p in paths.values():
        if p not in fmu_names:
            stem, k = p.stem, 1
            while f"{stem}.fmu" in fmu_names.values():
                k += 1
                stem = f"{p.stem}_{k}"
            fmu_names[p] = f"{stem}.fmu"
    return fmu_names


def _write_ssvs(pyssp: Any, ssp: Any, staging: Path, values: dict[str, dict[str, Any]],
                info: dict[str, ModelInfo]) -> int:
    """One ``.ssv`` per instance with parameters (all in :data:`PARAMETER_SET`); how
    many parameters were written."""
    n_parameters = 0
    for inst, params in values.items():
        if not params:
            continue
        ssv_path = staging / f"{inst}.ssv"
        with pyssp.SSV(ssv_path, mode="w") as ssv:
            ssv.ssv_elem.name = PARAMETER_SET
            for name, value in params.items():
                v = info[inst].variables[name]
                ssv.add_parameter(name, "Integer" if v.type == "Enumeration"
                                  else v.type, value=_xml_value(v, value))
                # pyssp-standard 0.9 writes a Real's unit even when None
                typed = ssv.parameters[-1]["type_value"]
                typed.parameter = {k: x for k, x in typed.parameter.items()
                                   if x is not None}
                n_parameters += 1
        ssp.add_resource(ssv_path)
    return n_parameters


def _write_ssd(pyssp: Any, ssd: Any, s: Scenario, parts: _Parts) -> None:
    """The system structure: components with connectors and bindings, connections, the
    not-carried note, units, the default experiment."""
    from pyssp_standard.common_content_ssc import Annotation
    from pyssp_standard.ssd import Connection, DefaultExperiment, System
    from pyssp_standard.unit import BaseUnit, Unit

    units, unit_definitions = {}, {}
    for n, p in parts.paths.items():
        units[n], definitions = _units(p)
        unit_definitions.update(definitions)
    used = _connector_names(s, parts.values)
    ssd.name = s.name
    ssd.version = "1.0"
    system = System(name=s.name)
    for inst in s.fmus:
        system.elements.append(_component(pyssp, inst, parts, used[inst], units[inst]))
    for c in s.connections:
        (si, sv), (di, dv) = split_name(c.from_), split_name(c.to)
        system.connections.append(Connection(
            start_element=si, start_connector=sv, end_element=di, end_connector=dv))
    if parts.not_carried:
        note = Annotation(NOT_CARRIED_ANNOTATION)
        note.add_text("Not carried by this SSP (gyrodiag export-ssp): "
                      + " | ".join(parts.not_carried))
        system.annotations.add_annotation(note)
    ssd.system = system
    used_units = sorted({units[i].get(var) for i in s.fmus for var in used[i]} - {None})
    for unit in used_units:
        ssd.units.add_unit(Unit(unit, base_unit=BaseUnit(unit_definitions.get(unit, {}))))
    experiment = DefaultExperiment()
    experiment.start_time = 0.0
    experiment.stop_time = s.duration_s
    experiment.annotations.add_annotation(_osp_algorithm(s.step_s))
    ssd.default_experiment = experiment


def _component(pyssp: Any, inst: str, parts: _Parts, used: list[str],
               units: dict[str, str]) -> Any:
    """The SSD component of one instance: its FMU, connectors, parameter binding."""
    from pyssp_standard.ssd import Component, Connector, ParameterBinding

    comp = Component()
    comp.name = inst
    comp.component_type = "application/x-fmu-sharedlibrary"
    comp.source = f"resources/{parts.fmu_names[parts.paths[inst]]}"
    for var in used:
        v = parts.info[inst].variables[var]
        comp.connectors.append(Connector(name=var, kind=_kind(v),
                                         type_=_type(pyssp, v, units.get(var))))
    if parts.values[inst]:
        comp.parameter_bindings = [ParameterBinding(source=f"resources/{inst}.ssv")]
    return comp


def _not_carried(s: Scenario) -> list[str]:
    notes = [f"physical fault {f.name!r}: {f.set} = {f.value!r} from {f.start_s:g} s"
             + ("" if math.isinf(f.end_s) else f" to {f.end_s:g} s")
             + " (SSP has no time events; run the scenario with the harness or set it "
               "by hand in the SSP tool)"
             for f in s.physical_faults]
    if s.coupling != "jacobi":
        notes.append(f"coupling {s.coupling!r} (SSP describes no master algorithm; the OSP "
                     "annotation asks libcosim for its fixed-step algorithm, which couples "
                     "by Jacobi)")
    infinite = [f"{f.injector}.{k}" for f in s.injector_faults
                for k, x in f.injector_parameters().items()
                if isinstance(x, float) and math.isinf(x)]
    infinite += [f"{n}.{k}" for n, i in s.fmus.items() for k, x in i.parameters.items()
                 if isinstance(x, float) and math.isinf(x)]
    if infinite:
        notes.append(f"infinite values of {', '.join(infinite)} are written as the largest "
                     "double, 1.8e308 (libcosim reads no INF)")
    notes.append("[record] and [[expect]] (what the harness records and checks)")
    notes.append(f"which parameter set to apply (SSP names no default): every .ssv is set "
                 f"{PARAMETER_SET!r}; libcosim applies it by default, Ecos only when named "
                 f"(--parameterSet {PARAMETER_SET})")
    return notes


def _osp_algorithm(step_s: float) -> Any:
    from lxml import etree as ET
    from pyssp_standard.common_content_ssc import Annotation

    annotation = Annotation(OSP_ANNOTATION)
    algorithm = ET.SubElement(annotation.root, f"{{{OSP_NAMESPACE}}}Algorithm",
                              nsmap={"osp": OSP_NAMESPACE})
    ET.SubElement(algorithm, f"{{{OSP_NAMESPACE}}}FixedStepAlgorithm",
                  baseStepSize=repr(float(step_s)))
    return annotation


def _finish_ssd(ssp_file: Path, s: Scenario) -> None:
    """Edits pyssp-standard (0.9) cannot make, done on the written SSD with lxml:

    * ``<Units>`` goes before ``<DefaultExperiment>`` (the schema's order; the library
      writes it after, which its own compliance check then rejects);
    * components with ``step_ratio`` > 1 get libcosim's StepSizeHint annotation (the
      library writes no component annotations);
    * the ``osp`` namespace is declared on the root element.
    """
    from lxml import etree as ET

    ssd_ns = "http://ssp-standard.org/SSP1/SystemStructureDescription"
    ssc_ns = "http://ssp-standard.org/SSP1/SystemStructureCommon"
    with zipfile.ZipFile(ssp_file) as zf:
        entries = {name: zf.read(name) for name in zf.namelist()}
    root = ET.fromstring(entries["SystemStructure.ssd"])
    units = root.find(f"{{{ssd_ns}}}Units")
    experiment = root.find(f"{{{ssd_ns}}}DefaultExperiment")
    if units is not None and experiment is not None:
        experiment.addprevious(units)
    hinted = {n: i.step_ratio * s.step_s for n, i in s.fmus.items() if i.step_ratio != 1}
    for comp in root.iter(f"{{{ssd_ns}}}Component"):
        if comp.get("name") in hinted:
            annotations = ET.SubElement(comp, f"{{{ssd_ns}}}Annotations")
            annotation = ET.SubElement(annotations, f"{{{ssc_ns}}}Annotation",
                                       type=OSP_ANNOTATION)
            ET.SubElement(annotation, f"{{{OSP_NAMESPACE}}}StepSizeHint",
                          nsmap={"osp": OSP_NAMESPACE}, value=repr(hinted[comp.get("name")]))
    # libcosim reads the SSD with boost's property tree, which takes a namespace
    # declaration on osp:Algorithm for a child element: declare osp on the root
    ET.cleanup_namespaces(root, top_nsmap={"osp": OSP_NAMESPACE})
    entries["SystemStructure.ssd"] = ET.tostring(root, xml_declaration=True, encoding="utf-8",
                                                 pretty_print=True)
    _write_zip(ssp_file, entries)


def _write_zip(path: Path, entries: dict[str, bytes]) -> None:
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED) as zf:
        for name, data in entries.items():
            zf.writestr(name, data)
    path.write_bytes(buffer.getvalue())


def _copy_fmu(src: Path, dst: Path, extra: dict[str, Path]) -> None:
    """Copy an FMU, adding ``extra`` files under its ``resources/``."""
    if not extra:
        shutil.copyfile(src, dst)
        return
    with zipfile.ZipFile(src) as zf:
        entries = {name: zf.read(name) for name in zf.namelist()}
    for inside, file_path in extra.items():
        entries[f"resources/{inside}"] = file_path.read_bytes()
    _write_zip(dst, entries)


def check_ssp(path: Path | str) -> None:
    """Validate an SSP's SystemStructure.ssd and .ssv files against the SSP 1.0 XSDs.

    Raises
    ------
    xmlschema.XMLSchemaValidationError
        With the offending element and the rule it breaks.
    """
    pyssp = _pyssp()
    with pyssp.SSP(Path(path), mode="r") as ssp:
        ssp.system_structure.__check_compliance__()
        for ssv in ssp.ssv:
            ssv.__check_compliance__()
