"""Output record of the detection-filter channel, its codes and its saved form."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..common._records import fast_init

__all__ = ["DFChannelOutput"]

#: ``isolated_sensor`` values besides a sensor number (1-based).
NONE_DETECTED, NOT_ISOLATED, MULTIPLE = 0, -1, -2


@fast_init
@dataclass(frozen=True)
class DFChannelOutput:
    """Outputs of one :meth:`DFChannel.update`.

    Attributes
    ----------
    valid : bool
        False when u or y had NaN/Inf; the sample was skipped, state untouched.
    calibrating : bool
        The calibration window is still being recorded; no decision yet.
    residual : ndarray, shape (m,)
        Main detection-filter residual γ = y − C x̂ (sensor units).
    alarms : ndarray of bool, shape (m,)
        Per-sensor alarm of the main residual (paper: k-of-n threshold test;
        sequential: CUSUM).
    statistic : ndarray, shape (m,)
        Per sensor, the alarm statistic in units of its threshold (alarm at 1).
    detected : bool
        Paper: a fault was detected (latched). Sequential: a fault episode is on.
    episodes : int
        Fault episodes since reset.
    isolated_sensor : int
        1-based sensor of the diagnosis; 0 nothing detected; −1 detected, not
        isolated; −2 several sensors (see ``isolated_mask``; 0 there when they could
        not be told apart).
    isolated_mask : int
        Bit i−1 set for every isolated sensor i.
    fault_type : int
        Type of the isolated sensor's fault (:class:`FaultKind` code; for two sensors
        their common type, else −1).
    magnitude : float
        Its size (bias, gain factor, stuck value, 0 for failure, ramp rate per s, noise
        std ratio); 0 when ``magnitude_valid`` is False.
    magnitude_valid : bool
    sensor_fault_type : ndarray of int, shape (m,)
        Type per sensor (0 where none).
    sensor_magnitude : ndarray, shape (m,)
        Size per sensor (0 where none or unknown).
    input_delay : int
        Alignment in use (module notes).
    """

    valid: bool
    calibrating: bool
    residual: NDArray[np.float64]
    alarms: NDArray[np.bool_]
    statistic: NDArray[np.float64]
    detected: bool
    episodes: int
    isolated_sensor: int
    isolated_mask: int
    fault_type: int
    magnitude: float
    magnitude_valid: bool
    sensor_fault_type: NDArray[np.int_]
    sensor_magnitude: NDArray[np.float64]
    input_delay: int

    @property
    def alarm(self) -> bool:
        """Detected fault (the channel's alarm)."""
        return self.detected


def invalid_output(last: DFChannelOutput) -> DFChannelOutput:
    """``last`` with ``valid`` cleared (a skipped sample)."""
    d = dict(last.__dict__)
    d["valid"] = False
    return DFChannelOutput(**d)


def output_state(out: DFChannelOutput) -> dict[str, Any]:
    """``out`` as a dict of copies (the channel state's ``last``)."""
    return {k: (v.copy() if isinstance(v, np.ndarray) else v)
            for k, v in out.__dict__.items()}


def output_from_state(state: dict[str, Any]) -> DFChannelOutput:
    """The output saved by :func:`output_state`, with its types restored."""
    d = dict(state)
    for key, dtype in (("residual", float), ("alarms", bool), ("statistic", float),
                       ("sensor_fault_type", int), ("sensor_magnitude", float)):
        d[key] = np.asarray(d[key], dtype=dtype).copy()
    for key in ("valid", "calibrating", "detected", "magnitude_valid"):
        d[key] = bool(d[key])
    for key in ("episodes", "isolated_sensor", "isolated_mask", "fault_type",
                "input_delay"):
        d[key] = int(d[key])
    d["magnitude"] = float(d["magnitude"])
    return DFChannelOutput(**d)
