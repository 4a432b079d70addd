"""Variables of the detection-filter channel (``gyrodiag.df.channel``), sized and
started from the seed aircraft (``gyrodiag.df.plant.seed_aircraft``).

Field targets: "config" (``DFChannelConfig``), "noise" (the noise std vector, None
when any entry is < 0) and "gust" (``GustModel``). The decision code and the sensor
dynamics file are read by the facade.
"""

from __future__ import annotations

from typing import Any

from gyrodiag.df.plant import seed_aircraft

from .spec import POSITIVE, Var, inp, out, par

SEED = seed_aircraft()
#: Detection-filter dimensions: states, inputs, sensors (those of the seed aircraft).
DF_N, DF_P, DF_M = SEED.A.shape[0], SEED.B.shape[1], SEED.C.shape[0]
#: df.decision code of the automatic choice (the default; gyrodiag.df.channel's).
DF_DECISION_AUTO = 2
#: Default df.gust_sigma_w: MIL-F-8785C's severe low-altitude turbulence, m/s.
DF_GUST_SIGMA_W = 2.3

#: SI exponents of the seed aircraft's signal units (for the units of A, B, C entries).
_UNIT_EXPONENTS: dict[str, dict[str, int]] = {
    "1": {}, "m": {"m": 1}, "m/s": {"m": 1, "s": -1}, "rad": {"rad": 1},
    "rad/s": {"rad": 1, "s": -1},
}


def _unit_ratio(num: str, den: str, per_second: bool = False) -> str:
    """Unit of num/den (/s), e.g. ("m/s", "rad", True) → "m/(rad.s2)"."""
    exps = dict(_UNIT_EXPONENTS[num])
    for base, e in _UNIT_EXPONENTS[den].items():
        exps[base] = exps.get(base, 0) - e
    if per_second:
        exps["s"] = exps.get("s", 0) - 1

    def part(base: str, e: int) -> str:
        return base if abs(e) == 1 else f"{base}{abs(e)}"

    order = ("m", "rad", "s")
    top = ".".join(part(b, exps[b]) for b in order if exps.get(b, 0) > 0) or "1"
    bottom = [part(b, exps[b]) for b in order if exps.get(b, 0) < 0]
    if not bottom:
        return top
    return f"{top}/{bottom[0]}" if len(bottom) == 1 else f"{top}/({'.'.join(bottom)})"


def _cfg(name: str, kind: str, start: Any, text: str, unit: str | None = None,
         lo: float | None = None, hi: float | None = None, field: str = "",
         **extra: Any) -> Var:
    """A parameter that fills DFChannelConfig's ``field`` (default: named like it)."""
    return par(name, kind, start, text, unit, lo, hi,
               field=f"config.{field or name[3:]}", **extra)


def _plant() -> list[Var]:
    """df.A, df.B (row by row), df.C, then df.eigenvalue and df.x0 per state."""
    s, vs = SEED, []
    for i in range(DF_N):
        vs += [par(f"df.A[{i + 1},{j + 1}]", "Real", float(s.A[i, j]),
                   f"Plant matrix A, row {i + 1} ({s.state_names[i]})",
                   _unit_ratio(s.state_units[i], s.state_units[j], True),
                   field="config.A", to="array", index=(i + 1, j + 1)) for j in range(DF_N)]
        vs += [par(f"df.B[{i + 1},{j + 1}]", "Real", float(s.B[i, j]),
                   f"Input matrix B, row {i + 1}, input {s.input_names[j]}",
                   _unit_ratio(s.state_units[i], s.input_units[j], True),
                   field="config.B", to="array", index=(i + 1, j + 1)) for j in range(DF_P)]
    for i in range(DF_M):
        vs += [par(f"df.C[{i + 1},{j + 1}]", "Real", float(s.C[i, j]),
                   f"Output matrix C, sensor {s.output_names[i]}",
                   _unit_ratio(s.output_units[i], s.state_units[j]),
                   field="config.C", to="array", index=(i + 1, j + 1)) for j in range(DF_N)]
    for i in range(DF_N):
        vs.append(par(f"df.eigenvalue[{i + 1}]", "Real", -float(i + 1),
                      f"Eigenvalue {i + 1} of A - KC (real, negative, distinct)", "1/s",
                      None, -POSITIVE, field="config.eigenvalues", to="array",
                      index=(i + 1,)))
        vs.append(par(f"df.x0[{i + 1}]", "Real", 0.0,
                      f"Initial estimate of state {s.state_names[i]}", s.state_units[i],
                      field="config.x0", to="array", index=(i + 1,)))
    return vs


def _sensor_delays() -> list[Var]:
    return [_cfg(f"df.sensor_delay[{i + 1}]", "Integer", 0,
                 f"Sensor {i + 1} (df.y[{i + 1}]) arrives this many samples after the others "
                 "of the same instant (routed through one FMU more under Jacobi coupling, "
                 "e.g. the DTG read-out: 1); the other channels are held back to match; the "
                 "harness sets it from its coupling plan", None, 0, 50,
                 field="sensor_delay_samples", to="list", index=(i + 1,))
            for i in range(DF_M)]


def _thresholds() -> list[Var]:
    """Per sensor: main threshold, noise std, the bank's thresholds without it."""
    s, vs = SEED, []
    for i in range(DF_M):
        unit = s.output_units[i]
        vs.append(_cfg(f"df.threshold[{i + 1}]", "Real", 1.0,
                       f"Main residual threshold of sensor {s.output_names[i]} "
                       "(used when df.calibrate_s = 0)", unit, POSITIVE,
                       field="main_thresholds", to="array", index=(i + 1,)))
        vs.append(par(f"df.noise_std[{i + 1}]", "Real", -1.0,
                      f"Noise std of sensor {s.output_names[i]}; < 0 on any sensor: learned "
                      "from the calibration window (paper rule without one: threshold / "
                      "k_sigma)", unit, field="noise.noise_std", to="array", index=(i + 1,)))
        used = [k for k in range(DF_M) if k != i]
        vs += [_cfg(f"df.bank_threshold[{i + 1},{j + 1}]", "Real", 1.0,
                    f"Threshold of observer {i + 1} (without sensor {i + 1}) on its "
                    f"residual {j + 1}, sensor {s.output_names[used[j]]} "
                    "(used when df.calibrate_s = 0)", s.output_units[used[j]], POSITIVE,
                    field="bank_thresholds", to="array", index=(i + 1, j + 1))
               for j in range(DF_M - 1)]
    return vs


PARAMETERS: tuple[Var, ...] = (
    par("df.enabled", "Boolean", True, "Run the detection-filter channel"),
    *_plant(),
    par("df.decision", "Integer", DF_DECISION_AUTO,
        "Decision rule: 0 paper (k-sigma per sample, k-of-n, latched, observer-bank "
        "isolation), 1 sequential (whitened residual, CUSUM for df.false_alarm_rate, "
        "isolation of one or two sensors, fault typing, episodes), 2 auto: sequential, "
        "or paper when df.sensor_dynamics_file gives a read-out model (the sequential "
        "rule does not isolate there)", None, 0, 2),
    _cfg("df.false_alarm_rate", "Real", 1e-3,
         "Sequential: design false-alarm rate of the detection (per hour)", "1/h", 1e-9,
         3600.0, field="false_alarms_per_h"),
    _cfg("df.cusum_k", "Real", 0.5,
         "Sequential: CUSUM reference in sigma of the whitened residual (optimal for "
         "mean shifts of 2k)", "1", 0.05, 5.0),
    _cfg("df.variance_ratio", "Real", 4.0,
         "Sequential: variance increase the variance CUSUMs are designed for (> 1)", "1",
         1.0 + 1e-9, 1e6),
    _cfg("df.max_faults", "Integer", 2,
         "Sequential: simultaneously faulty sensors to isolate (1 or 2)", None, 1, 2),
    _cfg("df.history_s", "Real", 4.0,
         "Sequential: samples kept to start the isolation before a change", "s", POSITIVE,
         600.0),
    _cfg("df.memory_s", "Real", 10.0,
         "Sequential: the isolation keeps running this long after a fault episode", "s",
         0.0),
    _cfg("df.input_delay_samples", "Integer", 0,
         "Alignment: y(k) is paired with u(k - d) (d < 0: with a later u, outputs then "
         "describe the sample |d| steps back); the chosen one if df.align_auto", None, -50,
         50),
    _cfg("df.align_auto", "Boolean", True,
         "Choose the alignment on the calibration window (least residual variance over "
         "d in [-df.align_max, df.align_max]); the master's coupling order needs no setting. "
         "Not with df.sensor_dynamics_file, whose read-out model sets the timing"),
    _cfg("df.align_max", "Integer", 2, "Largest |d| tried by df.align_auto", None, 0, 50),
    *_sensor_delays(),
    par("df.sensor_dynamics_file", "String", "",
        "JSON file of one sensor's read-out dynamics G (e.g. the DTG's rebalance loop on "
        "q, models/dtg/gd_dtg_readout.py; relative paths are in the FMU's resources): "
        "every input and every other sensor go through the same G (matched filtering); "
        "empty: every sensor is y = Cx"),
    par("df.gust_sigma_w", "Real", DF_GUST_SIGMA_W,
        "Sequential: Dryden vertical gust intensity sigma_w the residual model allows "
        "for (turbulence up to it is not a fault; MIL-F-8785C light 0.77, moderate "
        "1.5, severe 2.3); the gust enters through the alpha and q columns of df.A in "
        "the alpha-dot and q-dot rows; 0: no turbulence model", "m/s", 0.0, 100.0,
        field="gust.sigma_w"),
    par("df.gust_scale_length", "Real", 50.0,
        "Sequential: Dryden scale length L_w of the gust model (below 1000 ft: the "
        "altitude)", "m", POSITIVE, field="gust.scale_length"),
    par("df.gust_airspeed", "Real", 272.24,
        "Sequential: true airspeed V of the gust model", "m/s", POSITIVE,
        field="gust.airspeed"),
    par("df.gust_wingspan", "Real", 10.0,
        "Sequential: wing span b of the gust model's pitch-rate filter 4b/(pi V)", "m",
        POSITIVE, field="gust.wingspan"),
    _cfg("df.calibrate_s", "Real", 10.0,
         "Fault-free calibration window for the alignment, noise and thresholds; 0: "
         "none (paper rule: df.threshold[i]; sequential rule: df.noise_std[i])", "s", 0.0),
    _cfg("df.burn_in_s", "Real", 2.0,
         "Start of the calibration window ignored (observer convergence)", "s", 0.0),
    _cfg("df.k_sigma", "Real", 6.0, "Paper rule: thresholds at k standard deviations", "1",
         POSITIVE),
    *_thresholds(),
    _cfg("df.persistence_k", "Integer", 3, "Residual alarm: k of the last n", None, 1),
    _cfg("df.persistence_n", "Integer", 5, "Residual alarm persistence n", None, 1),
    _cfg("df.confirm_samples", "Integer", 5,
         "Samples of one isolation pattern before it is latched", None, 1),
    _cfg("df.isolation_window_s", "Real", 4.0,
         "Paper rule: when the alarm pattern does not isolate, isolate by the observer "
         "bank's residual energy within this time after detection (0: the pattern "
         "alone, as the paper's filter; a shorter window than 10 sample periods is "
         "lengthened to 10; small faults in turbulence need it)", "s", 0.0, 3600.0),
    _cfg("df.isolation_baseline_s", "Real", 10.0,
         "Paper rule: time constant of the bank's fault-free energy baseline before "
         "detection; the energy isolation measures against the larger of it and the "
         "calibration, so turbulence stronger than during calibration is not taken for "
         "a faultless observer (0: the calibration alone)", "s", 0.0, 3600.0),
)


def _sensor_signals(i: int) -> list[Var]:
    """Input y and the per-sensor outputs of sensor i (0-based)."""
    name, unit, k = SEED.output_names[i], SEED.output_units[i], i + 1
    return [
        inp(f"df.y[{k}]", "Real", 0.0, f"Sensor {name}", unit),
        out(f"df.residual[{k}]", "Real", 0.0, f"Detection-filter residual of sensor {name}",
            unit),
        out(f"df.alarm[{k}]", "Boolean", False, f"Residual alarm of sensor {name}"),
        out(f"df.threshold_in_use[{k}]", "Real", 0.0,
            f"Paper rule: residual threshold in use for sensor {name} "
            "(learned or given); 0 while calibrating and with the sequential rule", unit),
        out(f"df.statistic[{k}]", "Real", 0.0,
            f"Alarm statistic of sensor {name} in units of its "
            "threshold (alarm at 1): largest CUSUM / threshold (sequential), "
            "|residual| / threshold (paper)", "1", 0.0),
        out(f"df.noise_std_in_use[{k}]", "Real", 0.0,
            f"Noise std of sensor {name} in use (given or learned); 0 "
            "while calibrating", unit, 0.0),
        out(f"df.sensor_fault_type[{k}]", "Integer", 0,
            f"Fault type of sensor {name} (codes of df.fault_type; 0 "
            "when not isolated)"),
        out(f"df.fault_offset[{k}]", "Real", 0.0,
            f"Sensor {name}: bias, intermittent amplitude or stuck value "
            "(0 for a failure or another type)", unit),
        out(f"df.fault_gain[{k}]", "Real", 1.0,
            f"Sensor {name}: gain factor of a gain fault (1 otherwise)", "1"),
        out(f"df.fault_rate[{k}]", "Real", 0.0,
            f"Sensor {name}: drift rate of a ramp fault (0 otherwise)",
            f"{unit}/s" if unit != "m/s" else "m/s2"),
        out(f"df.noise_ratio[{k}]", "Real", 1.0,
            f"Sensor {name}: noise std over nominal of a noise-increase "
            "fault (1 otherwise)", "1"),
    ]


SIGNALS: tuple[Var, ...] = (
    *(inp(f"df.u[{j + 1}]", "Real", 0.0, f"Plant input {SEED.input_names[j]}",
          SEED.input_units[j]) for j in range(DF_P)),
    *(v for i in range(DF_M) for v in _sensor_signals(i)),
    out("df.calibrating", "Boolean", False, "Calibration window still being recorded"),
    out("df.detected", "Boolean", False,
        "Sensor fault detected: latched (paper rule); a fault episode in progress, "
        "cleared when the fault clears (sequential rule)"),
    out("df.episodes", "Integer", 0, "Fault episodes since the start"),
    out("df.isolated_sensor", "Integer", 0,
        "1-based index of the isolated sensor (the current or, between episodes, the "
        "last diagnosis); 0 none; -1 detected, not isolated; -2 several sensors "
        "(df.isolated_mask says which, 0 if they cannot be told apart)"),
    out("df.isolated_mask", "Integer", 0,
        "Bit i-1 set for each isolated sensor i (e.g. 6: sensors 2 and 3)"),
    out("df.fault_type", "Integer", 0,
        "-1 unknown, 0 none, 1 bias, 2 gain, 3 stuck, 4 complete failure, 5 noise "
        "increase, 6 ramp, 7 intermittent (of the isolated sensor; two sensors: their "
        "common type, else -1)"),
    out("df.fault_magnitude", "Real", 0.0,
        "Size of the isolated sensor's fault in the unit of its type: bias / stuck "
        "value / intermittent amplitude (sensor units), gain factor, ramp rate (per s), "
        "noise std ratio; declared dimensionless because its unit follows the isolated "
        "sensor and type; 0 for a failure or when df.fault_magnitude_valid is false. The "
        "per-sensor outputs df.fault_offset/gain/rate, df.noise_ratio carry units", "1"),
    out("df.fault_magnitude_valid", "Boolean", False,
        "df.fault_magnitude holds an estimate (a fault of known type is isolated)"),
    out("df.input_delay_in_use", "Integer", 0,
        "Alignment d in use (chosen on the calibration window with df.align_auto)"),
    out("df.valid", "Boolean", True, "Last u, y sample was finite"),
)

#: Every variable of the channel, in declaration order.
VARIABLES: tuple[Var, ...] = (*PARAMETERS, *SIGNALS)

#: Library argument names -> FMU parameter names (validation messages).
MESSAGE_NAMES: dict[str, str] = {
    "eigenvalues": "df.eigenvalue[1..5]", "calibrate_s": "df.calibrate_s",
    "burn_in_s": "df.burn_in_s", "k_sigma": "df.k_sigma",
    "main_thresholds": "df.threshold[1..6]", "bank_thresholds": "df.bank_threshold[i,j]",
    "noise_std": "df.noise_std[1..6]", "persistence_k": "df.persistence_k",
    "persistence_n": "df.persistence_n", "confirm_samples": "df.confirm_samples",
    "isolation_window_s": "df.isolation_window_s",
    "isolation_baseline_s": "df.isolation_baseline_s",
    "x0": "df.x0[1..5]", "decision": "df.decision",
    "sensor_dynamics": "df.sensor_dynamics_file",
    "false_alarms_per_h": "df.false_alarm_rate", "cusum_k": "df.cusum_k",
    "variance_ratio": "df.variance_ratio", "max_faults": "df.max_faults",
    "history_s": "df.history_s", "memory_s": "df.memory_s",
    "input_delay_samples": "df.input_delay_samples", "align_auto": "df.align_auto",
    "align_max": "df.align_max", "sensor_delay_samples": "df.sensor_delay[1..6]",
}
