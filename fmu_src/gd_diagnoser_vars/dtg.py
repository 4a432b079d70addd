"""Variables of the DTG identification channel (``gyrodiag.dtg.channel``).

Parameters with a ``field`` fill the same-named argument of ``DTGChannelConfig``
(target "config"); the facade adds the coded ones (estimator, classifier, case rate),
theta0's learn switch and the signature library.
"""

from __future__ import annotations

from typing import Any

from gyrodiag.dtg.case_rate import CASE_RATE_SCHEMES
from gyrodiag.dtg.channel import BAND_SIGMA
from gyrodiag.dtg.model import N_THETA
from gyrodiag.dtg.physical_test import PHYSICAL_SIGMA
from gyrodiag.dtg.reference import ALLOWANCE_SIGMA, CHANNELS, POWER_THRESHOLD

from .spec import AUTO, AUTO_INT, POSITIVE, Var, inp, out, par

#: Signatures that fit in the parameter table (more: use ``dtg.signature_file``).
MAX_SIGNATURES = 8
PHYSICAL_NAMES = ("c_over_J", "k_over_J", "L_over_J", "lambda_over_J", "Ku_over_KT_J")
PHYSICAL_UNITS = ("1/s", "1/s2", "rad/s", "1/s2", "1/s2")


def _cfg(name: str, kind: str, start: Any, text: str, unit: str | None = None,
         lo: float | None = None, hi: float | None = None, **extra: Any) -> Var:
    """A parameter that fills the config field named like it (without "dtg.")."""
    return par(name, kind, start, text, unit, lo, hi, field=f"config.{name[4:]}", **extra)


def _theta0() -> list[Var]:
    return [par(f"dtg.theta0[{i}]", "Real", 1.0, f"Nominal theta{i}", "1",
                field="config.theta0", to="list", index=(i,)) for i in range(1, N_THETA + 1)]


def _monitored() -> list[Var]:
    return [par(f"dtg.monitored[{i}]", "Boolean", True, f"theta{i} takes part in the decision",
                tunable=True, field="config.monitored", to="list", index=(i,))
            for i in range(1, N_THETA + 1)]


def _signatures() -> list[Var]:
    return [par(f"dtg.signature[{j},{i}]", "Integer", 0,
                f"Feature C{i} of fault signature {j} (fault code {j})")
            for j in range(1, MAX_SIGNATURES + 1) for i in range(1, N_THETA + 1)]


PARAMETERS: tuple[Var, ...] = (
    par("dtg.enabled", "Boolean", True, "Run the DTG identification channel"),
    _cfg("dtg.prefilter_enabled", "Boolean", True,
         "Butterworth low-pass on all four DTG signals"),
    _cfg("dtg.prefilter_order", "Integer", 6, "Butterworth order", None, 1, 20),
    _cfg("dtg.prefilter_cutoff_hz", "Real", 0.0,
         "Butterworth cut-off; 0: auto, 1/(20*sample_period_s) (the paper's 50 Hz at "
         "1 kHz), so that it follows the sample period", "Hz", 0.0, to="zero_none"),
    _cfg("dtg.prefilter_highpass_hz", "Real", 0.0,
         "High-pass corner cascaded with the low-pass (band-pass); 0: off (paper). "
         "Removes the slow torquer response to case rates, not in the regression",
         "Hz", 0.0, to="zero_none"),
    par("dtg.estimator", "Integer", 2,
        "Estimator: 0 sliding-window batch LS, 1 RLS, 2 RLS with forgetting factor",
        None, 0, 2),
    _cfg("dtg.window", "Integer", 500, "Batch LS window, samples", None, N_THETA),
    _cfg("dtg.forgetting", "Real", AUTO,
         "RLS forgetting factor (paper 0.99); -1: auto, 0.999, with dtg.case_rate 0.9998",
         "1", AUTO, 1.0, to="auto"),
    _cfg("dtg.p0", "Real", 1e6, "Initial RLS covariance scale", "1", POSITIVE),
    par("dtg.learn_theta0", "Boolean", True,
        "Learn nominal theta0 from the learning window (else use dtg.theta0[i])"),
    *_theta0(),
    _cfg("dtg.learn_start_s", "Real", AUTO,
         "Start of the theta0 learning window after the first sample; -1: auto, 1 s, "
         "with dtg.case_rate 2 s", "s", AUTO, to="auto"),
    _cfg("dtg.learn_end_s", "Real", AUTO,
         "End of the theta0 learning window; -1: auto, 5 s, with dtg.case_rate 10 s",
         "s", AUTO, to="auto"),
    _cfg("dtg.low", "Real", AUTO,
         "Lower ratio threshold on eta; -1: auto, 0.5 (paper), with dtg.case_rate 0.93; "
         "with dtg.low and dtg.high both auto and the physical test on, no band",
         "1", AUTO, 1.0 - POSITIVE, tunable=True, to="auto"),
    _cfg("dtg.high", "Real", AUTO,
         "Upper ratio threshold on eta; -1: auto, 1.5 (paper), with dtg.case_rate 1.07 "
         "(no band: see dtg.low)",
         "1", AUTO, tunable=True, to="auto"),
    _cfg("dtg.persistence_k", "Integer", AUTO_INT,
         "Alarm when k of the last n violate; -1: auto, 1, with dtg.case_rate 0.1 s",
         None, AUTO_INT, tunable=True, to="auto"),
    _cfg("dtg.persistence_n", "Integer", AUTO_INT,
         "Persistence window n, samples; -1: auto, 1, with dtg.case_rate 0.2 s",
         None, AUTO_INT, to="auto"),
    _cfg("dtg.band_sigma", "Real", BAND_SIGMA,
         "Case rate, pattern classifier: a ratio outside the band counts only where "
         "theta is also this many standard errors from theta0 (0: the band alone)",
         "1", 0.0, tunable=True),
    _cfg("dtg.physical_sigma", "Real", PHYSICAL_SIGMA,
         "Pattern classifier on a bench (no dtg.case_rate): threshold of the GLR test of a "
         "spin or torquer scale change, standard errors; 0: off (the ratio band only)",
         "1", 0.0),
    _cfg("dtg.latch", "Boolean", False, "Keep the alarm once raised", tunable=True),
    *_monitored(),
    par("dtg.n_signatures", "Integer", 0,
        "Number of signatures given as parameters dtg.signature[j,i]", None, 0,
        MAX_SIGNATURES),
    *_signatures(),
    par("dtg.signature_file", "String", "",
        "JSON signature library {\"signatures\": {name: [C1..C5]}}; relative paths "
        "are resolved in the FMU resources; overrides the parameter table"),
    _cfg("dtg.max_distance", "Real", -1.0,
         "Eq. 7 distance beyond which a fault is unknown (code -1); < 0: no limit",
         "1", tunable=True, to="negative_none"),
    _cfg("dtg.classify_window_s", "Real", 0.5,
         "Paper classifier: an alarm is classified by the median feature of its samples "
         "in this last window (the signature-learning rule); 0: each sample alone (paper)",
         "s", 0.0),
    par("dtg.classifier", "String", "pattern",
        "'pattern': frozen checked reference, residual tests with alarm memory and "
        "classification by learned response patterns (type, signal, axis, size); "
        "'paper': the paper's ratio band and decade signatures"),
    _cfg("dtg.window_s", "Real", 0.5,
         "Pattern classifier: window of the residual level and variance tests, and the "
         "shortest classification window", "s", POSITIVE),
    _cfg("dtg.long_window_s", "Real", 2.0,
         "Pattern classifier: window of the long variance test and the longest "
         "classification window (>= dtg.window_s)", "s", POSITIVE),
    _cfg("dtg.level_threshold", "Real", 6.0,
         "Pattern classifier: alarm when a residual's window mean exceeds this many "
         "block-mean spreads / sqrt(blocks) (held down to 2/3 of it)", "1", POSITIVE,
         tunable=True),
    _cfg("dtg.var_threshold", "Real", 4.0,
         "Pattern classifier: alarm when a residual's window variance exceeds this "
         "multiple of its nominal (held down to its 2/3 power)", "1", 1.0 + 1e-9,
         tunable=True),
    _cfg("dtg.long_var_threshold", "Real", 2.0,
         "Pattern classifier: the same over the long window", "1", 1.0 + 1e-9,
         tunable=True),
    _cfg("dtg.power_threshold", "Real", POWER_THRESHOLD,
         "Pattern classifier: threshold of the CUSUM of the residuals' low-frequency "
         "power (squared 25 ms block means in nominal spreads, tuned to a tripling; the "
         "witness of torquer read-out noise); held down to half of it; 0: off", "1", 0.0,
         tunable=True),
    _cfg("dtg.allowance_sigma", "Real", ALLOWANCE_SIGMA,
         "Pattern classifier with the case rate: the reference's error the variance "
         "tests and the power CUSUM allow for, in standard deviations of its covariance "
         "(a manoeuvre edge raises their ratios to that error squared); 1: the channel's "
         "earlier, tighter allowance", "1", 0.0, tunable=True),
    _cfg("dtg.theta_spread_threshold", "Real", 30.0,
         "Learning guard: largest spread of a learning segment's theta against the "
         "segments before it, in units of its least-squares covariance", "1", POSITIVE),
    par("dtg.case_rate", "Integer", 0,
        "Case rate in the DTG regression: 0 none (paper, case at rest), 1 central scheme, "
        "2 paper scheme; the rates are the inputs dtg.case_rate_x/_y, an estimate not from "
        "this gyro (e.g. a second gyro); theta0 and the reference are then per axis",
        None, 0, len(CASE_RATE_SCHEMES)),
    _cfg("dtg.pickoff_scale", "Real", 1e-3,
         "Nominal pick-off scale KT of the gyro (datasheet); the case rate enters the "
         "regressors as rate*T/KT (used when dtg.case_rate > 0)", "rad/V", POSITIVE),
    _cfg("dtg.case_rate_delay_samples", "Integer", 0,
         "Case rate: the voltages of sample k are paired with the case rate of sample "
         "k - d (d = 1: Jacobi coupling with the DTG plant between the aircraft and this "
         "FMU; d < 0: the case rate arrives later, the outputs describe the sample |d| "
         "earlier); the harness sets it from its coupling plan", None, -50, 50),
    _cfg("dtg.case_rate_align_max", "Integer", 0,
         "Case rate: choose the delay in -this..this from the data (0: keep "
         "dtg.case_rate_delay_samples); for hosts whose timing is unknown "
         "(docs/dtg_case_rate.md section 9)", None, 0, 50),
    _cfg("dtg.case_rate_lookahead_s", "Real", 0.032,
         "Case-rate alignment: how far the aligner runs ahead of the estimators (used "
         "when dtg.case_rate_align_max > 0; the outputs describe the sample this much "
         "earlier)", "s", POSITIVE, 1.0),
    _cfg("dtg.clear_after_s", "Real", 0.5,
         "Pattern classifier: a residual alarm clears this long after the last block "
         "with a test above its hold threshold", "s", 0.0),
)


def _signals() -> list[Var]:
    """Inputs, the identification outputs and the alarm outputs."""
    vs = [inp(f"dtg.{name}", "Real", 0.0, f"DTG signal {name}", "V")
          for name in ("Utx", "Uty", "Ux", "Uy")]
    vs += [inp(f"dtg.case_rate_{axis}", "Real", 0.0,
               f"Case rate about the gyro's {axis} axis held over the sample, from an "
               "estimate independent of this gyro (used when dtg.case_rate > 0)", "rad/s")
           for axis in ("x", "y")]
    for axis in ("x", "y"):
        for i in range(1, N_THETA + 1):
            vs.append(out(f"dtg.theta_{axis}[{i}]", "Real", 0.0,
                          f"Identified theta{i}, {axis} axis", "1"))
            vs.append(out(f"dtg.eta_{axis}[{i}]", "Real", 1.0,
                          f"Ratio |theta{i}|/|theta0_{i}|, {axis} axis", "1"))
    for i in range(1, N_THETA + 1):
        vs.append(out(f"dtg.theta0_used[{i}]", "Real", 0.0,
                      f"Nominal theta{i} in use, x axis (both axes when dtg.case_rate = 0; 0 "
                      "while learning)", "1"))
        vs.append(out(f"dtg.theta0_used_y[{i}]", "Real", 0.0,
                      f"Nominal theta{i} in use, y axis (= dtg.theta0_used[{i}] when "
                      "dtg.case_rate = 0; 0 while learning)", "1"))
    vs += [out(f"dtg.{name}", "Real", 0.0,
               f"Identified {name}; 0 while dtg.physical_valid is false", unit)
           for name, unit in zip(PHYSICAL_NAMES, PHYSICAL_UNITS, strict=True)]
    return [*vs,
            out("dtg.physical_valid", "Boolean", False,
                "The identified theta gives finite physical parameters"),
            out("dtg.learning", "Boolean", False, "Nominal theta0 still being learned"),
            out("dtg.alarm", "Boolean", False, "DTG parameter-ratio alarm"),
            out("dtg.fault_code", "Integer", 0,
                "0 none, j = nearest signature j, -1 unknown/unclassified, -2 two signal "
                "faults at once (pattern classifier; dtg.fault_name names both)"),
            out("dtg.fault_name", "String", "",
                "Name of dtg.fault_code's class (e.g. uty_step, spin): empty none, unknown; "
                "two faults: both names, larger first (e.g. utx_step+uy_step)"),
            out("dtg.first_alarm_time", "Real", -1.0,
                "Simulation time of the first DTG alarm (its sample's time), -1 if none", "s"),
            out("dtg.case_rate_delay_in_use", "Integer", 0,
                "Delay d of the case rate in use (dtg.case_rate_delay_samples, or the "
                "aligner's choice with dtg.case_rate_align_max > 0)"),
            out("dtg.valid", "Boolean", True, "Last DTG sample was finite")]


def _diagnosis() -> list[Var]:
    """Outputs of the reference, residual tests and pattern classification."""
    vs = [
        out("dtg.reference_valid", "Boolean", False,
            "The learned nominal reference passed its checks (false while learning)"),
        out("dtg.reference_status", "Integer", 0,
            "0 learning, 1 valid, 2 change inside the learning window (reference from the "
            "segments before it), 3 mismatch with the nominal prior (prior in use), "
            "4 not checked (paper classifier, too little data), 5 no reference (no usable "
            "data in the learning window: no alarm)"),
        out("dtg.residual_alarm", "Boolean", False,
            "Pattern classifier: residual tests against the frozen reference in alarm"),
        out("dtg.physical_alarm", "Boolean", False,
            "Pattern classifier: the GLR test of a spin or torquer scale change in alarm "
            "(dtg.physical_sigma)"),
        out("dtg.physical_statistic", "Real", 0.0,
            "Pattern classifier: that test's T2 over its best window (4 degrees of "
            "freedom; 0 while it waits for a reference or a full window)", "1"),
        out("dtg.fault_type", "Integer", 0,
            "0 none, 1 step, 2 noise, 3 loss, 4 drift, 5 spin slow-down, 6 torquer scale, "
            "-1 unknown"),
        out("dtg.fault_signal", "Integer", 0,
            "0 none or physical, 1 Utx, 2 Uty, 3 Ux, 4 Uy, -1 unknown or several "
            "(dtg.fault_signals)"),
        out("dtg.fault_axis", "Integer", 0, "0 none, 1 x, 2 y, 3 both, -1 unknown"),
        out("dtg.fault_signals", "Integer", 0,
            "Signals the class names, one bit each: 1 Utx, 2 Uty, 4 Ux, 8 Uy (two bits: "
            "two faults at once); 0 none, physical or unknown"),
        out("dtg.class_distance", "Real", -1.0,
            "Chi-square per channel of the class fitted to the statistics; -1 if none", "1"),
        out("dtg.fault_size", "Real", 0.0,
            "Estimated fault size: step offset, noise std, noise left by a loss, current "
            "drift offset (V); 0 if undefined (dtg.fault_size_valid)", "V"),
        out("dtg.fault_size_valid", "Boolean", False, "dtg.fault_size is defined"),
        out("dtg.fault_rate", "Real", 0.0, "Estimated drift rate; 0 unless a drift", "V/s"),
        out("dtg.fault_ratio", "Real", 1.0,
            "Physical classes: estimated parameter ratio (spin Omega/Omega_nom, torquer "
            "Ku/Ku_nom); 1 otherwise", "1"),
    ]
    for i, ch in enumerate(CHANNELS, start=1):
        vs.append(out(f"dtg.level[{i}]", "Real", 0.0,
                      f"{ch}: window mean minus nominal, in nominal block-mean spreads (test "
                      "window; classification window in alarm)", "1"))
        vs.append(out(f"dtg.log_var_ratio[{i}]", "Real", 0.0,
                      f"{ch}: log10 of window variance / nominal (detrended)", "1"))
    vs.append(out("dtg.level_growth", "Real", 0.0,
                  "Growth of the residual level across the window (drift witness)", "1"))
    vs.append(out("dtg.stat_window_s", "Real", 0.0,
                  "Length of the window of dtg.level / dtg.log_var_ratio", "s"))
    for i, axis in enumerate("xy", start=1):
        vs += [out(f"dtg.residual_level_z[{i}]", "Real", 0.0,
                   f"Level test statistic of the {axis} residual", "1"),
               out(f"dtg.residual_var_ratio[{i}]", "Real", 0.0,
                   f"Short-window variance ratio of the {axis} residual", "1"),
               out(f"dtg.residual_long_var_ratio[{i}]", "Real", 0.0,
                   f"Long-window variance ratio of the {axis} residual", "1"),
               out(f"dtg.residual_power_cusum[{i}]", "Real", 0.0,
                   f"Low-frequency power CUSUM of the {axis} residual over "
                   "dtg.power_threshold (alarm at 1)", "1")]
    for i in range(1, N_THETA + 1):
        vs.append(out(f"dtg.ref_theta0[{i}]", "Real", 0.0,
                      f"Reference theta{i} of the residuals, x axis (both axes when "
                      "dtg.case_rate = 0; 0 before the reference)", "1"))
        vs.append(out(f"dtg.ref_theta0_y[{i}]", "Real", 0.0,
                      f"Reference theta{i} of the residuals, y axis (0 before the reference)",
                      "1"))
    for key, unit, text in (("ref_mean", "V", "nominal mean"),
                            ("ref_block_std", "V", "nominal spread of block means"),
                            ("ref_var_short", "V2", "nominal variance, short window"),
                            ("ref_var_long", "V2", "nominal variance, long window")):
        vs += [out(f"dtg.{key}[{i}]", "Real", 0.0, f"{ch}: {text} (0 before the reference)",
                   unit) for i, ch in enumerate(CHANNELS, start=1)]
    return vs


#: Every variable of the channel, in declaration order.
VARIABLES: tuple[Var, ...] = (*PARAMETERS, *_signals(), *_diagnosis())

#: Library argument names -> FMU parameter names, so that a validation message names
#: the parameter the user has to change (the facade's _channel_context).
MESSAGE_NAMES: dict[str, str] = {
    "order": "dtg.prefilter_order", "cutoff_hz": "dtg.prefilter_cutoff_hz",
    "highpass_hz": "dtg.prefilter_highpass_hz",
    "sample_rate_hz": "1/sample_period_s", "estimator": "dtg.estimator",
    "window": "dtg.window", "forgetting": "dtg.forgetting", "p0": "dtg.p0",
    "theta0": "dtg.theta0[1..5]", "learn_start_s": "dtg.learn_start_s",
    "learn_end_s": "dtg.learn_end_s", "low": "dtg.low", "high": "dtg.high",
    "persistence_k": "dtg.persistence_k", "persistence_n": "dtg.persistence_n",
    "monitored": "dtg.monitored[1..5]", "classify_window_s": "dtg.classify_window_s",
    "signatures": "signatures (dtg.signature[j,i] or dtg.signature_file)",
    "max_distance": "dtg.max_distance", "classifier": "dtg.classifier",
    "window_s": "dtg.window_s", "long_window_s": "dtg.long_window_s",
    "level_threshold": "dtg.level_threshold", "var_threshold": "dtg.var_threshold",
    "long_var_threshold": "dtg.long_var_threshold",
    "theta_spread_threshold": "dtg.theta_spread_threshold",
    "power_threshold": "dtg.power_threshold",
    "allowance_sigma": "dtg.allowance_sigma",
    "clear_after_s": "dtg.clear_after_s", "patterns": "dtg.signature_file",
    "case_rate": "dtg.case_rate", "pickoff_scale": "dtg.pickoff_scale",
    "case_rate_delay_samples": "dtg.case_rate_delay_samples",
    "case_rate_align_max": "dtg.case_rate_align_max",
    "case_rate_lookahead_s": "dtg.case_rate_lookahead_s",
}
