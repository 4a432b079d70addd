"""Grey-model (GM(1,1)) prediction and fault detection of the HRG.

Method B (docs/methods.md §3, seed 001): a hemispherical resonator gyro's
output is predicted one sample ahead by a grey model fitted to the last ``m`` samples;
a measured sample farther than a threshold from its prediction raises a fault alarm.

Modules
-------
gm11
    GM(1,1): fit, optimal initial value, one-step prediction, positive shift.
predictor
    Classic and improved moving-window grey predictors; prediction error metric.
detector
    The grey fault detector: the predictor side composed with one decision rule.
residual
    The predictor side: predictions, re-seeding, substitutes, candidate predictors.
rules
    The per-sample decision rules (fixed threshold, k-sigma, CUSUM and lagged step
    test) as strategy objects behind one interface.
lagged
    The lagged step test of the sequential rule (weights, thresholds, its state).
calibration
    σ_e learned on a fault-free start; the choice among candidate predictors.
substitution
    The fault-free envelope and the bounded substitute fed to the predictor.
decision
    The rules' configurations (paper's fixed threshold, calibrated sequential,
    calibrated k-sigma) that build the detector.

Every public name of these modules is importable from the package too
(``from gyrodiag.grey import ...``); it is imported from its module at first use,
so that importing one module of the package imports none of its siblings.
"""

from __future__ import annotations

from ..common._lazy import lazy_exports

#: Public name -> the module of this package that defines it.
_EXPORTS = {
    "DEFAULT_LEVEL_RATIO": "gm11",
    "GM11_MIN_LENGTH": "gm11",
    "gm11_fit": "gm11",
    "gm11_fitted_values": "gm11",
    "gm11_optimal_initial_value": "gm11",
    "gm11_predict_classic": "gm11",
    "gm11_predict_next": "gm11",
    "gm11_predict_optimized": "gm11",
    "positive_shift": "gm11",
    "ClassicGreyPredictor": "predictor",
    "GreyPredictor": "predictor",
    "ImprovedGreyPredictor": "predictor",
    "prediction_errors_percent": "predictor",
    "GreyDetectorOutput": "detector",
    "GreyFaultDetector": "detector",
    "LAG_MAX_LIMIT": "lagged",
    "LONGEST_LAG_SHARE": "lagged",
    "LaggedStepTest": "lagged",
    "lag_step_weights": "lagged",
    "lag_test_threshold": "lagged",
    "DecisionRule": "rules",
    "FixedThreshold": "rules",
    "KSigmaTest": "rules",
    "SequentialTest": "rules",
    "Verdict": "rules",
    "ErrorScale": "calibration",
    "PredictorChoice": "calibration",
    "calibrated_sigma": "calibration",
    "Substitution": "substitution",
    "GreyResidual": "residual",
    "DEFAULT_LEARN_END_S": "decision",
    "MIN_CALIBRATION_ERRORS": "decision",
    "REFERENCE_MAX_SAMPLES": "decision",
    "CalibratedKSigma": "decision",
    "CalibratedSequential": "decision",
    "GreyDecision": "decision",
    "PaperThreshold": "decision",
}

__all__ = sorted(_EXPORTS)

__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
