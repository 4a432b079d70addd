"""Build every gyrodiag FMU (FMI 2.0 co-simulation, pythonfmu 0.7) and make it valid.

Usage::

    python build_fmu.py [--out build/fmus] [NAME ...]

Each FMU is built in a fresh subprocess (``python build_fmu.py --_one NAME --out DIR``)
because the pythonfmu builder imports the model script, and two scripts imported into one
interpreter could shadow each other's modules (docs/methods.md §6.3, §6.4).  After the build the
subprocess post-processes ``modelDescription.xml``, which pythonfmu leaves invalid
(docs/methods.md §6.1, §6.2):

* ``variability`` on every variable (pythonfmu omits it for Integer/Boolean, for which the
  FMI default ``continuous`` is illegal);
* ``<ModelStructure>`` rebuilt: ``<Outputs>`` with direct input dependencies (from the
  script's ``OUTPUT_DEPENDENCIES``; default none, outputs are computed in ``do_step``)
  and ``<InitialUnknowns>`` (outputs with initial calculated/approx plus calculated
  parameters);
* units, min/max/nominal and descriptions from the script's ``VARIABLE_META``, with every
  unit declared in ``<UnitDefinitions>`` (SI base-unit exponents where known);
* ``resources/slavemodule.txt`` names a generated entry module that imports the model
  class (``ENTRY_TEMPLATE``): pythonfmu executes its entry module's file again at every
  instantiation, and the model script leaked its classes each time;
* ``resources/requirements.txt`` from the script's ``REQUIREMENTS`` (default numpy+scipy),
  because the FMU runs on the host's Python (docs/methods.md §6.5).  Hosts that are not Python
  processes need no LD_PRELOAD: the status shim finds and starts a Python itself
  (``HOST_NOTES`` below, in every FMU's documentation).

The Linux binary is wrapped by the status shim (``fmu_src/shim/fmi2_status_shim.c``,
compiled here with the system C compiler against fmpy's FMI headers): pythonfmu 0.7
turns every Python exception into fmi2Fatal, so our facades log problems at error
status instead of raising, and the shim returns fmi2Error for such a call. The shim also
starts the interpreter in hosts that are not Python processes and guards FMU states. The original
pythonfmu library is kept next to it as ``pythonfmu-export.so``. Without a C compiler
the FMU is built unwrapped, with a warning (errors then surface as fmi2OK + log).

A shipped package with C kernels (``gyrodiag/common/_ckernels.c``) gets them compiled here for
the building Python (CPython stable ABI: any CPython >= 3.11 on the platform) as
``resources/gyrodiag/common/_ckernels.abi3.so``; extension modules and caches the builder copied
from the source tree are dropped. Without a compiler the FMU runs the plain-Python kernels.

Generated resources (:data:`GENERATED_RESOURCES`): data files an FMU ships that are
computed from another model's source, written by that model's own command line in a
fresh process at build time (never committed).  The Diagnoser carries the paper DTG's
rate read-out dynamics (``models/dtg/gd_dtg_readout.py``) as
``resources/sensor_dynamics/dtg_paper_y_q3_1ms.json``, which a system scenario names with
``df.sensor_dynamics_file = "sensor_dynamics/dtg_paper_y_q3_1ms.json"`` (relative to the
resources), and the detection filter's default observer designs
(``resources/gyrodiag/df/observer_gains.npz``, :mod:`gyrodiag.df.gains`), so that its
start-up does not import ``scipy.signal``.

Finally every FMU is checked with ``fmpy.validation.validate_fmu``; any problem makes
the command exit non-zero.  An FMU whose source folder does not exist yet is skipped with
a message (it is not an error).
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import io
import py_compile
import subprocess
import sys
import tempfile
import time
import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent
DEFAULT_OUT = ROOT / "build" / "fmus"

# (model name, source folder relative to the repository root, script file name)
REGISTRY: list[tuple[str, str, str]] = [
    ("FaultInjector", "models/fault_injector", "gd_fault_injector_fmu.py"),
    ("HRG", "models/hrg", "gd_hrg_fmu.py"),
    ("Aircraft", "models/aircraft", "gd_aircraft_fmu.py"),
    ("PitchController", "models/pitch_controller", "gd_pitch_controller_fmu.py"),
    ("DTG", "models/dtg", "gd_dtg_fmu.py"),
    ("Diagnoser", "fmu_src", "gd_diagnoser_fmu.py"),
]

#: Resources generated at build time: FMU name -> [(archive name under resources/, the
#: command's script relative to the repository root, its arguments; the builder appends
#: ``--out FILE``)].  The script's folder is added to the FMU's sources (staleness).
GENERATED_RESOURCES: dict[str, list[tuple[str, str, tuple[str, ...]]]] = {
    "Diagnoser": [
        # the paper DTG (set 1) as the pitch gyro: its y-axis read-out is the filter's
        # sensor 3 (q), at the 1 kHz of the system scenarios (docs/readout_dynamics.md)
        ("sensor_dynamics/dtg_paper_y_q3_1ms.json", "models/dtg/gd_dtg_readout.py",
         ("--set", "1", "--axis", "y", "--sensor", "3", "--step", "0.001")),
        # the detection filter's default observer designs (gyrodiag.df.gains): a
        # Diagnoser that finds its bank here never imports scipy.signal (0.7-1 s)
        ("gyrodiag/df/observer_gains.npz", "fmu_src/tools/observer_gains.py", ()),
    ],
}

DEFAULT_REQUIREMENTS = ["numpy>=1.24", "scipy>=1.10"]
SHIM_SOURCE = ROOT / "fmu_src" / "shim" / "fmi2_status_shim.c"
SHIM_INNER_NAME = "pythonfmu-export.so"

#: pythonfmu's entry module of every FMU (``resources/slavemodule.txt`` names it), in
#: place of the model script. pythonfmu 0.7 (``findClass`` in its binary) imports that
#: module and then compiles and executes its file again at every fmi2Instantiate, in the
#: module's globals with fresh locals, keeps a list of the MRO of every class that run
#: defines (so every class it defines, with its functions, stays alive), releases one
#: reference to the module's globals that it never took, and inserts the resources
#: directory into ``sys.path`` once more. Executed again, the model script leaked its
#: classes at every instance (issue 37); this stub leaves one MRO list and the names of
#: its classes (under 1 kB), gives the reference back and keeps ``sys.path`` from
#: growing. Fields: module, class.
ENTRY_TEMPLATE = '''"""pythonfmu's entry module of this FMU (build_fmu.py, ENTRY_TEMPLATE).

The model is {module}.{cls}; pythonfmu executes this file again at every fmi2Instantiate.
"""
import ctypes as _ctypes
import sys as _sys

if locals() is not globals():  # executed again by pythonfmu's findClass
    _ctypes.pythonapi.Py_IncRef(_ctypes.py_object(globals()))  # the one it releases
    if _sys.path and _sys.path[0] in _sys.path[1:]:  # its sys.path entry of this instance
        _sys.path[1:] = [p for p in _sys.path[1:] if p != _sys.path[0]]
else:  # first import: every package of requirements.txt, or an error that names them
    import importlib.util as _util
    import os as _os
    import re as _re

    with open(_os.path.join(_os.path.dirname(__file__), "requirements.txt")) as _f:
        _names = [_re.split(r"[<>=!~;\\[ ]", _r.strip())[0] for _r in _f
                  if _r.strip() and "# optional at start-up" not in _r]
    _missing = [_n for _n in _names if _util.find_spec(_n) is None]
    if _missing:
        raise ImportError(
            f"{{', '.join(_missing)}} missing: this FMU needs the packages of "
            f"resources/requirements.txt ({{', '.join(_names)}}) in the Python that runs it: "
            "install them there (python -m pip install -r "
            "requirements.txt) or, in a host that is not a Python process, set "
            "GYRODIAG_PYTHON to a python executable that has them")
from {module} import {cls}  # noqa: E402
'''


def entry_module_name(script_stem: str) -> str:
    """Name of the entry module of the FMU whose model script is ``script_stem``."""
    return f"{script_stem}_entry"


# FMI 2.0 BaseUnit exponents (and factor) of the unit strings used in this project.
# A unit not listed here is still declared, only without its SI decomposition.
KNOWN_UNITS: dict[str, dict[str, float]] = {
    "1": {},
    "s": {"s": 1},
    "Hz": {"s": -1},
    "1/s": {"s": -1},
    "rad": {"rad": 1},
    "deg": {"rad": 1, "factor": 0.017453292519943295},
    "rad/s": {"rad": 1, "s": -1},
    "rad/s2": {"rad": 1, "s": -2},
    "deg/s": {"rad": 1, "s": -1, "factor": 0.017453292519943295},
    "deg/h": {"rad": 1, "s": -1, "factor": 0.017453292519943295 / 3600.0},
    "m": {"m": 1},
    "m/s": {"m": 1, "s": -1},
    "m/s2": {"m": 1, "s": -2},
    "kg": {"kg": 1},
    "kg.m2": {"kg": 1, "m": 2},
    "N": {"kg": 1, "m": 1, "s": -2},
    "N.m": {"kg": 1, "m": 2, "s": -2},
    "A": {"A": 1},
    "V": {"kg": 1, "m": 2, "s": -3, "A": -1},
    "V/s": {"kg": 1, "m": 2, "s": -4, "A": -1},
    "V2": {"kg": 2, "m": 4, "s": -6, "A": -2},
    "V/(rad/s)": {"kg": 1, "m": 2, "s": -2, "A": -1, "rad": -1},
    "N.m/A": {"kg": 1, "m": 2, "s": -2, "A": -1},
    "rad/s/A": {"rad": 1, "s": 1, "A": -1, "kg": -1, "m": -2},
    "rpm": {"rad": 1, "s": -1, "factor": 0.10471975511965977},
    "ohm": {"kg": 1, "m": 2, "s": -3, "A": -2},
    "H": {"kg": 1, "m": 2, "s": -2, "A": -2},
    "1/s2": {"s": -2},
    "N.m/rad": {"kg": 1, "m": 2, "s": -2, "rad": -1},
    "m/rad": {"m": 1, "rad": -1},
    "rad/m": {"rad": 1, "m": -1},
    "m.s/rad": {"m": 1, "s": 1, "rad": -1},
    "rad.s/m": {"rad": 1, "s": 1, "m": -1},
    "m/(rad.s)": {"m": 1, "s": -1, "rad": -1},
    "rad/(m.s)": {"rad": 1, "s": -1, "m": -1},
    "m/(rad.s2)": {"m": 1, "s": -2, "rad": -1},
    "rad/(m.s2)": {"rad": 1, "s": -2, "m": -1},
}
_BASE_UNIT_ORDER = ("kg", "m", "s", "A", "K", "mol", "cd", "rad", "factor", "offset")


def script_path(entry: tuple[str, str, str]) -> Path:
    """Absolute path of the pythonfmu script of a registry entry."""
    _, folder, script = entry
    return ROOT / folder / script


#: Shipped with every FMU: the facades' shared base (guarded states, step checks).
FACADE_BASE = ROOT / "fmu_src" / "gd_fmu_base.py"


def project_files(entry: tuple[str, str, str]) -> list[Path]:
    """Files shipped next to the script: sibling modules and packages, the facade base."""
    script = script_path(entry)
    folder = script.parent
    files = [p for p in sorted(folder.glob("*.py"))
             if p != script and not p.name.startswith("test_")]
    if FACADE_BASE not in files:
        files.append(FACADE_BASE)
    packages = [p for p in sorted(folder.iterdir()) if p.is_dir() and (p / "__init__.py").exists()]
    return files + packages


def source_files(entry: tuple[str, str, str]) -> list[Path]:
    """Every file whose change makes the FMU stale (script, project files, this builder)."""
    out = [script_path(entry), Path(__file__).resolve(), SHIM_SOURCE]
    for _, script, _ in GENERATED_RESOURCES.get(entry[0], []):
        out.extend(sorted((ROOT / script).parent.glob("*.py")))
    for p in project_files(entry):
        out.extend(sorted([*p.rglob("*.py"), *p.rglob("*.c"), *p.rglob("*.json")])
                   if p.is_dir() else [p])
    return out


def available(entry: tuple[str, str, str]) -> bool:
    return script_path(entry).exists()


def stale_fmus(out_dir: Path, names: list[str] | None = None) -> list[str]:
    """Names of available FMUs missing from ``out_dir`` or older than one of their sources."""
    stale = []
    for entry in REGISTRY:
        name = entry[0]
        if (names and name not in names) or not available(entry):
            continue
        fmu = Path(out_dir) / f"{name}.fmu"
        if not fmu.exists():
            stale.append(name)
            continue
        built = fmu.stat().st_mtime
        if any(src.stat().st_mtime > built for src in source_files(entry)):
            stale.append(name)
    return stale


# ----------------------------------------------------------------------------------------
# post-processing of modelDescription.xml
# ----------------------------------------------------------------------------------------

def _default_variability(causality: str, type_tag: str) -> str:
    if causality in ("parameter", "calculatedParameter"):
        return "fixed"
    return "continuous" if type_tag == "Real" else "discrete"


def rebuild_stale(out: Path, names: list[str] | None = None) -> list[str]:
    """Rebuild, in a fresh process, the FMUs of ``out`` older than their sources (all
    of ``names``, or every FMU); the names rebuilt. For benchmarks and tools."""
    stale = stale_fmus(out, names)
    if stale:
        subprocess.run([sys.executable, str(ROOT / "build_fmu.py"), "--out", str(out),
                        *stale], cwd=ROOT, check=True, capture_output=True, timeout=3600)
    return stale


def _format_number(value: float | int) -> str:
    return str(int(value)) if isinstance(value, int) else f"{float(value):.16g}"


def _unit_element(name: str) -> ET.Element:
    unit = ET.Element("Unit", {"name": name})
    exps = KNOWN_UNITS.get(name)
    if exps:
        attrib = {k: _format_number(exps[k]) for k in _BASE_UNIT_ORDER if k in exps}
        ET.SubElement(unit, "BaseUnit", attrib)
    return unit


def postprocess_model_description(
    xml_bytes: bytes,
    variable_meta: dict[str, dict],
    output_dependencies: dict[str, list[str]],
) -> tuple[bytes, list[str]]:
    """Return the fixed modelDescription and a list of notes (unknown units, bad names).

    Raises
    ------
    ValueError
        If ``variable_meta`` or ``output_dependencies`` name a variable the FMU lacks.
    """
    root = ET.fromstring(xml_bytes)
    svs = list(root.find("ModelVariables"))
    by_name = {sv.get("name"): sv for sv in svs}
    unknown = sorted(set(variable_meta) - set(by_name))
    if unknown:
        raise ValueError(f"VARIABLE_META names unknown variables: {unknown}")
    unknown = sorted(set(output_dependencies) - set(by_name))
    if unknown:
        raise ValueError(f"OUTPUT_DEPENDENCIES names unknown variables: {unknown}")
    units_used = _apply_variable_meta(svs, variable_meta)
    notes = _write_unit_definitions(root, units_used)
    _write_model_structure(root, svs, output_dependencies)
    ET.indent(root, space="  ")
    return ET.tostring(root, encoding="UTF-8", xml_declaration=True), notes


def _apply_variable_meta(svs: list[ET.Element], variable_meta: dict[str, dict]) -> list[str]:
    """Variability, description, unit and bounds of each variable; the units used."""
    units_used: list[str] = []
    for sv in svs:
        name = sv.get("name")
        type_el = sv[0]
        causality = sv.get("causality", "local")
        if sv.get("variability") is None:
            sv.set("variability", _default_variability(causality, type_el.tag))
        meta = variable_meta.get(name, {})
        if "description" in meta and not sv.get("description"):
            sv.set("description", meta["description"])
        for key in ("unit", "displayUnit", "min", "max", "nominal", "quantity"):
            if key not in meta:
                continue
            if key in ("unit", "displayUnit", "nominal") and type_el.tag != "Real":
                raise ValueError(f"{key} given for non-Real variable {name!r}")
            value = meta[key]
            type_el.set(key, value if isinstance(value, str) else _format_number(value))
        unit = type_el.get("unit")
        if unit is not None and unit not in units_used:
            units_used.append(unit)
    return units_used


def _write_unit_definitions(root: ET.Element, units_used: list[str]) -> list[str]:
    """<UnitDefinitions> right after <CoSimulation> (schema order); notes on unknown units."""
    notes: list[str] = []
    for old in root.findall("UnitDefinitions"):
        root.remove(old)
    if units_used:
        unit_defs = ET.Element("UnitDefinitions")
        for unit in sorted(units_used):
            if unit not in KNOWN_UNITS:
                notes.append(f"unit {unit!r} has no SI decomposition in KNOWN_UNITS")
            unit_defs.append(_unit_element(unit))
        cosim_pos = list(root).index(root.find("CoSimulation"))
        root.insert(cosim_pos + 1, unit_defs)
    return notes


def _write_model_structure(root: ET.Element, svs: list[ET.Element],
                           output_dependencies: dict[str, list[str]]) -> None:
    """<ModelStructure> rebuilt from scratch: outputs with their dependencies, and the
    initial unknowns."""
    by_name = {sv.get("name"): sv for sv in svs}
    index_of = {sv.get("name"): i + 1 for i, sv in enumerate(svs)}
    old_structure = root.find("ModelStructure")
    if old_structure is not None:
        root.remove(old_structure)
    structure = ET.SubElement(root, "ModelStructure")
    outputs = [sv for sv in svs if sv.get("causality") == "output"]
    if outputs:
        out_el = ET.SubElement(structure, "Outputs")
        for sv in outputs:
            name = sv.get("name")
            deps = output_dependencies.get(name, [])
            for dep in deps:
                if by_name[dep].get("causality") != "input":
                    raise ValueError(f"output {name!r} depends on {dep!r}, which is no input")
            attrib = {"index": str(index_of[name]),
                      "dependencies": " ".join(str(index_of[d]) for d in deps)}
            if deps:
                attrib["dependenciesKind"] = " ".join("dependent" for _ in deps)
            ET.SubElement(out_el, "Unknown", attrib)
    initial_unknowns = [
        sv for sv in svs
        if (sv.get("causality") == "output"
            and sv.get("initial", "calculated") in ("approx", "calculated"))
        or sv.get("causality") == "calculatedParameter"
    ]
    if initial_unknowns:
        init_el = ET.SubElement(structure, "InitialUnknowns")
        for sv in initial_unknowns:
            # no dependencies attribute: depends on all knowns (parameters, start values)
            ET.SubElement(init_el, "Unknown", {"index": str(index_of[sv.get("name")])})


def compile_status_shim(work_dir: Path) -> Path | None:
    """Compile the Linux status shim into ``work_dir``; None (with a warning) if impossible."""
    import shutil

    import fmpy

    if not sys.platform.startswith("linux"):
        print("[build_fmu] warning: status shim is built on Linux only; FMU left unwrapped")
        return None
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        print("[build_fmu] warning: no C compiler found; FMU left without the status shim "
              "(errors will be logged but the call returns fmi2OK)")
        return None
    headers = Path(fmpy.__file__).parent / "c-code"
    work_dir.mkdir(parents=True, exist_ok=True)
    out = work_dir / "fmi2_status_shim.so"
    cmd = [cc, "-O2", "-shared", "-fPIC", "-pthread", "-Wall", "-Wextra", "-Werror", f"-I{headers}",
           "-o", str(out), str(SHIM_SOURCE), "-ldl"]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    if proc.returncode != 0:
        raise RuntimeError(f"compiling the status shim failed:\n{proc.stderr}")
    return out


def compile_kernels(source: Path, work_dir: Path) -> Path | None:
    """Compile a package's C kernels (``_ckernels.c``) for the Python running this build.

    The extension uses the CPython stable ABI (3.11), so the ``.abi3.so`` loads in any
    CPython >= 3.11 on the same platform, whatever numpy it has. Returns None with a
    warning when there is no compiler (the FMU then runs the plain-Python kernels).
    """
    import shutil
    import sysconfig

    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None or not sys.platform.startswith("linux"):
        print("[build_fmu] warning: no C compiler (or not Linux): the FMU gets no compiled "
              "kernels and runs the plain-Python fallback")
        return None
    work_dir.mkdir(parents=True, exist_ok=True)
    out = work_dir / "_ckernels.abi3.so"
    include = sysconfig.get_paths()["include"]
    cmd = [cc, "-O2", "-shared", "-fPIC", "-ffp-contract=off", "-Wall", "-Wextra",
           "-Wno-unused-parameter", "-Wno-missing-field-initializers",
           "-Wno-cast-function-type", "-Werror", f"-I{include}", "-o", str(out), str(source)]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    if proc.returncode != 0:
        raise RuntimeError(f"compiling {source.name} failed:\n{proc.stderr}")
    return out


HOST_NOTES = """
<h2>Using this FMU</h2>
<p>This is an FMI 2.0 co-simulation FMU made with pythonfmu 0.7: its binary runs the
model in a CPython interpreter of the host machine and imports the model from
<code>resources/</code>. What a host needs:</p>
<ul>
<li><b>Platform</b>: Linux x86-64 only (<code>binaries/linux64</code>, with the gyrodiag
status shim described below). No binary for another platform is shipped: pythonfmu's
Windows one lacks the shim and has never been run with these FMUs.</li>
<li><b>A Python with the packages</b> of <code>resources/requirements.txt</code>
(<code>python -m pip install -r requirements.txt</code>); pythonfmu itself is shipped in
<code>resources/</code>. Tested with CPython 3.11. Without one of them fmi2Instantiate
returns NULL and logs which package is missing, in which Python, and GYRODIAG_PYTHON.</li>
<li><b>Python hosts</b> (FMPy, the gyrodiag harness, libcosimpy): nothing else; the FMU
uses the host's interpreter.</li>
<li><b>Hosts that are not Python processes</b> (a C master, libcosim's cosim, Simulink,
OMSimulator) on Linux: nothing to preload. At the first fmi2Instantiate the binary asks
one Python executable, once, where its shared libpython and its <code>sys.path</code>
are: <code>$GYRODIAG_PYTHON</code> if set (a path to a python executable), else
<code>$VIRTUAL_ENV/bin/python</code>, else <code>python3</code> on <code>PATH</code>.
It loads that libpython with RTLD_GLOBAL, starts the interpreter on the calling thread
without signal handlers, gives it that <code>sys.path</code> (its site-packages,
<code>.pth</code> entries and <code>PYTHONPATH</code>) and leaves it running until the
process exits: the interpreter is not finalised (finalising scipy there crashed hosts at
exit). That Python needs a shared libpython: a build with <code>--enable-shared</code>
(python.org installers, conda, pyenv with
<code>PYTHON_CONFIGURE_OPTS=--enable-shared</code>) or the distribution's
<code>libpython3.X</code> package. If none is found, fmi2Instantiate fails with a
message saying so. The older recipe (<code>LD_PRELOAD</code> of libpython plus
<code>PYTHONPATH</code>) still works.</li>
<li>All pythonfmu FMUs of one process share one interpreter: load FMUs of one gyrodiag
build together (they share the module <code>gd_fmu_base</code>) and run long campaigns
in separate processes.</li>
<li><b>Errors</b>: a bad parameter (named, with its range), a refused step or an
unexpected problem is logged through the FMU logger and the call returns fmi2Error, never
fmi2Fatal; the instance keeps its state. Messages of status warning and error reach the
logger whatever the debug-logging setting. Wrong calls from a host are refused the same
way before any Python runs (Linux): a get/set of an unknown value reference or through
the accessor of another type (the message names the value reference and its type), a set
of a fixed parameter or an output after initialisation, a call in the wrong state, NULL
arrays; fmi2Terminate and fmi2FreeInstance work after any error.</li>
<li><b>Time events</b> (fault windows, manoeuvres) are compared within half a
communication step: a master that adds h each step sees them at the same step as one
that computes k&middot;h.</li>
<li><b>FMU states</b>: get/set/serialize hold every internal filter state, covariance and
window. Serialized states are framed (<code>GDFMUST1</code>, the FMU's GUID, length,
FNV-1a 64 checksum): truncated, corrupt or foreign bytes, and states of other FMUs, give
fmi2Error naming the problem and leave the instance unchanged.</li>
<li><b>Speed</b>: per-sample kernels are compiled
(<code>resources/gyrodiag/common/_ckernels.abi3.so</code>,
Linux x86-64, any CPython &ge; 3.11, any numpy; no JIT, no cache folder, nothing written
at run time). Where it does not load (another platform or Python) the FMU runs the same
kernels in plain Python, with the same outputs to 1e-12, slower; the environment
variable <code>GYRODIAG_KERNELS=python</code> forces that fallback.</li>
</ul>
"""


def documentation_html(model_description: bytes, module_doc: str) -> bytes:
    """documentation/index.html: the script's docstring, usage notes, variable table."""
    import html

    root = ET.fromstring(model_description)
    rows = []
    for sv in root.find("ModelVariables"):
        t = sv[0]
        cells = [
            sv.get("name"), t.tag, sv.get("causality", "local"), sv.get("variability", ""),
            t.get("unit", ""), t.get("start", ""), t.get("min", ""), t.get("max", ""),
            sv.get("description", ""),
        ]
        rows.append("<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in cells) + "</tr>")
    head = ("name", "type", "causality", "variability", "unit", "start", "min", "max",
            "description")
    name = html.escape(root.get("modelName", "FMU"))
    doc = html.escape(module_doc.strip() or root.get("description", ""))
    page = f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>{name}</title>
<style>body{{font-family:sans-serif;max-width:70em;margin:auto}}
table{{border-collapse:collapse;font-size:90%}}td,th{{border:1px solid #ccc;padding:2px 6px}}
pre{{white-space:pre-wrap}}</style></head><body>
<h1>{name}</h1>
<p>{html.escape(root.get("description", ""))}</p>
<pre>{doc}</pre>
{HOST_NOTES}
<h2>Variables</h2>
<table><tr>{"".join(f"<th>{h}</th>" for h in head)}</tr>
{chr(10).join(rows)}
</table></body></html>
"""
    return page.encode("utf-8")


def _bytecode(fmu: zipfile.ZipFile, extra: dict[str, bytes] | None = None) -> dict[str, bytes]:
    """Hash-checked bytecode of every Python file under resources/ (archive name of the
    .pyc → its bytes), for the Python that builds the FMU; ``extra`` (archive name →
    source) adds files or replaces the archive's.

    pythonfmu imports the model and its packages from the unzipped resources, which a
    host unzips afresh (mtimes lost) and may not be allowed to write into (or runs with
    PYTHONDONTWRITEBYTECODE): then every instance compiled every module from source,
    0.07 s per instance here. A CHECKED_HASH pyc is valid whatever the file times, is
    checked against the source it sits beside, and is ignored by any other Python
    version (its file name carries the interpreter's cache tag).
    """
    out: dict[str, bytes] = {}
    with tempfile.TemporaryDirectory(prefix="gyrodiag-pyc-") as tmp:
        extra = extra or {}
        for name in sorted({*fmu.namelist(), *extra}):
            if not (name.startswith("resources/") and name.endswith(".py")):
                continue
            source = Path(tmp) / "module.py"
            source.write_bytes(extra[name] if name in extra else fmu.read(name))
            target = Path(tmp) / "module.pyc"
            py_compile.compile(str(source), cfile=str(target), dfile=name, doraise=True,
                               invalidation_mode=py_compile.PycInvalidationMode.CHECKED_HASH)
            out[importlib.util.cache_from_source(name)] = target.read_bytes()
    return out


def rewrite_fmu(
    fmu: Path, model_description: bytes, requirements: list[str], model_identifier: str,
    shim: Path | None, documentation: bytes | None = None,
    kernels: dict[str, Path] | None = None, entry: tuple[str, str] | None = None,
) -> None:
    """Replace modelDescription.xml, add resources/requirements.txt and the
    documentation, wrap the Linux binary with the status shim, put the compiled
    kernels and generated resources ``kernels`` (archive name → file) in place of any
    extension modules the builder copied from the source tree (those are for whichever
    Python built them), and with ``entry`` (model module, class) make the stub of
    :data:`ENTRY_TEMPLATE` pythonfmu's entry module. Only the Linux binaries are shipped:
    pythonfmu's win64 DLL has no status shim and has never run here (docs/fmu.md,
    "Platforms")."""
    linux_binary = f"binaries/linux64/{model_identifier}.so"
    kernels = kernels or {}
    generated: dict[str, bytes] = {}
    if entry is not None:
        stub = entry_module_name(entry[0])
        generated[f"resources/{stub}.py"] = ENTRY_TEMPLATE.format(
            module=entry[0], cls=entry[1]).encode()
        generated["resources/slavemodule.txt"] = stub.encode()
    buffer = io.BytesIO()
    with zipfile.ZipFile(fmu) as src, zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED) as dst:
        names = set(src.namelist())
        # before the copy: writestr(info) moves the shared ZipInfo's offsets to dst's
        bytecode = _bytecode(src, generated)
        for info in src.infolist():
            if info.filename in ("modelDescription.xml", "resources/requirements.txt",
                                 "documentation/index.html", *generated):
                continue
            if shim is not None and info.filename == linux_binary:
                continue
            if info.filename.startswith("binaries/") and not info.filename.startswith(
                    "binaries/linux64/"):
                continue  # pythonfmu's win64 DLL: no status shim, never run here
            if info.filename in kernels:  # a copy the builder found in the source tree
                continue
            if info.filename.startswith("resources/") and (
                info.filename.endswith((".so", ".pyc")) or "__pycache__/" in info.filename
            ):
                continue
            dst.writestr(info, src.read(info.filename))
        for name, path in kernels.items():
            dst.writestr(name, path.read_bytes())
        for name, data in [*bytecode.items(), *generated.items()]:
            dst.writestr(name, data)
        dst.writestr("modelDescription.xml", model_description)
        dst.writestr("resources/requirements.txt", "\n".join(requirements) + "\n")
        if documentation is not None:
            dst.writestr("documentation/index.html", documentation)
        if shim is not None:
            if linux_binary not in names:
                raise ValueError(f"{fmu.name} has no {linux_binary} to wrap")
            dst.writestr(f"binaries/linux64/{SHIM_INNER_NAME}", src.read(linux_binary))
            dst.writestr(linux_binary, shim.read_bytes())
    fmu.write_bytes(buffer.getvalue())


def generate_resources(name: str, work_dir: Path) -> dict[str, Path]:
    """Write the :data:`GENERATED_RESOURCES` of FMU ``name`` into ``work_dir``.

    Returns
    -------
    dict
        Archive name (``resources/...``) -> generated file.

    Raises
    ------
    RuntimeError
        Naming the resource and the command when a generator fails.
    """
    out: dict[str, Path] = {}
    for archive, script, args in GENERATED_RESOURCES.get(name, []):
        target = work_dir / archive
        target.parent.mkdir(parents=True, exist_ok=True)
        cmd = [sys.executable, str(ROOT / script), *args, "--out", str(target)]
        proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=600)
        if proc.returncode != 0 or not target.is_file():
            raise RuntimeError(f"{name}: generating resources/{archive} failed "
                               f"({' '.join(cmd)}): {proc.stderr.strip()}")
        out[f"resources/{archive}"] = target
    return out


def build_one(name: str, out_dir: Path) -> Path:
    """Build and post-process one FMU (run this in a fresh process)."""
    from pythonfmu import FmuBuilder

    entry = next(e for e in REGISTRY if e[0] == name)
    script = script_path(entry)
    # the builder imports the script, which imports the facade base shipped beside it
    sys.path.insert(0, str(FACADE_BASE.parent))
    out_dir.mkdir(parents=True, exist_ok=True)
    tmp_fmu = out_dir / f".{name}.building.fmu"
    built = FmuBuilder.build_FMU(
        script,
        dest=tmp_fmu,
        project_files=project_files(entry),
        canGetAndSetFMUstate=True,
        canSerializeFMUstate=True,
    )
    module = importlib.import_module(script.stem)  # already imported by the builder
    with zipfile.ZipFile(built) as zf:
        xml_bytes = zf.read("modelDescription.xml")
    model_name = ET.fromstring(xml_bytes).get("modelName")
    if model_name != name:
        raise ValueError(f"{script.name} defines model {model_name!r}, registry expects {name!r}")
    fixed, notes = postprocess_model_description(
        xml_bytes,
        getattr(module, "VARIABLE_META", {}),
        getattr(module, "OUTPUT_DEPENDENCIES", {}),
    )
    for note in notes:
        print(f"[build_fmu] {name}: note: {note}")
    shim = compile_status_shim(out_dir / ".shim" / name)
    kernels: dict[str, Path] = {}
    with zipfile.ZipFile(built) as zf:
        c_sources = [n for n in zf.namelist()
                     if n.startswith("resources/") and n.endswith("/_ckernels.c")]
    for c_name in c_sources:
        package = c_name[len("resources/"):-len("/_ckernels.c")]
        compiled = compile_kernels(script.parent / package / "_ckernels.c",
                                   out_dir / ".kernels" / name / package)
        if compiled is not None:
            kernels[f"resources/{package}/_ckernels.abi3.so"] = compiled
    # generated data files travel with the kernels (archive name -> file)
    kernels.update(generate_resources(name, out_dir / ".resources" / name))
    if not isinstance(getattr(module, model_name, None), type):
        raise ValueError(f"{script.name} has no class {model_name!r} (the model name)")
    rewrite_fmu(built, fixed, list(getattr(module, "REQUIREMENTS", DEFAULT_REQUIREMENTS)),
                model_name, shim, documentation_html(fixed, module.__doc__ or ""), kernels,
                entry=(script.stem, model_name))
    final = out_dir / f"{name}.fmu"
    built.replace(final)
    return final


def validate(fmu: Path) -> list[str]:
    from fmpy.validation import validate_fmu

    return list(validate_fmu(str(fmu)))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("names", nargs="*", help="FMUs to build (default: all available)")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help="output directory")
    parser.add_argument("--_one", dest="one", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    out_dir = args.out.resolve()

    if args.one:
        path = build_one(args.one, out_dir)
        print(f"[build_fmu] built {path}")
        return 0

    known = [e[0] for e in REGISTRY]
    unknown = [n for n in args.names if n not in known]
    if unknown:
        parser.error(f"unknown FMU name(s) {unknown}; known: {known}")
    selected = [e for e in REGISTRY if not args.names or e[0] in args.names]

    failed: list[str] = []
    built: list[Path] = []
    for entry in selected:
        name = entry[0]
        if not available(entry):
            print(f"[build_fmu] SKIP {name}: {script_path(entry)} does not exist (yet)")
            continue
        t0 = time.perf_counter()
        proc = subprocess.run(
            [sys.executable, str(Path(__file__).resolve()), "--_one", name, "--out", str(out_dir)],
            cwd=ROOT, capture_output=True, text=True, timeout=600,
        )
        sys.stdout.write(proc.stdout)
        if proc.returncode != 0:
            sys.stderr.write(proc.stderr)
            print(f"[build_fmu] FAILED to build {name} (exit {proc.returncode})")
            failed.append(name)
            continue
        print(f"[build_fmu] {name}: built in {time.perf_counter() - t0:.1f} s")
        built.append(out_dir / f"{name}.fmu")

    for fmu in built:
        problems = validate(fmu)
        if problems:
            failed.append(fmu.stem)
            print(f"[build_fmu] {fmu.name}: fmpy validation reports {len(problems)} problem(s):")
            for p in problems:
                print(f"    - {p}")
        else:
            print(f"[build_fmu] {fmu.name}: fmpy validation OK")

    if failed:
        print(f"[build_fmu] FAILED: {sorted(set(failed))}")
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
