"""The aircraft chain as one container FMU (fmucontainer) in fmpy, and in the harness.

``python _container_runner.py FMU_DIR OUT_DIR`` takes the aircraft seed scenario
(scenarios/aircraft_q_bias.toml as shipped: Gauss-Seidel, order aircraft, injector,
controller, diag; every output recorded) and

* runs it with the harness (``OUT_DIR/aircraft-harness/``);
* writes the fmucontainer description ``OUT_DIR/container/aircraft_chain.json``: the four
  FMUs in the harness's stepping order, the scenario's connections as links, the
  parameters the harness sets (the scenario's, the injector fault's, the sample
  alignment's) as start values, every recorded signal as a container output named
  ``rec.instance.variable``; fmucontainer in sequential mode (each FMU steps on the outputs
  its predecessors just produced: the harness's Gauss-Seidel) at the scenario's step;
* simulates ``OUT_DIR/container/aircraft_chain.fmu`` with fmpy (``OUT_DIR/aircraft-container/``),
  its outputs read at every step from t = 0;

and writes ``OUT_DIR/aircraft.types.json`` (FMI type of every recorded signal) and
``OUT_DIR/container.log`` (fmucontainer's output).
"""

from __future__ import annotations

import json
import math
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

if TYPE_CHECKING:
    from gyrodiag_harness import RunResult

SCENARIO = ROOT / "scenarios" / "aircraft_q_bias.toml"
CONTAINER = "aircraft_chain"
#: Prefix of the container's outputs: fmucontainer names its link variables
#: ``<fmu file stem, lower case>.<port>`` ("aircraft.y_v"), which the plain names would repeat.
OUTPUT_PREFIX = "rec."


def _start_value(kind: str, value: Any) -> Any:
    """A start value as fmucontainer's JSON takes it (it checks it against the port type)."""
    if kind == "Boolean":
        return bool(value)
    if kind in ("Integer", "Enumeration"):
        return str(int(value))
    x = float(value)
    return repr(x) if math.isfinite(x) else ("inf" if x > 0 else "-inf")


def container_description(scenario: Any, fmu_dir: Path, record: list[str]) -> dict[str, Any]:
    """fmucontainer's JSON for ``scenario``: FMUs in stepping order, links, start values
    (what the harness sets before initialisation), ``record`` as outputs."""
    from fmpy import read_model_description

    from gyrodiag_harness.cosim.master import model_info, plan_coupling
    from gyrodiag_harness.cosim.scenario import split_name
    from gyrodiag_harness.cosim.timing import fill_timing_parameters

    files = {n: f"{i.fmu}.fmu" for n, i in scenario.fmus.items()}
    if len(set(files.values())) != len(files):
        raise ValueError(f"{scenario.name}: an FMU used by two instances ({files}); this "
                         "description names embedded FMUs by file")
    info = {n: model_info(read_model_description(str(fmu_dir / f))) for n, f in files.items()}
    plan = plan_coupling(scenario)
    params: dict[str, dict[str, Any]] = {n: dict(i.parameters) for n, i in scenario.fmus.items()}
    for f in scenario.injector_faults:
        params[f.injector].update(f.injector_parameters())
    for m in scenario.manoeuvres:
        params[m.instance].update(m.instance_parameters())
    fill_timing_parameters(params, scenario, plan.delayed,
                           {n: i.variables for n, i in info.items()})
    links = []
    for c in scenario.connections:
        (si, sv), (di, dv) = split_name(c.from_), split_name(c.to)
        links.append([files[si], sv, files[di], dv])
    start = [[files[n], name, _start_value(info[n].variables[name].type, value)]
             for n in plan.order for name, value in params[n].items()]
    outputs = [[files[split_name(q)[0]], split_name(q)[1], OUTPUT_PREFIX + q] for q in record]
    return {"name": f"{CONTAINER}.fmu", "step_size": scenario.step_s, "sequential": True,
            "mt": False, "auto_link": False, "auto_input": False, "auto_output": False,
            "fmu": [files[n] for n in plan.order], "link": links, "start": start,
            "output": outputs}


def build_container(description: dict[str, Any], fmu_dir: Path, work: Path) -> Path:
    """Run ``fmucontainer`` on ``description`` in ``work`` (with copies of the FMUs)."""
    work.mkdir(parents=True, exist_ok=True)
    for name in description["fmu"]:
        shutil.copyfile(fmu_dir / name, work / name)
    spec = work / f"{CONTAINER}.json"
    spec.write_text(json.dumps(description, indent=1), encoding="utf-8")
    exe = Path(sys.executable).with_name("fmucontainer")
    proc = subprocess.run([str(exe), "-container", spec.name, "-fmu-directory", str(work)],
                          capture_output=True, text=True, cwd=work, timeout=600)
    (work.parent / "container.log").write_text(proc.stdout + proc.stderr, encoding="utf-8")
    out = work / f"{CONTAINER}.fmu"
    if proc.returncode != 0 or not out.is_file():
        raise RuntimeError(f"fmucontainer failed (exit {proc.returncode}):\n"
                           f"{(proc.stdout + proc.stderr)[-4000:]}")
    return out


def simulate_container(fmu: Path, record: list[str], duration_s: float,
                       step_s: float) -> RunResult:
    """fmpy ``simulate_fmu`` of the container, outputs at every step from t = 0."""
    import fmpy
    import numpy as np

    from gyrodiag_harness import RunResult

    wall0 = time.perf_counter()
    res = fmpy.simulate_fmu(str(fmu), stop_time=duration_s, step_size=step_s,
                            output_interval=step_s, output=[OUTPUT_PREFIX + q for q in record])
    return RunResult(scenario=CONTAINER, time=np.asarray(res["time"], dtype=float),
                     signals={q: np.asarray(res[OUTPUT_PREFIX + q], dtype=float)
                              for q in record},
                     step_s=step_s, wall_time_s=time.perf_counter() - wall0,
                     stop_time_s=duration_s)


def main(fmu_dir: Path, out_dir: Path) -> None:
    import tomllib

    from fmpy import read_model_description

    from gyrodiag_harness import run_scenario
    from gyrodiag_harness.cosim.scenario import parse_scenario

    data = tomllib.loads(SCENARIO.read_text(encoding="utf-8"))
    data.pop("record", None)  # record every output
    scenario = parse_scenario(data, source=str(SCENARIO), default_name=SCENARIO.stem,
                              path=SCENARIO)
    harness = run_scenario(scenario, fmu_dir=fmu_dir, progress=False)
    harness.save(out_dir / "aircraft-harness", precision="float64")
    record = list(harness.signals)
    types = {}
    for inst, spec in scenario.fmus.items():
        md = read_model_description(str(fmu_dir / f"{spec.fmu}.fmu"))
        types.update({f"{inst}.{v.name}": v.type for v in md.modelVariables})
    (out_dir / "aircraft.types.json").write_text(json.dumps({n: types[n] for n in record}),
                                                 encoding="utf-8")
    description = container_description(scenario, fmu_dir, record)
    fmu = build_container(description, fmu_dir, out_dir / "container")
    run = simulate_container(fmu, record, scenario.duration_s, scenario.step_s)
    run.save(out_dir / "aircraft-container", precision="float64")


if __name__ == "__main__":
    main(Path(sys.argv[1]), Path(sys.argv[2]))
