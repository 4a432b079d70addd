"""gyrodiag: gyro and flight-control sensor fault diagnosis algorithms.

Plain numpy/scipy/python-control classes with explicit state and no FMI knowledge;
the Diagnoser FMU facade only maps variables onto them. One package per method, and
one they share (importing ``gyrodiag`` imports none of them):

Packages
--------
dtg
    Dynamically tuned gyro: rotor model, case rate, nominal reference, response
    patterns and their learning, the paper's decision, the DTG channel.
grey
    GM(1,1), the moving-window grey predictors and the grey fault detector (HRG).
df
    Detection filter on the seed aircraft: plant, filter design, isolation, residual
    model, sensor dynamics, the sequential decision rule, observer gains, the DF
    channel.
common
    Shared: prefilter, estimators, CUSUM tests and their threshold table,
    distributions, validation, records and the per-sample kernels.

Modules
-------
demo
    A short end-to-end DTG identification demo (``python -m gyrodiag.demo``).
"""

__version__ = "0.1.0"
