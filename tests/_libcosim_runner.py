"""The same scenarios through three masters, in a fresh process (docs/methods.md §6.11, §6.16).

``python _libcosim_runner.py FMU_DIR OUT_DIR`` runs every case of :data:`CASES`

* with the harness's fmpy master, coupling forced to Jacobi (``harness``);
* with libcosim from the scenario (``libcosim``, :mod:`gyrodiag_harness.cosim.libcosim`);
* with libcosim from the SSP that ``export-ssp`` writes (``ssp``; not for the case with a
  physical fault, which SSP cannot carry),

and saves ``OUT_DIR/<case>-<master>/`` (the harness's run format with every bit, since
the masters are compared to 1e-10), the SSP ``OUT_DIR/<case>.ssp`` with
``OUT_DIR/<case>.export.json`` (what the export reported), and
``OUT_DIR/<case>.types.json`` (the FMI type of every recorded signal).
"""

from __future__ import annotations

import json
import sys
import tomllib
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

#: DTG signatures used by the DTG case (the shipped scenario reads a learned library).
SIGNATURES = {"signatures": {"utx_step": [0, 0, -2, -2, 0], "utx_noise": [0, 0, -3, -3, 0],
                             "utx_loss": [0, 0, -1, -1, -1], "ux_drift": [0, 0, 0, 0, -1]}}


def _aircraft() -> dict[str, Any]:
    """The aircraft seed scenario as shipped (q-sensor bias 0.1 rad/s at 10 s)."""
    return tomllib.loads((ROOT / "scenarios" / "aircraft_q_bias.toml").read_text())


def _dtg() -> dict[str, Any]:
    """The DTG seed scenario dtg_fault_utx_step_s1, shortened: θ0 learned 0.3-1.2 s, the
    1 V Utx step at 1.6 s, 2.5 s in all."""
    data = tomllib.loads((ROOT / "scenarios" / "dtg_fault_utx_step_s1.toml").read_text())
    data["duration_s"] = 2.5
    data["fmus"]["diag"]["parameters"].update({"dtg.learn_start_s": 0.3,
                                              "dtg.learn_end_s": 1.2})
    data["faults"][0]["start_s"] = 1.6
    data["expect"] = [e for e in data["expect"] if e.get("kind") != "metric"]
    return data


def _hrg_physical() -> dict[str, Any]:
    """HRG output monitored by the grey channel; a physical fault (scale factor ×1.02,
    5-12 s) that only the scenario master can carry."""
    return {
        "name": "hrg_physical", "duration_s": 20.0, "step_s": 0.5,
        "fmus": {
            "hrg": {"fmu": "HRG", "parameters": {"profile": 2, "rate_const": 0.1,
                                                 "scale_factor": 10.0, "noise_std": 1e-3,
                                                 "seed": 5}},
            "diag": {"fmu": "Diagnoser", "parameters": {
                "sample_period_s": 0.5, "dtg.enabled": False, "df.enabled": False,
                "grey.decision": 0, "grey.window": 6, "grey.threshold": 0.01,
                "grey.clear_after_s": 3.0}},
        },
        "connections": [{"from": "hrg.voltage", "to": "diag.grey.y"}],
        "faults": [{"name": "scale", "set": "hrg.scale_factor", "value": 10.2,
                    "start_s": 5.0, "end_s": 12.0}],
    }


CASES = {"aircraft": _aircraft, "dtg": _dtg, "hrg_physical": _hrg_physical}


def main(fmu_dir: Path, out_dir: Path) -> None:
    from fmpy import read_model_description

    from gyrodiag_harness import run_scenario
    from gyrodiag_harness.cosim.libcosim import run_scenario_libcosim, run_ssp_libcosim
    from gyrodiag_harness.cosim.scenario import parse_scenario
    from gyrodiag_harness.cosim.ssp import export_ssp

    results = out_dir / "results"
    results.mkdir(parents=True, exist_ok=True)
    (results / "dtg_signatures.json").write_text(json.dumps(SIGNATURES), encoding="utf-8")
    for case, make in CASES.items():
        data = make()
        data["coupling"] = "jacobi"
        data.pop("record", None)  # record every output
        scenario = parse_scenario(data, source=case, default_name=case,
                                  path=ROOT / "scenarios" / f"{case}.toml")
        harness = run_scenario(scenario, fmu_dir=fmu_dir, progress=False,
                               results_dir=results)
        harness.save(out_dir / f"{case}-harness", precision="float64")
        names = list(harness.signals)
        types = {}
        for inst, spec in scenario.fmus.items():
            md = read_model_description(str(fmu_dir / f"{spec.fmu}.fmu"))
            types.update({f"{inst}.{v.name}": v.type for v in md.modelVariables})
        (out_dir / f"{case}.types.json").write_text(
            json.dumps({n: types[n] for n in names}), encoding="utf-8")
        lc = run_scenario_libcosim(scenario, fmu_dir=fmu_dir, results_dir=results)
        lc.save(out_dir / f"{case}-libcosim", precision="float64")
        if scenario.physical_faults:
            continue
        ssp_file = out_dir / f"{case}.ssp"
        done = export_ssp(scenario, ssp_file, fmu_dir=fmu_dir, results_dir=results)
        (out_dir / f"{case}.export.json").write_text(json.dumps(
            {"components": done.components, "parameters": done.parameters,
             "not_carried": done.not_carried}), encoding="utf-8")
        run_ssp_libcosim(ssp_file, names).save(out_dir / f"{case}-ssp", precision="float64")


if __name__ == "__main__":
    main(Path(sys.argv[1]), Path(sys.argv[2]))
