"""Variables of the grey-prediction channel (``gyrodiag.grey``).

Field targets: "improved" (``ImprovedGreyPredictor`` options), "paper"
(``PaperThreshold``), "learned" (both learned rules) and "sequential" (the
sequential rule's own arguments). The model, window, evaluation, decision code,
alarm clearing and auto order are read by the facade.
"""

from __future__ import annotations

from typing import Any

from gyrodiag.grey.decision import (
    DEFAULT_LEARN_END_S,
    CalibratedKSigma,
    CalibratedSequential,
    PaperThreshold,
)

from .spec import POSITIVE, Var, inp, out, par

#: Declared unit of the grey channel's signal (the HRG output voltage it was made for).
GREY_UNIT = "V"
#: grey.decision codes -> the rule (gyrodiag.grey.decision); 1, the sequential rule, is
#: the default, 0 the paper's fixed threshold.
GREY_DECISIONS = {0: PaperThreshold, 1: CalibratedSequential, 2: CalibratedKSigma}
GREY_DECISION_DEFAULT = 1


def _to(target: str, name: str, kind: str, start: Any, text: str, unit: str | None = None,
        lo: float | None = None, hi: float | None = None, **extra: Any) -> Var:
    """A parameter that fills argument ``target`` ("group.argument")."""
    return par(name, kind, start, text, unit, lo, hi, field=target, **extra)


PARAMETERS: tuple[Var, ...] = (
    par("grey.enabled", "Boolean", True, "Run the grey-prediction channel"),
    par("grey.model", "Integer", 1,
        "0 classic GM(1,1) (C = first sample), 1 improved (optimised C, residual fit)",
        None, 0, 1),
    par("grey.window", "Integer", 10,
        "Moving window length m >= 4, samples; 0 (classic model only): the whole "
        "record since the start or the last alarm clearing (the paper's ordinary GM)",
        None, 0),
    par("grey.classic_evaluation", "Integer", 0,
        "Classic model's time response: 0 careful (exact as a -> 0), 1 textbook "
        "(1 - e^a)(C - b/a)e^(-am), which collapses on a constant window as in the paper",
        None, 0, 1),
    par("grey.decision", "Integer", GREY_DECISION_DEFAULT,
        "Decision rule: 0 paper (alarm when |y - prediction| > grey.threshold), "
        "1 sequential (threshold from the prediction errors of the fault-free start "
        "grey.learn_end_s, lagged step test and CUSUM for grey.false_alarm_rate), "
        "2 k-sigma (the same learned sigma_e, alarm at grey.k_sigma * sigma_e per sample)",
        None, 0, max(GREY_DECISIONS)),
    _to("paper.threshold", "grey.threshold", "Real", 0.05,
        "Paper rule (grey.decision = 0): alarm threshold on |y - prediction|, in the "
        "monitored signal's unit", GREY_UNIT, POSITIVE, tunable=True),
    par("grey.clear_after_s", "Real", 20.0,
        "Clear an alarm this long after onset; <= 0: never", "s", tunable=True),
    _to("improved.a_min", "grey.a_min", "Real", 1e-6,
        "|a| below which the improved model predicts by the polynomial", "1", 0.0),
    _to("improved.residual_order", "grey.residual_order", "Integer", 2,
        "Improved model: degree of the residual polynomial (paper: 2)", None, 0, 4),
    _to("learned.learn_end_s", "grey.learn_end_s", "Real", DEFAULT_LEARN_END_S,
        "Learned rules (grey.decision = 1, 2): the signal is fault-free from the start "
        "until this time: the predictor's warm-up window, then the one-step prediction "
        "errors that give their standard deviation sigma_e (at least 10 of them)",
        "s", POSITIVE),
    _to("learned.threshold_floor", "grey.threshold_floor", "Real", 0.01,
        "Learned rules: smallest threshold allowed on |y - prediction| (sigma_e >= "
        "floor / grey.k_sigma; floor / grey.k_sigma is also the lagged test's allowance "
        "for its reference's model error), in the monitored signal's unit",
        GREY_UNIT, POSITIVE, tunable=True),
    _to("learned.k_sigma", "grey.k_sigma", "Real", 5.0,
        "Learned rules: k-sigma alarm at |y - prediction| > k_sigma * sigma_e "
        "(grey.decision = 2); sigma floor grey.threshold_floor / k_sigma", "1", POSITIVE),
    _to("sequential.false_alarms_per_h", "grey.false_alarm_rate", "Real", 1e-3,
        "Sequential rule: design false-alarm rate (per hour)", "1/h", 1e-9, 3600.0),
    _to("sequential.cusum_k", "grey.cusum_k", "Real", 1.5,
        "Sequential rule: CUSUM reference in sigma_e", "1", 0.05, 5.0),
    _to("learned.suspicion_sigma", "grey.suspicion_sigma", "Real", 4.0,
        "Learned rules: a sample off its prediction by more than this many sigma_e is "
        "not fed to the predictor until the test decides", "1", POSITIVE),
    _to("sequential.lag_max", "grey.lag_max", "Integer", 3,
        "Sequential rule: lagged step test on the last 1..lag_max samples "
        "against a polynomial reference window that ends before them (a generalised "
        "likelihood ratio per lag, threshold for grey.false_alarm_rate); while it is "
        "ready the CUSUM only holds alarms; 0: CUSUM alone", None, 0, 4),
    _to("sequential.reference_window_s", "grey.reference_window_s", "Real", 30.0,
        "Sequential rule, lagged test: longest reference window, s (at most 400 "
        "samples, at least grey.reference_order + 3; it starts at min(20 samples, this) "
        "after the start or an alarm and grows)", "s", POSITIVE),
    _to("sequential.reference_order", "grey.reference_order", "Integer", 3,
        "Sequential rule, lagged test: degree of the reference polynomial "
        "(grey.reference_window_s must hold order + 3 samples)", None, 0, 3),
    par("grey.auto_order", "Boolean", True,
        "Learned rules, improved model: also run residual orders 1 and 0 during the "
        "calibration and keep the one with the least error (noise favours low orders); "
        "not used by the paper rule or the classic model"),
)

SIGNALS: tuple[Var, ...] = (
    inp("grey.y", "Real", 0.0,
        f"Monitored signal (declared in {GREY_UNIT}, the HRG output the channel was made "
        "for; any signal works, its unit is then that of grey.threshold, "
        "grey.threshold_floor and the outputs)", GREY_UNIT),
    out("grey.prediction", "Real", 0.0,
        "One-step prediction of this sample; 0 while grey.prediction_valid is false",
        GREY_UNIT),
    out("grey.error", "Real", 0.0,
        "y - prediction; 0 while grey.prediction_valid or grey.valid is false", GREY_UNIT),
    out("grey.prediction_valid", "Boolean", False,
        "A prediction exists for this sample (window filled)"),
    out("grey.alarm", "Boolean", False, "Grey prediction alarm"),
    out("grey.calibrating", "Boolean", False,
        "Learned rules: warm-up or calibration window in progress (no alarm)"),
    out("grey.sigma", "Real", 0.0,
        "Learned rules: standard deviation of the fault-free prediction error in use "
        "(signal units); 0 before it is learned and with the paper rule", GREY_UNIT, 0.0),
    out("grey.noise_sigma", "Real", 0.0,
        "Sequential rule, lagged test: standard deviation of the signal's white noise in "
        "use (95 % upper bound from third differences, grey.threshold_floor / "
        "grey.k_sigma added in quadrature); 0 before it is known or without the lagged "
        "test", GREY_UNIT, 0.0),
    out("grey.statistic", "Real", 0.0,
        "Alarm statistic in units of its threshold (alarm at 1)", "1", 0.0),
    out("grey.valid", "Boolean", True, "Last grey sample was finite"),
)

#: Every variable of the channel, in declaration order.
VARIABLES: tuple[Var, ...] = (*PARAMETERS, *SIGNALS)

#: Library argument names -> FMU parameter names (validation messages).
MESSAGE_NAMES: dict[str, str] = {
    "window": "grey.window", "threshold": "grey.threshold", "a_min": "grey.a_min",
    "clear_after_s": "grey.clear_after_s", "residual_order": "grey.residual_order",
    "k_sigma": "grey.k_sigma", "false_alarms_per_h": "grey.false_alarm_rate",
    "cusum_k": "grey.cusum_k", "suspicion_sigma": "grey.suspicion_sigma",
    "learn_end_s": "grey.learn_end_s", "threshold_floor": "grey.threshold_floor",
    "lag_max": "grey.lag_max",
    "reference_window_s": "grey.reference_window_s",
    "reference_order": "grey.reference_order",
}
