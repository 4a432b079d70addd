"""DTG.fmu acceptance tests (fmpy, fresh process; FMUs from the ``fmu_dir`` fixture).

* outputs equal an independent reference (solve_ivp of the rotor equations written in
  α, α' form, python-control's Tustin controller) to 1e-6, loop off and on, with a
  communication step that is not a multiple of the controller sample time;
* the paper's identified θ pattern on the nominal closed loop at 1 kHz (set 1), with the
  library's 6th-order 50 Hz Butterworth prefilter and batch least squares;
* a 10 % spin-motor slow-down switched on during the run moves θ3, θ4 by ≈ −10 %;
* the steady rebalance read-out equals a constant case rate to 1e-3 (both axes, both
  sets); loop stability and margins of both designs;
* FMU state save/restore (also serialised) reproduces the outputs bit for bit.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "models" / "dtg"))

import gd_dtg_sets as sets  # noqa: E402
from gd_dtg_loop import loop_margins  # noqa: E402

OUT = ["Utx", "Uty", "Ux", "Uy", "omega_x_read", "omega_y_read"]
T = 1e-3
IDENT_SECONDS = 10.0  # per half of the identification run
RATE_X, RATE_Y = 0.01, -0.02  # rad/s, read-out test


# ---------------------------------------------------------------------------------------
# scenario process
# ---------------------------------------------------------------------------------------

def _random_inputs(n: int, seed: int, rate_std: float, volt_std: float) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.column_stack([rate_std * rng.standard_normal((n, 2)),
                            volt_std * rng.standard_normal((n, 2))])


def _drive(s, inputs: np.ndarray, h: float, events: dict[int, dict] | None = None):
    """Set inputs [ωx, ωy, Ux_in, Uy_in] before each step; rows of (t, outputs)."""
    rows = [[s.time, *s.get_many(OUT)]]
    for k, u in enumerate(inputs):
        for name, value in (events or {}).get(k, {}).items():
            s.set(name, value)
        for name, value in zip(("omega_x", "omega_y", "Ux_in", "Uy_in"), u, strict=True):
            s.set(name, value)
        s.step(h)
        rows.append([s.time, *s.get_many(OUT)])
    return np.array(rows)


def _scenarios(fmu_dir: Path, out: Path) -> None:
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from conftest import FmuSlave

    fmu = fmu_dir / "DTG.fmu"
    res: dict[str, np.ndarray] = {}
    quiet = {"noise_std": 0.0, "dither_std": 0.0}

    cases = {  # name: (parameters, step, n steps, rate std, volt std)
        "open_paper": ({"parameter_set": 1, "rebalance_on": False}, T, 500, 0.01, 1.0),
        "open_prod": ({"parameter_set": 2, "rebalance_on": False}, 0.7e-3, 300, 0.01, 1.0),
        "closed_paper": ({"parameter_set": 1}, T, 1000, 0.01, 0.2),
        "closed_prod": ({"parameter_set": 2}, 0.7e-3, 150, 0.01, 0.2),
    }
    for i, (name, (par, h, n, rs, vs)) in enumerate(cases.items()):
        inputs = _random_inputs(n, 100 + i, rs, vs)
        s = FmuSlave(fmu, name, {**par, **quiet})
        res[name] = _drive(s, inputs, h)
        res[name + "_inputs"] = inputs
        res[name + "_h"] = np.array(h)
        s.close()

    # nominal closed loop, dither + pick-off noise, spin slow-down at IDENT_SECONDS
    n = round(IDENT_SECONDS / T)
    s = FmuSlave(fmu, "ident", {"dither_std": 1.0, "noise_std": 1e-3, "seed": 1})
    res["ident"] = _drive(s, np.zeros((2 * n, 4)), T, {n: {"spin_fraction": 0.9}})
    s.close()

    for name, pset, seconds in (("readout_paper", 1, 6.0), ("readout_prod", 2, 1.0)):
        s = FmuSlave(fmu, name, {"parameter_set": pset, **quiet})
        steps = np.tile([RATE_X, RATE_Y, 0.0, 0.0], (round(seconds / T), 1))
        res[name] = _drive(s, steps, T)[-1]
        s.close()

    s = FmuSlave(fmu, "prod_ident", {"parameter_set": 2, "dither_std": 1.0,
                                      "noise_std": 1e-3, "seed": 1})
    res["prod_ident"] = _drive(s, np.zeros((n, 4)), T)
    s.close()

    # save / restore, with a tunable fault change after the save point
    s = FmuSlave(fmu, "state", {"dither_std": 1.0, "noise_std": 1e-3, "seed": 3})
    _drive(s, _random_inputs(100, 7, 0.01, 0.0), T)
    t_saved, state = s.time, s.fmu.getFMUstate()
    serialised = s.fmu.serializeFMUstate(state)
    branch = _random_inputs(100, 8, 0.01, 0.0)
    event = {50: {"spin_fraction": 0.95}}
    first = _drive(s, branch, T, event)
    s.fmu.setFMUstate(state)
    s.set("spin_fraction", 1.0)  # the restore must bring back the variables as well
    s.time = t_saved
    second = _drive(s, branch, T, event)
    s.fmu.setFMUstate(s.fmu.deSerializeFMUstate(serialised))
    s.time = t_saved
    third = _drive(s, branch, T, event)
    s.close()
    res["state_first"], res["state_second"], res["state_third"] = first, second, third
    np.savez(out, **res)


# ---------------------------------------------------------------------------------------
# independent reference
# ---------------------------------------------------------------------------------------

def _coefficients(p):
    """Rotor coefficients from the raw physical constants of the set (nominal)."""
    spin = p.spin_rate
    return dict(J=p.J, c=p.c, k=p.K - (p.Ie - p.Iz / 2) * spin**2, L=(p.Jz + p.Ie) * spin,
                lam=(p.c + p.D) * spin, Ku=p.Ku, KT=p.KT)


def _controller(p):
    """Tustin-discretised rebalance controller built with python-control."""
    import control

    s = control.tf("s")
    C = p.kp * (1 + p.ki / s) / (s**2 / p.filter_corner**2
                                 + 2 * p.filter_damping * s / p.filter_corner + 1)
    if p.lead_zero != p.lead_pole:
        C = C * (1 + s / p.lead_zero) / (1 + s / p.lead_pole)
    d = control.ss(control.sample_system(C, p.controller_sample_time, method="tustin"))
    return d.A, np.ravel(d.B), np.ravel(d.C), float(np.ravel(d.D)[0])


def _reference(p, inputs: np.ndarray, h: float, loop: bool):
    """Outputs (Utx, Uty, Ux, Uy) at the communication points, independent simulation.

    State [α, β, α', β'] (relative rates); ω constant within a step, a step change of ω
    makes α' jump by −Δω (J·ω̇ impulse). Controller ticks every Tc from t = 0.
    """
    from scipy.integrate import solve_ivp

    c = _coefficients(p)
    J, cc, k, L, lam, Ku, KT = (c[n] for n in ("J", "c", "k", "L", "lam", "Ku", "KT"))

    def rhs(_t, x, wx, wy, ux, uy):
        a, b, da, db = x
        dda = (Ku * ux - cc * da - k * a - L * (db + wy) - lam * b) / J
        ddb = (Ku * uy - cc * db - k * b + L * (da + wx) + lam * a) / J
        return [da, db, dda, ddb]

    Tc = p.controller_sample_time
    if loop:
        Ac, Bc, Cc, Dc = _controller(p)
        xc = np.zeros((len(Bc), 2))
        cr, sr = np.cos(p.loop_rotation), np.sin(p.loop_rotation)
        R = np.array([[cr, -sr], [sr, cr]])

    x = np.zeros(4)
    rows = []
    u_ctrl = np.zeros(2)

    def tick(x):
        nonlocal xc
        e = -R @ (x[:2] / KT)
        u = Cc @ xc + Dc * e
        xc = Ac @ xc + np.outer(Bc, e)
        return u

    if loop:
        u_ctrl = tick(x)
    rows.append([x[0] / KT, x[1] / KT, *u_ctrl])
    w_prev = np.zeros(2)
    m = 0  # last tick index
    t = 0.0
    for j, (wx, wy, uxi, uyi) in enumerate(inputs):
        x[2] -= wx - w_prev[0]
        x[3] -= wy - w_prev[1]
        w_prev = np.array([wx, wy])
        t_end = (j + 1) * h
        u_int = np.zeros(2)
        while t < t_end - 1e-12:
            nxt = (m + 1) * Tc
            target = nxt if nxt <= t_end + 1e-12 else t_end
            u = u_ctrl + np.array([uxi, uyi])
            sol = solve_ivp(rhs, (t, target), x, method="DOP853", rtol=1e-12, atol=1e-14,
                            args=(wx, wy, *u))
            x = sol.y[:, -1]
            u_int += u * (target - t)
            t = target
            if abs(target - nxt) <= 1e-12:
                m += 1
                if loop:
                    u_ctrl = tick(x)
        rows.append([x[0] / KT, x[1] / KT, *(u_int / h)])
    return np.array(rows)


def _identify(rec: np.ndarray, start: float, stop: float) -> np.ndarray:
    """θ by batch LS on both axes after the library's 6th-order 50 Hz prefilter."""
    from gyrodiag.common.estimators import batch_ls
    from gyrodiag.common.prefilter import ButterworthPrefilter
    from gyrodiag.dtg.model import dtg_regression

    t = rec[:, 0]
    sel = (t >= start - 1e-9) & (t < stop - 1e-9)
    filt = ButterworthPrefilter(6, 50.0, 1.0 / T, n_channels=4).update(rec[sel][:, 1:5])
    skip = 500  # prefilter and loop transients (0.5 s)
    px, yx, py, yy = dtg_regression(*filt[skip:].T)
    return batch_ls(np.vstack([px, py]), np.concatenate([yx, yy]))


def _theta_physical(p) -> np.ndarray:
    from gyrodiag.dtg.model import DTGParameters, theta_from_physical

    return theta_from_physical(DTGParameters(**_coefficients(p)), T)


# ---------------------------------------------------------------------------------------
# tests
# ---------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def rec(run_fmu_script) -> dict[str, np.ndarray]:
    return run_fmu_script(Path(__file__).resolve())


@pytest.mark.parametrize("name, pset, loop", [
    ("open_paper", 1, False), ("open_prod", 2, False),
    ("closed_paper", 1, True), ("closed_prod", 2, True),
])
def test_outputs_equal_independent_reference(rec, name, pset, loop):
    p = sets.parameter_set(pset)
    got = rec[name][:, 1:5]
    ref = _reference(p, rec[name + "_inputs"], float(rec[name + "_h"]), loop)
    for j, label in enumerate(["Utx", "Uty", "Ux", "Uy"]):
        scale = np.max(np.abs(ref[:, j]))
        assert scale > 1e-3, f"{label} not excited in {name}"
        np.testing.assert_allclose(got[:, j], ref[:, j], rtol=1e-6, atol=1e-6 * scale,
                                   err_msg=f"{name}: {label}")
    if not loop:  # with the loop off the torquer outputs are the held inputs
        np.testing.assert_allclose(got[1:, 2:4], rec[name + "_inputs"][:, 2:4], rtol=1e-12)


def test_identified_theta_has_the_paper_pattern(rec):
    theta = _identify(rec["ident"], 0.0, IDENT_SECONDS)
    phys = _theta_physical(sets.paper_set())
    print("identified θ (nominal):", theta, "\ntheta_from_physical:", phys,
          "\ndiscretisation/closed-loop bias:", theta - phys)
    # paper θ_nom = [1.9951, 0.9959, −0.0288, −0.0303, 0.0002]; the spread over noise
    # seeds is < 2e-3 on θ1, θ2 and < 1e-3 on θ3, θ4 (README), the bias vs
    # theta_from_physical ≈ +8e-3 on θ1, θ2 (backward differences vs the sampled rotor)
    assert theta[0] == pytest.approx(2.0, abs=0.02)
    assert theta[1] == pytest.approx(1.0, abs=0.02)
    assert -0.04 < theta[2] < -0.02 and -0.04 < theta[3] < -0.02
    assert theta[2] == pytest.approx(theta[3], rel=0.15)
    assert 1.2e-4 < theta[4] < 3e-4  # paper 2e-4
    assert 50 < abs(theta[3]) / theta[4] < 300  # "about two orders of magnitude"
    np.testing.assert_allclose(theta[:2], phys[:2], atol=0.015)
    np.testing.assert_allclose(theta[2:], phys[2:], rtol=0.1)


def test_spin_slow_down_moves_theta(rec):
    nominal = _identify(rec["ident"], 0.0, IDENT_SECONDS)
    slow = _identify(rec["ident"], IDENT_SECONDS, 2 * IDENT_SECONDS)
    eta = np.abs(slow) / np.abs(nominal)
    print("η for a 10 % spin slow-down:", eta)
    # L, λ ∝ Ω: θ3, θ4 fall by 10 % (physical: η = 0.900, 0.900); θ1, θ2 barely move
    np.testing.assert_allclose(eta[2:4], 0.9, atol=0.03)
    np.testing.assert_allclose(eta[:2], 1.0, atol=0.01)
    # measurable: the change of θ4 is > 10× its seed-to-seed spread (< 1e-3)
    assert abs(slow[3] - nominal[3]) > 2e-3


def test_production_identification_at_1khz_is_not_the_paper_pattern(rec):
    theta = _identify(rec["prod_ident"], 0.0, IDENT_SECONDS)
    p = sets.production_set()
    c = _coefficients(p)
    print("production identified θ:", theta, " L·T/J =", c["L"] * T / c["J"])
    # L·T/J ≈ 1.9 rad per sample: θ3 ≈ θ4 are O(1) and positive, nothing like −0.03
    assert theta[0] == pytest.approx(2.0, abs=0.05)
    assert theta[1] == pytest.approx(1.0, abs=0.05)
    assert theta[2] > 0.5 and theta[3] > 0.5


@pytest.mark.parametrize("name", ["readout_paper", "readout_prod"])
def test_rebalance_read_out_equals_constant_rate(rec, name):
    last = dict(zip(OUT, rec[name][1:], strict=True))
    assert last["omega_x_read"] == pytest.approx(RATE_X, rel=1e-3)
    assert last["omega_y_read"] == pytest.approx(RATE_Y, rel=1e-3)
    assert abs(last["Utx"]) < 1e-3 and abs(last["Uty"]) < 1e-3  # rotor held at null


@pytest.mark.parametrize("pset", [1, 2])
@pytest.mark.parametrize("spin_fraction", [1.0, 0.9])
def test_rebalance_loop_is_stable_with_margin(pset, spin_fraction):
    m = loop_margins(sets.parameter_set(pset), spin_fraction=spin_fraction)
    assert m.spectral_radius < 1.0
    assert m.modulus_margin > 0.6  # ⇒ gain margin > 8 dB, phase margin > 35°
    assert m.phase_margin_deg > 40.0 and m.gain_margin_db > 10.0


def test_fmu_state_round_trip(rec):
    np.testing.assert_array_equal(rec["state_first"], rec["state_second"])
    np.testing.assert_array_equal(rec["state_first"], rec["state_third"])
    assert np.std(rec["state_first"][:, 1]) > 0  # noisy, so the generator state matters


if __name__ == "__main__":
    _scenarios(Path(sys.argv[1]), Path(sys.argv[2]))
