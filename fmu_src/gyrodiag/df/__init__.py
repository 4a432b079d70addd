"""Detection-filter (DF) diagnosis of the flight-control sensors on the seed aircraft.

Modules
-------
plant
    Seed aircraft: linearised longitudinal model and the paper's eigenvalues.
filter
    Beard–Jones detection filter design, residual evaluation and thresholds.
isolation
    Observer banks and sensor fault isolation.
isolation_state
    Saved state of the sensor fault isolator: assembly and restore.
isolability
    Isolability analysis: which sensor faults a model can detect and isolate.
residual
    Residual covariance model and whitening; sensor noise variances.
gust
    Dryden turbulence as a disturbance model of the plant.
sensor_dynamics
    Sensor read-out dynamics and their equaliser.
generators
    Residual generators of the sequential rule (observer plus whitening) and their
    joint simulation.
settings
    Settings, output record and codes of the sequential rule.
hypotheses
    Hypothesis bank and isolation decision of the sequential rule.
onset
    Change-time estimates of the sequential rule.
signatures
    Fault signatures on the main filter's whitened residual and their running sums.
fault_typing
    Fit of the fault types of the sequential rule.
presence
    Presence test of an isolated fault (sequential rule).
sequential_diagnosis
    The sequential decision rule: detection, episodes and the sample history over
    the modules above (it re-exports the public names of generators and settings).
scale_calibration
    Widening of the sequential rule's residual channels on fault-free data.
sequential_state
    Saved state of the sequential rule's diagnoser: assembly and checked restore.
gains
    Memo of observer designs, seeded by the table a build ships.
channel_config
    Settings of the DF channel and the choice of its decision rule.
channel_output
    Output record of the DF channel.
calibration
    The channel's design and its calibration window: residuals, initial state,
    alignment scores.
decision
    Interface of the channel's decision rules (strategies).
paper_rule
    The paper's decision rule (k·σ thresholds, observer-bank isolation).
sequential_rule
    The sequential decision rule (noise fit, CUSUMs, hypothesis isolation).
channel
    The DF channel of the Diagnoser: all of the above on streamed samples.

Every public name of these modules is importable from the package too
(``from gyrodiag.df import ...``); it is imported from its module at first use,
so that importing one module of the package imports none of its siblings.
"""

from __future__ import annotations

from ..common._lazy import lazy_exports

#: Public name -> the module of this package that defines it.
_EXPORTS = {
    "PAPER_EIGENVALUES": "plant",
    "PAPER_PRINTED_K": "plant",
    "LongitudinalModel": "plant",
    "seed_aircraft": "plant",
    "DetectionFilter": "filter",
    "DiscreteObserver": "filter",
    "ResidualEvaluator": "filter",
    "ResidualThresholds": "filter",
    "design_detection_filter": "filter",
    "gaussian_k_sigma": "filter",
    "observability_matrix": "filter",
    "observable_subspace": "filter",
    "parity_space": "filter",
    "zoh_discretise": "filter",
    "BankObserver": "isolation",
    "FaultType": "isolation",
    "IsolabilityReport": "isolability",
    "IsolationResult": "isolation",
    "SensorFaultIsolator": "isolation",
    "SensorIsolability": "isolability",
    "design_observer_bank": "isolation",
    "isolability_analysis": "isolability",
    "place_observer_gain": "isolation",
    "isolator_state": "isolation_state",
    "restore_isolator_state": "isolation_state",
    "Disturbance": "residual",
    "GustModel": "gust",
    "seed_gust_input": "gust",
    "ResidualModel": "residual",
    "Whitening": "residual",
    "estimate_sensor_variances": "residual",
    "SensorDynamics": "sensor_dynamics",
    "SensorDynamicsEqualiser": "sensor_dynamics",
    "MULTIPLE": "sequential_diagnosis",
    "NOT_ISOLATED": "sequential_diagnosis",
    "DiagnosisOutput": "sequential_diagnosis",
    "FaultKind": "sequential_diagnosis",
    "ObserverStack": "sequential_diagnosis",
    "ResidualGenerator": "sequential_diagnosis",
    "SequentialDiagnoser": "sequential_diagnosis",
    "SequentialSettings": "sequential_diagnosis",
    "design_residual_generator": "sequential_diagnosis",
    "simulate_fault_free": "sequential_diagnosis",
    "calibrate_scales": "scale_calibration",
    "diagnoser_state": "sequential_state",
    "restore_diagnoser_state": "sequential_state",
    "FaultTyper": "fault_typing",
    "PRESENCE_CONSTANT": "fault_typing",
    "PRESENCE_MODEL": "fault_typing",
    "PRESENCE_NONE": "fault_typing",
    "PRESENCE_VARIANCE": "fault_typing",
    "HypothesisBank": "hypotheses",
    "hypotheses_of": "hypotheses",
    "refine_onset": "onset",
    "walk_back": "onset",
    "FaultSignatures": "signatures",
    "N_REG": "signatures",
    "REG_BIAS": "signatures",
    "REG_GAIN": "signatures",
    "REG_RAMP": "signatures",
    "PresenceTest": "presence",
    "CAL_MIN_SAMPLES": "channel_config",
    "DECISIONS": "channel_config",
    "DECISION_AUTO": "channel_config",
    "DFChannelConfig": "channel_config",
    "decision_rule": "channel_config",
    "DFChannelOutput": "channel_output",
    "CalibrationWindow": "calibration",
    "DFDesign": "calibration",
    "alignment_score": "calibration",
    "equalised_noise_variances": "calibration",
    "initial_state": "calibration",
    "window_pairs": "calibration",
    "DFDecision": "decision",
    "PaperRule": "paper_rule",
    "SequentialRule": "sequential_rule",
    "DFChannel": "channel",
}

__all__ = sorted(_EXPORTS)

__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
