"""Dynamically tuned gyro (DTG) diagnosis: identification, reference, decision.

Modules
-------
model
    DTG rotor model: regressors, θ ↔ physical parameters.
case_rate
    The rotor model with the case rate as an input (case-rate regressors).
alignment
    Sample alignment of the case-rate input to the rotor read-out.
reference
    Learned nominal reference, residual monitors and classification statistics.
patterns
    Response-pattern library and classifier of DTG faults.
physical_test
    GLR test of a spin or torquer scale change.
learning
    Learning the pattern library from training runs (numpy only).
decision
    The paper's decision: ratio thresholds, log10 features, nearest signature.
config
    Settings of the DTG channel.
outputs
    Outputs of the DTG channel.
classifier
    The interface of the DTG channel's classifiers.
paper_rule
    The paper's classifier: ratio band, decade signatures.
pattern_rule
    The pattern classifier: residual tests, pattern library.
pairing
    Pairing of the voltages with the case rate (the aligner's queue).
blocks
    The channel's reference blocks and the case rate's block statistics.
channel
    The DTG channel of the Diagnoser: all of the above on streamed samples.

Every public name of these modules is importable from the package too
(``from gyrodiag.dtg import ...``); it is imported from its module at first use,
so that importing one module of the package imports none of its siblings.
"""

from __future__ import annotations

from ..common._lazy import lazy_exports

#: Public name -> the module of this package that defines it.
_EXPORTS = {
    "N_THETA": "model",
    "THETA_NAMES": "model",
    "DTGParameters": "model",
    "DTGRegressor": "model",
    "PhysicalRatios": "model",
    "dtg_regression": "model",
    "physical_from_theta": "model",
    "rotor_state_space": "model",
    "theta_from_physical": "model",
    "CASE_RATE_SCHEMES": "case_rate",
    "CaseRateDTGRegressor": "case_rate",
    "CentralPhysicalRatios": "case_rate",
    "dtg_case_rate_regression": "case_rate",
    "physical_from_theta_central": "case_rate",
    "theta_central_from_physical": "case_rate",
    "CaseRateAligner": "alignment",
    "ALLOWANCE_SIGMA": "reference",
    "CHANNELS": "reference",
    "N_CHANNELS": "reference",
    "N_TESTS": "reference",
    "REFERENCE_STATUS": "reference",
    "ClassificationStatistics": "reference",
    "NominalPrior": "reference",
    "NominalReference": "reference",
    "ReferenceLearner": "reference",
    "RegressionModel": "reference",
    "ResidualMonitor": "reference",
    "ResidualThresholds": "reference",
    "block_moments": "reference",
    "regression_residuals": "reference",
    "window_moments": "reference",
    "AXIS_CODES": "patterns",
    "FAULT_TYPES": "patterns",
    "FORMAT": "patterns",
    "SIGNALS": "patterns",
    "NoiseModel": "patterns",
    "PatternClass": "patterns",
    "PatternClassifier": "patterns",
    "PatternLibrary": "patterns",
    "PatternResult": "patterns",
    "DEFAULT_LIBRARY_FILE": "patterns",
    "default_library": "patterns",
    "PatternRun": "learning",
    "PHYSICAL_KINDS": "physical_test",
    "PHYSICAL_SIGMA": "physical_test",
    "PhysicalResult": "physical_test",
    "PhysicalTest": "physical_test",
    "AXIS_Z": "readout_noise",
    "OTHER_AXIS_SHARE": "readout_noise",
    "renamed_noise": "readout_noise",
    "attenuated_axis": "readout_noise",
    "physical_class": "patterns",
    "learn_patterns": "learning",
    "UNKNOWN_CODE": "decision",
    "Classification": "decision",
    "DecisionOutput": "decision",
    "SignatureClassifier": "decision",
    "ThresholdDecision": "decision",
    "WindowedMedianFeature": "decision",
    "feature_floats": "decision",
    "feature_vector": "decision",
    "median_feature": "decision",
    "parameter_ratios": "decision",
    "signature_distance": "decision",
    "AUTO_SETTINGS": "config",
    "CLASSIFIERS": "config",
    "ESTIMATOR_KINDS": "config",
    "DTGChannelConfig": "config",
    "DTGChannelOutput": "outputs",
    "DTGDiagnosis": "outputs",
    "ChannelClassifier": "classifier",
    "PaperRule": "paper_rule",
    "MASKED_SIGNAL_FIT": "pattern_rule",
    "OMEGA_EXCITATION_Z": "pattern_rule",
    "PatternRule": "pattern_rule",
    "CaseRatePairing": "pairing",
    "OMEGA_SPREAD_FLOOR": "blocks",
    "ReferenceBlocks": "blocks",
    "DTGChannel": "channel",
}

__all__ = sorted(_EXPORTS)

__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
