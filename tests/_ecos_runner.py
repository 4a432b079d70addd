"""The exported aircraft SSP in Ecos and the same scenario in the harness, in a fresh process.

``python _ecos_runner.py FMU_DIR OUT_DIR`` exports the aircraft seed scenario (coupling
forced to Jacobi, every output recorded) as ``OUT_DIR/aircraft.ssp``, runs it

* with the harness's fmpy master (``OUT_DIR/aircraft-harness/``);
* with Ecos (ecospy) from the SSP, naming the export's parameter set at initialisation
  (``OUT_DIR/aircraft-ecos/``), the way an Ecos user runs ``--parameterSet``,

* with Ecos from the same SSP naming no parameter set (``OUT_DIR/aircraft-ecos-unnamed/``,
  a few signals: what an Ecos user gets without ``--parameterSet``),

and writes ``OUT_DIR/aircraft.types.json`` (the FMI type of every recorded signal) and
``OUT_DIR/aircraft.ecos.json`` (Ecos's version and its clock at the end).

Ecos couples by Jacobi (every instance steps on the values transferred after the step
before), reads its outputs after initialisation (row 0 is known, unlike libcosim's) and
adds h to t at every step (its clock drifts by rounding; the rows are timed k·h here).
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _libcosim_runner import ROOT, _aircraft

if TYPE_CHECKING:
    from gyrodiag_harness import RunResult

ECOS_SEPARATOR = "::"  # Ecos names a variable "instance::variable"
#: Recorded in the run that names no parameter set.
UNNAMED_SIGNALS = ("aircraft.y_q", "aircraft.x_q", "injector.out_3", "diag.df.calibrating")


def _getter(sim: Any, kind: str) -> Any:
    """The ecospy accessor of an FMI type."""
    if kind == "Real":
        return sim.get_real
    if kind in ("Integer", "Enumeration"):
        return sim.get_integer
    if kind == "Boolean":
        return sim.get_bool
    raise TypeError(f"no Ecos accessor for FMI type {kind!r}")


def run_ecos(ssp: Path, types: dict[str, str], duration_s: float, step_s: float,
             parameter_set: str | None) -> tuple[RunResult, dict[str, Any]]:
    """Run ``ssp`` in Ecos, reading ``types`` (name → FMI type) after init and every step."""
    import numpy as np
    from ecospy import EcosLib, EcosSimulation

    from gyrodiag_harness import RunResult

    getters = []
    n_steps = round(duration_s / step_s)
    rows: list[list[float]] = []
    wall0 = time.perf_counter()
    with EcosSimulation(step_size=step_s, ssp_path=str(ssp)) as sim:
        sim.init(parameter_set=parameter_set)
        for name, kind in types.items():
            inst, var = name.split(".", 1)
            getters.append((_getter(sim, kind), f"{inst}{ECOS_SEPARATOR}{var}"))

        def row() -> list[float]:
            return [float(get(ident)) for get, ident in getters]

        rows.append(row())
        for _ in range(n_steps):
            sim.step()
            rows.append(row())
        clock = sim.get_time()
        sim.terminate()
    table = np.array(rows, dtype=float)
    result = RunResult(scenario=ssp.stem, time=step_s * np.arange(n_steps + 1),
                       signals={q: table[:, j].copy() for j, q in enumerate(types)},
                       step_s=step_s, wall_time_s=time.perf_counter() - wall0,
                       stop_time_s=n_steps * step_s)
    return result, {"version": str(EcosLib().version()), "clock_s": clock,
                    "clock_error_s": clock - n_steps * step_s,
                    "wall_s": result.wall_time_s, "finite": bool(np.isfinite(table).all()),
                    "rows": len(rows)}


def main(fmu_dir: Path, out_dir: Path) -> None:
    from fmpy import read_model_description

    from gyrodiag_harness import run_scenario
    from gyrodiag_harness.cosim.scenario import parse_scenario
    from gyrodiag_harness.cosim.ssp import PARAMETER_SET, export_ssp

    data = _aircraft()
    data["coupling"] = "jacobi"
    data.pop("record", None)  # record every output
    scenario = parse_scenario(data, source="aircraft", default_name="aircraft",
                              path=ROOT / "scenarios" / "aircraft.toml")
    harness = run_scenario(scenario, fmu_dir=fmu_dir, progress=False)
    harness.save(out_dir / "aircraft-harness", precision="float64")
    types = {}
    for inst, spec in scenario.fmus.items():
        md = read_model_description(str(fmu_dir / f"{spec.fmu}.fmu"))
        types.update({f"{inst}.{v.name}": v.type for v in md.modelVariables})
    types = {n: types[n] for n in harness.signals}
    (out_dir / "aircraft.types.json").write_text(json.dumps(types), encoding="utf-8")
    ssp = out_dir / "aircraft.ssp"
    export_ssp(scenario, ssp, fmu_dir=fmu_dir)
    ecos, facts = run_ecos(ssp, types, scenario.duration_s, scenario.step_s, PARAMETER_SET)
    ecos.save(out_dir / "aircraft-ecos", precision="float64")
    unnamed, _ = run_ecos(ssp, {n: types[n] for n in UNNAMED_SIGNALS}, scenario.duration_s,
                          scenario.step_s, None)
    unnamed.save(out_dir / "aircraft-ecos-unnamed", precision="float64")
    (out_dir / "aircraft.ecos.json").write_text(json.dumps(facts), encoding="utf-8")


if __name__ == "__main__":
    main(Path(sys.argv[1]), Path(sys.argv[2]))
