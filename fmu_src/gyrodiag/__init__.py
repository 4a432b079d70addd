"""gyrodiag: gyro and flight-control sensor fault diagnosis algorithms.

Plain numpy/scipy/python-control classes with explicit state and no FMI knowledge;
the Diagnoser FMU facade only maps variables onto them.

Modules
-------
prefilter
    Streaming Butterworth low-pass (second-order sections with carried state).
dtg
    Dynamically tuned gyro rotor model: regressors, θ ↔ physical parameters.
estimators
    Sliding-window batch least squares, RLS, RLS with forgetting factor.
decision
    Ratio thresholds, log10 feature vectors, nearest-signature classification.
grey
    GM(1,1) and the improved moving-window grey predictor and detector (HRG).
detection_filter, isolation, aircraft
    Beard–Jones detection filter, residual thresholds, isolability analysis and sensor
    fault isolation on the seed aircraft.
"""

__version__ = "0.1.0"
