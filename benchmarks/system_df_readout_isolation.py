"""Figures of docs/notes.md (System): the detection filter with the DTG read-out model,
sequential rule against the paper rule, on a 10 % spin slow-down in a manoeuvre.

Runs the system chain without FMUs (tests/_system_chain.py: aircraft + LQR at 1 kHz, the
paper DTG as pitch gyro; 0.05 rad square wave from 10 s, calibration 2–10 s) and prints

1. per spin-fault onset: the first detection, the isolated sensor and the fault type and
   size at the end, for the sequential rule (``df.decision`` 1) and the paper rule (0),
   both with the read-out model (matched filtering, docs/readout_dynamics.md);
2. why the sequential rule fails with it, on a fault-free run: the lag-1 autocorrelation
   of the whitened residual of hypothesis generator ¬q (white by design), and the
   hypotheses rejected when the bank is started from the main filter's state on
   fault-free data (as an episode does), with and without the read-out model.

    python benchmarks/system_df_readout_isolation.py [--onsets 10 11 12 13 17]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
for sub in ("tests", "fmu_src", "models/dtg"):
    sys.path.insert(0, str(ROOT / sub))

import gd_dtg_readout as readout  # noqa: E402
import gd_dtg_sets as sets  # noqa: E402
from _system_chain import PitchCommand, run_chain  # noqa: E402

from gyrodiag.df.channel import DFChannel, DFChannelConfig  # noqa: E402
from gyrodiag.df.sensor_dynamics import SensorDynamics  # noqa: E402

T = 1e-3
SENSORS = ("v", "alpha", "q", "theta", "gamma", "h")


def _readout() -> SensorDynamics:
    return SensorDynamics.from_dict(readout.readout_dict(sets.paper_set(), "y", 3, T), T)


def _channel(decision: str, model: bool) -> DFChannel:
    return DFChannel(DFChannelConfig(sample_period_s=T, calibrate_s=10.0, burn_in_s=2.0,
                                     decision=decision, align_auto=False,
                                     sensor_dynamics=_readout() if model else None))


def _feed(ch: DFChannel, o: dict[str, np.ndarray]) -> tuple[float | None, object]:
    first, out = None, None
    for k in range(o["t"].size):
        out = ch.update_floats((0.0, o["elevator"][k]),
                               (o["y_v"][k], o["y_alpha"][k], o["q_read"][k],
                                o["y_theta"][k], o["y_gamma"][k], o["y_h"][k]))
        if first is None and out.detected:
            first = float(o["t"][k])
    return first, out


def _name(i: int) -> str:
    return {-2: "two or more", -1: "not isolated", 0: "none"}.get(i, SENSORS[i - 1]
                                                                 if i > 0 else str(i))


def isolation_table(onsets: list[float]) -> None:
    print("spin 0.9 at the onset, 0.05 rad square wave from 10 s, judged 6 s after it")
    print(f"{'onset s':>8} | {'sequential: detected, isolated, type, size':<44} | paper rule")
    for ts in onsets:
        o = run_chain(ts + 6.0, command=PitchCommand(1, -0.05, start=10.0, period=8.0),
                      spin=(ts, 0.9))
        cells = []
        for decision in ("sequential", "paper"):
            first, out = _feed(_channel(decision, True), o)
            cells.append(f"{first if first is None else round(first - ts, 3)} s, "
                         f"{_name(out.isolated_sensor)}, type {out.fault_type}, "
                         f"{out.magnitude:.3f}")
        print(f"{ts:8.1f} | {cells[0]:<44} | {cells[1]}")


def colour_and_replay() -> None:
    o = run_chain(16.0)
    for model in (False, True):
        ch = _channel("sequential", model)
        _feed(ch, o)
        e = ch._engine  # the sequential engine after 6 s of fault-free monitoring
        gi = e.hypotheses.index((2,))
        bank = e.bank
        bank.reset()
        for g in range(len(e.bank_generators)):
            bank.set_observer_state(g, e._hist_x[0])
        z = np.array([bank.update(e._hist_w[j % e._n_hist])[0][bank.out_slices[gi]]
                      for j in range(e._count)])[200:]
        rho = [np.corrcoef(z[1:, c], z[:-1, c])[0, 1] for c in range(z.shape[1])]
        print(f"read-out model {'on ' if model else 'off'}: generator ¬q, lag-1 "
              f"autocorrelation of z (v, α, ϑ, γ, h) {np.round(rho, 3).tolist()}, std "
              f"{np.round(z.std(axis=0), 2).tolist()}")
        # start the bank from the main state at 1 s windows, as an episode does
        for start in range(0, e._count - 1000, 1000):
            bank.reset()
            for g in range(len(e.bank_generators)):
                bank.set_observer_state(g, e._hist_x[start % e._n_hist])
            cusum = e._new_cusum(bank.n_out)
            cusum.reset(start)
            rejected: dict[tuple[int, ...], int] = {}
            z0 = None
            for j in range(start, start + 1000):
                zb = bank.update(e._hist_w[j % e._n_hist])[0]
                z0 = np.abs(zb).max() if z0 is None else z0
                if cusum.update(zb):
                    for c in np.flatnonzero(cusum.alarms):
                        rejected.setdefault(e.hypotheses[e._bank_gen_of_channel[c]],
                                            j - start)
            singles = {SENSORS[h[0]]: n for h, n in rejected.items() if len(h) == 1}
            print(f"    bank started at {10 + start * T:.0f} s: first-sample max |z| "
                  f"{z0:.1f}; single-sensor hypotheses rejected (samples after the start)"
                  f" {singles or 'none'}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--onsets", type=float, nargs="+", default=[10.0, 11.0, 12.0, 13.0, 17.0])
    a = ap.parse_args(argv)
    isolation_table(a.onsets)
    colour_and_replay()
    return 0


if __name__ == "__main__":
    sys.exit(main())
