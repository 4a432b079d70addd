"""The paper's classifier of the DTG channel (``classifier="paper"``).

θ0 is the mean θ over the learning window (unless given); each axis is judged by the
ratio band on η = |θ|/|θ0| and an alarm is classified by the nearest decade signature
C = round(log10 η), optionally the median C over the alarm samples of the last
``classify_window_s``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from .classifier import ChannelClassifier, names_class
from .decision import (
    UNKNOWN_CODE,
    SignatureClassifier,
    WindowedMedianFeature,
    feature_floats,
)
from .model import N_THETA
from .outputs import STATUS_NOT_CHECKED, DTGDiagnosis

if TYPE_CHECKING:
    from .channel import DTGChannel
    from .reference import NominalReference

__all__ = ["PaperRule"]


class PaperRule(ChannelClassifier):
    """Ratio band alarms classified by decade signatures (the paper's rule).

    Parameters
    ----------
    host : DTGChannel
        The channel it classifies for.
    """

    kind = "paper"
    # the paper classifier does not need the reference: report it unchecked
    failed_status = STATUS_NOT_CHECKED

    def __init__(self, host: DTGChannel) -> None:
        super().__init__(host)
        c = host.config
        self._window = round(c.classify_window_s / host.T) + 1
        self._theta0_shape = host.theta0_shape
        self.reset()

    def reset(self) -> None:
        """Return to the state right after construction."""
        c = self.host.config
        self._signatures = (
            SignatureClassifier(c.signatures, c.max_distance) if c.signatures else None
        )
        # both ends of the window, as the training window of gyrodiag_harness.campaigns.signatures
        self._features = WindowedMedianFeature(N_THETA, self._window)
        self._learn_sum = np.zeros(self._theta0_shape)
        self._learn_count = 0

    def learn(self, t: float, theta: NDArray[np.float64]) -> NDArray[np.float64] | None:
        """Sum θ (shape (2, 5)) over the learning window; its mean once ``t`` (s) has
        passed the window's end, None before and when it has a zero entry."""
        c = self.host.config
        if c.learn_start_s <= t < c.learn_end_s:
            self._learn_sum += theta if c.case_rate is not None else theta.mean(axis=0)
            self._learn_count += 1
        elif t >= c.learn_end_s and self._learn_count > 0:
            theta0 = self._learn_sum / self._learn_count
            self._learn_count = 0
            if np.any(theta0 == 0.0):
                # No excitation in the learning window (e.g. a host's default zero
                # inputs): no reference, so no ratios and no alarm, rather than a failure
                # of every later sample. See reference_failed.
                return None
            return theta0
        return None

    def reference_failed(self) -> bool:
        """True once the learning window has ended without a θ0 (a zero entry: no
        excitation)."""
        host = self.host
        return (host.theta0 is None and self._learn_count == 0
                and host.samples * host.T > host.config.learn_end_s)

    def decide(self, t: float, eta: Sequence[list[float]], band_alarm: bool,
               block_done: bool) -> tuple[bool, int, NDArray[np.int64], DTGDiagnosis]:
        """The band's alarm, classified by the feature of the axis with the larger
        Σ|C_i| (x on a tie), windowed when ``classify_window_s`` > 0."""
        alarm = band_alarm
        fx, fy = feature_floats(eta[0]), feature_floats(eta[1])
        feature = fy if sum(map(abs, fy)) > sum(map(abs, fx)) else fx
        windowed = self._features.window > 1
        if windowed:  # window 1 (the paper's rule) needs no history
            self._features.update(feature, alarm)
        code = 0
        if alarm:
            if windowed:
                feature = self._features.median()
            code = (
                self._signatures.classify(feature).code
                if self._signatures is not None
                else UNKNOWN_CODE
            )
        return alarm, code, np.array(feature, dtype=np.int64), self.host.diagnosis

    def class_name(self, code: int) -> str:
        """Name of a ``fault_code`` in the signature table."""
        return names_class(list(self.host.config.signatures), code)

    def get_state(self) -> dict[str, Any]:
        """Windowed features and the θ0 learning sums."""
        return {"features": self._features.get_state(),
                "learn_sum": self._learn_sum.copy(), "learn_count": self._learn_count}

    def set_state(self, state: dict[str, Any],
                  reference: NominalReference | None) -> None:
        """Restore :meth:`get_state` (another ``classify_window_s`` raises first)."""
        try:
            self._features.set_state(state["features"])
        except ValueError as exc:
            raise ValueError(f"state['features'] (classify_window_s): {exc}") from exc
        self._learn_sum = np.asarray(state["learn_sum"], dtype=float).copy()
        self._learn_count = int(state["learn_count"])
