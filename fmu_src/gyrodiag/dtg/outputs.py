"""Outputs of the DTG diagnosis channel (:class:`DTGChannelOutput`, with the block-rate
:class:`DTGDiagnosis`) and their plain-dict form for saved states."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..common._records import fast_init
from .model import N_THETA
from .reference import N_CHANNELS, N_TESTS, REFERENCE_STATUS

__all__ = ["DTGChannelOutput", "DTGDiagnosis"]

#: Reference status when the guard could not run (paper classifier, too little data).
STATUS_NOT_CHECKED = 4
#: Reference status when learning ended without any usable reference (no excitation in
#: the window, e.g. a host's default zero inputs): the channel never alarms.
STATUS_FAILED = 5
#: Feature output of the pattern classifier (it classifies no feature vector).
NO_FEATURE = np.zeros(N_THETA, dtype=np.int64)


@dataclass(frozen=True)
class DTGDiagnosis:
    """Block-rate outputs of the reference, the residual tests and the classification.

    Updated at the end of each reference block (``block`` counts the updates); the same
    object is shared by the samples in between.

    Attributes
    ----------
    reference_status : int
        :data:`~gyrodiag.dtg.reference.REFERENCE_STATUS` code (0 learning, 1 valid,
        2 change inside the learning window, 3 prior mismatch: prior in use), or
        :data:`STATUS_NOT_CHECKED` (4, paper classifier with too little data) or
        :data:`STATUS_FAILED` (5, no usable data in the learning window: no reference,
        no alarm).
    residual_alarm : bool
        The residual tests are in alarm (pattern classifier).
    class_name : str
        Name of the class in ``fault_code`` ("" none, "unknown").
    fault_type, fault_signal, fault_axis : int
        Codes of :data:`~gyrodiag.dtg.patterns.FAULT_TYPES` (1 step, 2 noise, 3 loss,
        4 drift, 5 spin, 6 torquer), :data:`~gyrodiag.dtg.patterns.SIGNALS` (1 Utx,
        2 Uty, 3 Ux, 4 Uy; 0 physical) and axes (1 x, 2 y, 3 both); 0 no alarm, −1
        unknown (``fault_signal`` −1 with two bits in ``signal_mask``: two signals).
    distance : float
        χ² per channel of the class (NaN if none).
    size, rate, ratio : float
        Estimated fault size (V), drift rate (V/s), physical ratio (NaN if undefined).
    level, log_variance : ndarray, shape (6,)
        Statistics of the test window (no alarm) or the classification window (alarm):
        level shift in block-spread units and log10 variance ratio of Utx, Uty, Ux, Uy,
        ex, ey.
    growth : float
        Growth of the residual level in that window (drift witness).
    window_s : float
        Length of that window, s.
    tests : ndarray, shape (8,)
        Residual test statistics: level z of ex, ey, short variance ratios of ex, ey,
        long variance ratios of ex, ey, low-frequency power CUSUMs of ex, ey over their
        threshold.
    block : int
        Update counter.
    signal_mask : int
        Signals named by the class, one bit each (1 Utx, 2 Uty, 4 Ux, 8 Uy).
    """

    reference_status: int = REFERENCE_STATUS["learning"]
    residual_alarm: bool = False
    class_name: str = ""
    fault_type: int = 0
    fault_signal: int = 0
    fault_axis: int = 0
    distance: float = math.nan
    size: float = math.nan
    rate: float = math.nan
    ratio: float = math.nan
    level: NDArray[np.float64] = field(default_factory=lambda: np.zeros(N_CHANNELS))
    log_variance: NDArray[np.float64] = field(default_factory=lambda: np.zeros(N_CHANNELS))
    growth: float = 0.0
    window_s: float = 0.0
    tests: NDArray[np.float64] = field(default_factory=lambda: np.zeros(N_TESTS))
    block: int = 0
    signal_mask: int = 0


@fast_init
@dataclass(frozen=True)
class DTGChannelOutput:
    """Outputs of one :meth:`DTGChannel.update`.

    Attributes
    ----------
    valid : bool
        False when this sample had a NaN/Inf input and was skipped (state untouched).
    learning : bool
        θ0 is still being learned; no decision yet.
    theta : ndarray, shape (2, 5)
        θ of the x axis (row 0) and y axis (row 1).
    eta : ndarray, shape (2, 5)
        Ratios |θ|/|θ0| per axis (ones while learning).
    physical : ndarray, shape (5,)
        [c/J (1/s), k/J (1/s²), L/J (rad/s), λ/J (1/s²), Ku/(KT·J) (1/s²)] from the mean
        θ of both axes (NaN where the inversion is undefined).
    alarm : bool
        Any axis in alarm.
    fault_code : int
        0 no alarm, 1… signature index, ``UNKNOWN_CODE`` (−1) unclassified.
    feature : ndarray of int, shape (5,)
        Feature vector C that is classified: at each sample, C of the axis with the
        larger Σ|C_i|; in alarm, the median of those over the alarm samples of the last
        ``classify_window_s``.
    first_alarm_time_s : float
        Time of the first alarm since reset, s (NaN if none).
    diagnosis : DTGDiagnosis
        Reference, residual tests and pattern classification (block rate).
    """

    valid: bool
    learning: bool
    theta: NDArray[np.float64]
    eta: NDArray[np.float64]
    physical: NDArray[np.float64]
    alarm: bool
    fault_code: int
    feature: NDArray[np.int64]
    first_alarm_time_s: float
    diagnosis: DTGDiagnosis = field(default_factory=DTGDiagnosis)


def replace_output(out: DTGChannelOutput, **changes: Any) -> DTGChannelOutput:
    """``out`` with ``changes`` (field name → value), arrays copied."""
    d = output_to_dict(out)
    d.update(changes)
    return output_from_dict(d, out.diagnosis)


def output_to_dict(out: DTGChannelOutput) -> dict[str, Any]:
    """Plain dict of ``out`` without its diagnosis (saved states)."""
    return {
        "valid": out.valid, "learning": out.learning, "theta": out.theta.copy(),
        "eta": out.eta.copy(), "physical": out.physical.copy(), "alarm": out.alarm,
        "fault_code": out.fault_code, "feature": out.feature.copy(),
        "first_alarm_time_s": out.first_alarm_time_s,
    }


def output_from_dict(d: dict[str, Any], diagnosis: DTGDiagnosis) -> DTGChannelOutput:
    """Inverse of :func:`output_to_dict`, with ``diagnosis``."""
    return DTGChannelOutput(
        valid=bool(d["valid"]), learning=bool(d["learning"]),
        theta=np.asarray(d["theta"], dtype=float).reshape(2, N_THETA),
        eta=np.asarray(d["eta"], dtype=float).reshape(2, N_THETA),
        physical=np.asarray(d["physical"], dtype=float).reshape(N_THETA),
        alarm=bool(d["alarm"]), fault_code=int(d["fault_code"]),
        feature=np.asarray(d["feature"], dtype=np.int64).reshape(N_THETA),
        first_alarm_time_s=float(d["first_alarm_time_s"]), diagnosis=diagnosis,
    )


def diagnosis_to_dict(d: DTGDiagnosis) -> dict[str, Any]:
    """Plain dict of ``d`` (saved states)."""
    return {
        "reference_status": d.reference_status, "residual_alarm": d.residual_alarm,
        "class_name": d.class_name, "fault_type": d.fault_type,
        "fault_signal": d.fault_signal, "fault_axis": d.fault_axis, "distance": d.distance,
        "size": d.size, "rate": d.rate, "ratio": d.ratio, "level": d.level.copy(),
        "log_variance": d.log_variance.copy(), "growth": d.growth, "window_s": d.window_s,
        "tests": d.tests.copy(), "block": d.block, "signal_mask": d.signal_mask,
    }


def diagnosis_from_dict(d: dict[str, Any]) -> DTGDiagnosis:
    """Inverse of :func:`diagnosis_to_dict`."""
    return DTGDiagnosis(
        reference_status=int(d["reference_status"]), residual_alarm=bool(d["residual_alarm"]),
        class_name=str(d["class_name"]), fault_type=int(d["fault_type"]),
        fault_signal=int(d["fault_signal"]), fault_axis=int(d["fault_axis"]),
        distance=float(d["distance"]), size=float(d["size"]), rate=float(d["rate"]),
        ratio=float(d["ratio"]),
        level=np.asarray(d["level"], dtype=float).reshape(N_CHANNELS),
        log_variance=np.asarray(d["log_variance"], dtype=float).reshape(N_CHANNELS),
        growth=float(d["growth"]), window_s=float(d["window_s"]),
        tests=np.asarray(d["tests"], dtype=float).reshape(N_TESTS), block=int(d["block"]),
        signal_mask=int(d["signal_mask"]),
    )
