"""Library demonstration: identify a simulated DTG rotor and judge a fault.

Run ``python -m gyrodiag.demo``. A J-normalised rotor is simulated exactly (zero-order
hold, matrix exponential) at 1 kHz with band-limited random torquer excitation and
pick-off noise; the four signals pass the paper's 6th-order 50 Hz Butterworth
prefilter; RLS with forgetting 0.99 identifies θ on both axes; the nominal θ0 is then
used to judge a second run in which the spin rate has dropped by 10 %.
"""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np
from scipy import signal

from .common.estimators import ForgettingRLS
from .common.prefilter import ButterworthPrefilter
from .dtg.decision import ThresholdDecision, feature_vector
from .dtg.model import (
    DTGParameters,
    DTGRegressor,
    physical_from_theta,
    rotor_state_space,
    theta_from_physical,
)

T_S = 1e-3
NOMINAL = DTGParameters(J=1.0, c=40.0, k=800.0, L=-30.0, lam=50.0, Ku=500.0, KT=0.5)


def simulate(params: DTGParameters, n: int, seed: int, noise_v: float) -> np.ndarray:
    """Columns Utx, Uty, Ux, Uy (V) of a sampled open-loop rotor run."""
    rng = np.random.default_rng(seed)
    sos = signal.butter(4, 40.0, fs=1.0 / T_S, output="sos")
    u = signal.sosfilt(sos, rng.standard_normal((n, 2)), axis=0)
    A, B, C = rotor_state_space(params)
    Ad, Bd, Cd, Dd, _ = signal.cont2discrete((A, B, C, np.zeros((2, 2))), T_S, "zoh")
    # u[k] drives the rotor over (t_{k-1}, t_k]; Utx(k) is sampled at t_k.
    _, y, _ = signal.dlsim((Ad, Bd, Cd, Dd, T_S), np.vstack([u[1:], u[-1:]]))
    y = np.vstack([np.zeros((1, 2)), y[:-1]])
    y += noise_v * rng.standard_normal(y.shape)
    return np.column_stack([y, u])


def identify(record: np.ndarray) -> np.ndarray:
    """Prefilter, build regressors and run RLS with forgetting; θ trajectory."""
    filt = ButterworthPrefilter(6, 50.0, 1.0 / T_S, n_channels=4)
    reg = DTGRegressor()
    est = ForgettingRLS(5, forgetting=0.999, p0=1e8)
    traj = []
    for sample in filt.update(record):
        rows = reg.update(*sample)
        if rows is not None:
            est.update(rows[0], rows[1])
            est.update(rows[2], rows[3])
        traj.append(est.theta.copy())
    return np.array(traj)


def _row(label: str, values: np.ndarray) -> str:
    return f"  {label:<22s}" + "".join(f"{v:>13.6g}" for v in values)


def judge(theta0: np.ndarray, params: DTGParameters, n: int, seed: int, noise_v: float,
          ) -> dict[str, np.ndarray | bool]:
    """Identify a faulty rotor and judge it against ``theta0``; with what the model says
    the judgement should be (the ratio of the faulty to the nominal rotor's θ)."""
    theta = identify(simulate(params, n, seed=seed, noise_v=noise_v))[n // 2 :].mean(axis=0)
    measured = ThresholdDecision(theta0).update(theta)
    eta_expected = theta_from_physical(params, T_S) / theta_from_physical(NOMINAL, T_S)
    expected = ThresholdDecision(np.ones(5)).update(eta_expected)
    return {"eta": measured.eta, "eta_expected": eta_expected,
            "C": feature_vector(measured.eta), "C_expected": feature_vector(eta_expected),
            "alarm": bool(measured.alarm), "alarm_expected": bool(expected.alarm)}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=10.0, help="run length, s")
    parser.add_argument("--noise", type=float, default=1e-4, help="pick-off noise std, V")
    args = parser.parse_args(argv)
    if not (args.seconds >= 1.0):
        parser.error(f"--seconds must be >= 1, got {args.seconds}")
    if not (args.noise >= 0.0):
        parser.error(f"--noise must be >= 0, got {args.noise}")
    n = int(args.seconds / T_S)

    truth = theta_from_physical(NOMINAL, T_S)
    theta0 = identify(simulate(NOMINAL, n, seed=1, noise_v=args.noise))[n // 2 :].mean(axis=0)
    print(f"Nominal rotor, {args.seconds:g} s at 1 kHz, pick-off noise {args.noise:g} V, "
          "RLS with forgetting 0.999 (θ: mean of the second half)")
    print(f"  {'':<22s}" + "".join(f"{f'θ{i}':>13s}" for i in range(1, 6)))
    print(_row("expected (model)", truth))
    print(_row("identified", theta0))
    print(_row("relative error", np.abs(theta0 - truth) / np.abs(truth)))
    print("  expected: the rotor's own θ under backward differences; a few % off is the "
          "prefilter's and the noise's bias")
    r = physical_from_theta(theta0, T_S)
    print("Physical ratios from θ: identified (expected)")
    print(f"  c/J = {r.c_over_J:.2f} 1/s ({NOMINAL.c / NOMINAL.J:.2f}), k/J = "
          f"{r.k_over_J:.1f} 1/s² ({NOMINAL.k / NOMINAL.J:.1f}), L/J = {r.L_over_J:.2f} "
          f"rad/s ({NOMINAL.L / NOMINAL.J:.2f}), Ku/(KT·J) = {r.Ku_over_KT_J:.1f} "
          f"({NOMINAL.Ku / (NOMINAL.KT * NOMINAL.J):.1f})")
    print("  expected: the continuous rotor's ratios; the backward-difference model biases "
          "the identified ones (docs/notes.md, DTG)")

    print("Faults judged against the identified θ0 (paper band 0.5 … 1.5 on η = θ/θ0)")
    faults = {
        "spin-motor slow-down 10 %": dataclasses.replace(NOMINAL, L=0.9 * NOMINAL.L,
                                                        lam=0.9 * NOMINAL.lam),
        "torquer gain −60 %": dataclasses.replace(NOMINAL, Ku=0.4 * NOMINAL.Ku),
    }
    for seed, (label, params) in enumerate(faults.items(), start=2):
        out = judge(theta0, params, n, seed, args.noise)
        print(f"  {label}")
        print(f"  {'':<22s}" + "".join(f"{f'η{i}':>13s}" for i in range(1, 6)))
        print(_row("expected (model)", out["eta_expected"]))
        print(_row("measured", out["eta"]))
        print(f"  C = {out['C'].tolist()} (expected {out['C_expected'].tolist()}), alarm = "
              f"{out['alarm']} (expected {out['alarm_expected']})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
