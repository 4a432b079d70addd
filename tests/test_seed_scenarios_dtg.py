"""DTG and system seed scenarios.

The suite collects ``scenarios/`` with the gyrodiag pytest plugin (ini ``gyrodiag =
true``): each seed scenario is a test item checked against its ``[[expect]]`` tables.
The tests here take the same runs from the session's run cache (fixture
``gyrodiag_run``: each scenario runs once per session, in a worker process of its own,
docs/methods.md §6.11, whoever asks first, also across xdist workers):

* the DTG fault scenarios (8 runs, seeds 11-12) load the signature library through
  ``files = { "dtg.signature_file" = "${out}/dtg_signatures.json" }``, which the plugin
  learns once per session from ``scenarios/training`` (12 training runs, seeds 101-103);
  ``learn-signatures --saved`` on the same training runs must write the same library;
* the nominal and physical-fault scenarios;
* the system scenarios: the spin scenario and its fault-free control.

The tests assert that every expectation holds and key figures read back from the runs:
the paper's θ pattern, the learned signatures and classification codes, detection
delays, the physical faults' η and the system scenario's two witnesses.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from gyrodiag_harness.campaigns.signatures import check_training_scenarios
from gyrodiag_harness.cosim.results import RunResult
from gyrodiag_harness.cosim.scenario import ScenarioError, load_scenario, parse_scenario
from gyrodiag_harness.verification.metrics import detection_delay_s

ROOT = Path(__file__).resolve().parents[1]
SCEN = ROOT / "scenarios"
FAULTS = {"utx_step": 1, "utx_noise": 2, "utx_loss": 3, "ux_drift": 4}
FAULT_T = 6.0
GROUP_B = ["dtg_nominal.toml", "dtg_physical_spin_slowdown.toml",
           "dtg_physical_torquer_scale.toml"]
SYSTEM = ["system_pitch_gyro_spin", "system_pitch_gyro_nominal"]
#: Batch-LS θ of the independent paper-rotor reference (dither 1 V, pick-off noise 1 mV,
#: 50 Hz prefilter; mean of 8 seeds) and its combinations d = θ1 − 2θ2, s = 1 − θ1 + θ2.
REF_THETA = (2.00369, 1.00456, -0.030607, -0.029204, 2.0005e-4)
REF_D, REF_S = -5.435e-3, 8.711e-4


def _cmd(*args: str) -> list[str]:
    return [sys.executable, "-m", "gyrodiag_harness", *args]


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    return env


@pytest.fixture(scope="module")
def campaign(gyrodiag_run, gyrodiag_results: Path) -> dict:
    t0 = time.perf_counter()
    faults = sorted(SCEN.glob("dtg_fault_*.toml"))
    paths = [*faults, *(SCEN / f for f in GROUP_B)]
    runs = {p.stem: r for p, r in zip(paths, gyrodiag_run.many(paths), strict=True)}
    return {"runs": runs, "library": gyrodiag_results / "dtg_signatures.json",
            "training": gyrodiag_results / "training", "faults": faults,
            "wall_s": time.perf_counter() - t0}


def _load(campaign: dict, name: str) -> RunResult:
    return campaign["runs"][name]


# ----------------------------------------------------------------- signature learning
def test_learn_signatures_writes_a_library_in_code_order(campaign, tmp_path):
    lib = json.loads(campaign["library"].read_text())
    # the command line learns the same library from the same (saved) training runs
    again = tmp_path / "dtg_signatures.json"
    proc = subprocess.run(_cmd("learn-signatures", str(SCEN / "training"), "--saved",
                               "--runs-out", str(campaign["training"]), "--out", str(again)),
                          cwd=ROOT, env=_env(), capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    assert json.loads(again.read_text())["signatures"] == lib["signatures"]
    assert list(lib["signatures"]) == list(FAULTS)
    assert lib["codes"] == FAULTS
    sig = {k: np.array(v) for k, v in lib["signatures"].items()}
    # physics of the features: θ1, θ2 stay (the dither identifies the rotor's own
    # dynamics); a fault on the x pick-off collapses the y axis' cross terms θ3, θ4;
    # a drift on Ux is an input the rotor does not follow: only θ5 falls
    for name, c in sig.items():
        assert c[0] == 0 and c[1] == 0, (name, c)
    for name in ("utx_step", "utx_noise", "utx_loss"):
        assert sig[name][2] < 0 and sig[name][3] < 0, (name, sig[name])
    assert sig["ux_drift"][:4].tolist() == [0, 0, 0, 0] and sig["ux_drift"][4] < 0
    # stronger corruption of Utx, deeper collapse: noise (1 V) < step (1 V) < loss (0.01 V)
    assert sig["utx_noise"][2] < sig["utx_step"][2] < sig["utx_loss"][2]
    # every class is distinct, and every training run is nearest to its own class
    names = list(sig)
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            assert np.mean(np.abs(sig[a] - sig[b])) >= 0.4, (a, b)
    for run in lib["runs"]:
        d = {n: np.mean(np.abs(np.array(run["feature"]) - c)) for n, c in sig.items()}
        assert min(d, key=d.get) == run["signature"], run


def test_fault_scenarios_detect_and_classify(campaign):
    delays = {}
    for name, code in FAULTS.items():
        for seed in ("s1", "s2"):
            r = _load(campaign, f"dtg_fault_{name}_{seed}")
            alarm = r.signal("diag.dtg.alarm")
            assert not np.any(alarm[r.time < FAULT_T] > 0.5)
            delays[name, seed] = detection_delay_s(r.time, alarm, FAULT_T)
            assert r.signal("diag.dtg.fault_code")[-1] == code, (name, seed)
    # pick-off step and noise are seen at once; the lost signal and the drift need the
    # estimator to move (loss: ~0.1-0.3 s; drift: the ramp must first grow, ~0.7 s)
    for seed in ("s1", "s2"):
        assert delays["utx_step", seed] < 0.05
        assert delays["utx_noise", seed] < 0.05
        assert delays["utx_loss", seed] < 1.0
        assert 0.3 < delays["ux_drift", seed] < 1.2


# ----------------------------------------------------------------- nominal and physical
def test_nominal_theta_pattern_of_the_paper(campaign):
    r = _load(campaign, "dtg_nominal")
    half = r.time >= 30.0
    for axis in "xy":
        th = np.array([r.signal(f"diag.dtg.theta_{axis}[{i}]")[half].mean()
                       for i in range(1, 6)])
        # against the independent reference of the paper's rotor (tests/test_dtg_fmu.py
        # _reference_closed_loop, same dither and noise, 8 seeds), within 4 σ of the
        # spread of a 30 s mean (docs/notes.md "θ spread"): c = 0 moves d by 3e-3, k = 0
        # moves s by 8e-4, a tripled c moves d by 6e-3
        assert th[0] - 2 * th[1] == pytest.approx(REF_D, abs=1.2e-3)
        assert 1 - th[0] + th[1] == pytest.approx(REF_S, abs=4e-5)
        assert th[2] == pytest.approx(REF_THETA[2], abs=1.6e-3)
        assert th[3] == pytest.approx(REF_THETA[3], abs=1.6e-3)
        assert th[4] == pytest.approx(REF_THETA[4], abs=6e-6)
        assert 50 < abs(th[2]) / th[4] < 500  # "two orders of magnitude below"
    assert not np.any(r.signal("diag.dtg.alarm") > 0.5)
    assert not np.any(r.signal("diag_fine.dtg.alarm") > 0.5)


def test_fine_band_lies_beyond_the_nominal_spread(campaign):
    r = _load(campaign, "dtg_nominal")
    after = r.time >= 10.0
    eta = np.array([[r.signal(f"diag_fine.dtg.eta_{a}[{i}]")[after] for i in (3, 4)]
                    for a in "xy"])
    sigma = eta.std(axis=-1).max()
    # band 0.93/1.07 = 1 ± 4σ of the largest nominal η std (θ3, θ4), and a 10 % spin
    # change (η 0.90) lies beyond it
    assert 0.005 < sigma < 0.0175
    assert eta.min() > 0.93 and eta.max() < 1.07


def test_physical_faults_detected_in_the_fine_band_only(campaign):
    spin = _load(campaign, "dtg_physical_spin_slowdown")
    t = spin.time
    d_spin = detection_delay_s(t, spin.signal("diag_fine.dtg.alarm"), 12.0)
    assert 0.0 < d_spin < 8.0
    late = t >= 20.0
    for a in "xy":
        for i in (3, 4):  # L and λ scale with the spin: θ3, θ4 fall by 10 %
            assert spin.signal(f"diag_fine.dtg.eta_{a}[{i}]")[late].mean() == \
                pytest.approx(0.9, abs=0.02)
    assert not np.any(spin.signal("diag.dtg.alarm") > 0.5)  # paper band: blind
    assert spin.signal("diag.dtg.eta_x[3]")[late].mean() == pytest.approx(0.9, abs=0.03)
    torq = _load(campaign, "dtg_physical_torquer_scale")
    d_torq = detection_delay_s(torq.time, torq.signal("diag_fine.dtg.alarm"), 12.0)
    assert 0.0 < d_torq < 5.0
    eta5 = torq.signal("diag_fine.dtg.eta_x[5]")[torq.time >= 20.0].mean()
    assert eta5 == pytest.approx(0.8, abs=0.05)  # θ5 ∝ Ku


# ----------------------------------------------------------------- system (docs/methods.md §5)
@pytest.fixture(scope="module")
def system_runs(gyrodiag_run) -> dict:
    """Spin scenario and its fault-free control, from the session's run cache."""
    t0 = time.perf_counter()
    runs = dict(zip(SYSTEM, gyrodiag_run.many([SCEN / f"{n}.toml" for n in SYSTEM]),
                    strict=True))
    return {"runs": runs, "wall_s": time.perf_counter() - t0}


def _system(runs: dict, name: str) -> RunResult:
    return runs["runs"][name]


def _theta34(r: RunResult, t0: float, t1: float) -> np.ndarray:
    m = (r.time >= t0) & (r.time < t1)
    return np.array([r.signal(f"diag_fine.dtg.theta_{a}[{i}]")[m].mean()
                     for a in "xy" for i in (3, 4)])


def _eta_range(r: RunResult, t0: float, t1: float) -> tuple[float, float]:
    m = (r.time >= t0) & (r.time < t1)
    eta = np.array([r.signal(f"diag_fine.dtg.eta_{a}[{i}]")[m]
                    for a in "xy" for i in range(1, 6)])
    return float(eta.min()), float(eta.max())


def test_system_gyro_in_the_loop_reads_the_pitch_rate(system_runs):
    for name in SYSTEM:
        r = _system(system_runs, name)
        level = (r.time >= 2.0) & (r.time < 20.0)
        err = (r.signal("dtg.omega_y_read") - r.signal("aircraft.x_q"))[level]
        # the read-out noise is the 1 V torquer dither seen through Ku/L (151 V per
        # rad/s): 1/151 = 6.6e-3 rad/s per sample, the pick-off noise adds little
        assert 5e-3 < np.sqrt(np.mean(err**2)) < 8e-3
        # with the controller at 1 kHz and 1e-4 rad attitude sensors, level flight is
        # calm: the case rate the DTG regression does not model stays ~1e-4 rad/s
        assert r.signal("aircraft.x_q")[level].std() < 1e-3


def test_system_dtg_channel_witness(system_runs):
    spin = _system(system_runs, "system_pitch_gyro_spin")
    ctrl = _system(system_runs, "system_pitch_gyro_nominal")
    t = spin.time
    alarm_s, alarm_c = spin.signal("diag_fine.dtg.alarm"), ctrl.signal("diag_fine.dtg.alarm")
    # the same seeds: both runs are identical up to the fault
    np.testing.assert_array_equal(spin.signal("diag_fine.dtg.eta_x[3]")[t < 20.0],
                                  ctrl.signal("diag_fine.dtg.eta_x[3]")[t < 20.0])
    assert not np.any(alarm_s[t < 20.0] > 0.5)
    assert not np.any(alarm_c[t < 28.0] > 0.5)  # control: quiet all through level flight
    lo, hi = _eta_range(ctrl, 10.0, 28.0)
    assert 0.93 < lo and hi < 1.07, (lo, hi)
    delay = detection_delay_s(t, alarm_s, 20.0)
    assert 0.5 < delay < 8.0  # forgetting 0.9998: ~5 s memory
    # L and λ scale with the spin: θ3, θ4 of both axes fall against the control run
    # (not yet the full 0.9 with a 5 s memory, 6-8 s after the step)
    ratio = _theta34(spin, 26.0, 28.0) / _theta34(ctrl, 26.0, 28.0)
    assert np.all((ratio > 0.88) & (ratio < 0.96)), ratio


@pytest.mark.xfail(strict=True, reason="known limitation: DTG channel alarms once the pilot "
                   "manoeuvres in the fault-free paper-configuration run (unmodelled case "
                   "rate; issues 32, 34)")
def test_system_dtg_channel_quiet_in_fault_free_manoeuvres(system_runs):
    ctrl = _system(system_runs, "system_pitch_gyro_nominal")
    assert not np.any(ctrl.signal("diag_fine.dtg.alarm") > 0.5)


def test_system_detection_filter_witness(system_runs):
    spin = _system(system_runs, "system_pitch_gyro_spin")
    t = spin.time
    det = spin.signal("diag_df.df.detected")
    # a q gain error is invisible at q ~ 0: quiet in level flight, also after the spin
    # fault; the spin fault scales the gyro's read-out (sensor 3, q) from the manoeuvre on
    assert not np.any(det[t < 28.0] > 0.5)
    assert detection_delay_s(t, det, 28.0) < 0.5
    assert spin.signal("diag_df.df.isolated_sensor")[-1] == 3
    assert spin.signal("diag_df.df.fault_type")[-1] == 2
    assert spin.signal("diag_df.df.fault_magnitude")[-1] < 0.95


@pytest.mark.xfail(strict=True, reason="known limitation: the paper rule types the paper "
                   "rotor's read-out lag as a q gain of ~0.85 in fault-free manoeuvres "
                   "(issue 33)")
def test_system_detection_filter_quiet_in_fault_free_manoeuvres(system_runs):
    ctrl = _system(system_runs, "system_pitch_gyro_nominal")
    assert not np.any(ctrl.signal("diag_df.df.detected") > 0.5)


@pytest.mark.xfail(strict=True, reason="known limitation: the spin fault's q gain is typed "
                   "with the read-out lag on top (~0.77 for a true 0.9; issue 33)")
def test_system_detection_filter_types_the_spin_fault_gain(system_runs):
    spin = _system(system_runs, "system_pitch_gyro_spin")
    assert spin.signal("diag_df.df.fault_magnitude")[-1] == pytest.approx(0.9, abs=0.03)


# ----------------------------------------------------------------- fast checks
def test_training_set_codes_are_one_to_n():
    scenarios = [load_scenario(p) for p in sorted((SCEN / "training").glob("*.toml"))]
    assert check_training_scenarios(scenarios) == FAULTS
    bad = parse_scenario({**_minimal(), "training": {"signature": "a", "code": 2}},
                         source="gap.toml")
    with pytest.raises(ScenarioError, match=r"training\.code: codes of the classes must be 1\.\.1"):
        check_training_scenarios([bad])


def test_file_parameter_errors_name_the_key(tmp_path):
    from gyrodiag_harness.cosim.scenario import resolve_file_parameters

    data = _minimal()
    data["fmus"]["diag"]["files"] = {"dtg.signature_file": "${out}/lib.json"}
    s = parse_scenario(data, source="f.toml")
    with pytest.raises(ScenarioError, match=r"fmus.diag.files.dtg.signature_file: .*results "
                                            r"folder, but none"):
        resolve_file_parameters(s)
    with pytest.raises(ScenarioError, match=r"lib\.json not found in "):
        resolve_file_parameters(s, tmp_path)
    (tmp_path / "lib.json").write_text("{}")
    got = resolve_file_parameters(s, tmp_path)
    assert got == {"diag": {"dtg.signature_file": str((tmp_path / "lib.json").resolve())}}
    data["fmus"]["diag"]["files"] = {"dtg.signature_file": "${results}/x.json"}
    with pytest.raises(ScenarioError, match="only placeholder"):
        parse_scenario(data, source="f.toml")
    data["fmus"]["diag"]["files"] = {"dtg.signature_file": "a.json"}
    data["fmus"]["diag"]["parameters"] = {"dtg.signature_file": "b.json"}
    with pytest.raises(ScenarioError, match="set it in one place only"):
        parse_scenario(data, source="f.toml")


def _minimal() -> dict:
    return {"name": "m", "duration_s": 1.0, "step_s": 0.001,
            "fmus": {"diag": {"fmu": "Diagnoser"}}}
