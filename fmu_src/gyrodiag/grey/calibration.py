"""Calibration of the grey channel's learned rules on a fault-free start.

:class:`ErrorScale` learns σ_e, the standard deviation of the one-step prediction error,
from the calibration window and keeps refining it on the samples judged fault-free;
:class:`PredictorChoice` runs candidate predictors beside the configured one over the
same window and keeps the one with the least error.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..common._distributions import chi2_ppf
from .predictor import GreyPredictor

__all__ = ["ErrorScale", "PredictorChoice", "calibrated_sigma"]


def calibrated_sigma(errors: NDArray[np.float64]) -> float:
    """Standard deviation of fault-free prediction errors, made robust and safe.

    The errors are winsorised at 5 robust σ (1.4826 × MAD) so that one outlier does not
    inflate it, and the root mean square is raised to its one-sided 95 % upper
    confidence bound (χ², N samples), since a threshold set from an underestimated σ
    false-alarms (on 40 samples the bound is 1.23 σ̂). Same units as ``errors``.
    """
    n = errors.size
    centre = float(np.median(errors))
    robust = 1.4826 * float(np.median(np.abs(errors - centre)))
    if robust > 0.0:
        errors = np.clip(errors, centre - 5.0 * robust, centre + 5.0 * robust)
    rms = math.sqrt(float(np.mean((errors - centre) ** 2)))
    return rms * math.sqrt(n / chi2_ppf(0.05, n))


class ErrorScale:
    """σ_e of the one-step prediction error (signal units), learned then refined.

    Parameters
    ----------
    samples : int
        Errors the calibration window holds (0: nothing is learned).
    floor : float
        Smallest σ_e allowed, signal units (threshold floor / k_sigma).
    suspicion_sigma : float
        Samples beyond this many σ_e are not judged fault-free, so the refinement sees
        a truncated normal law.
    """

    def __init__(self, samples: int, floor: float, suspicion_sigma: float) -> None:
        self.samples = samples
        self.floor = floor
        self.suspicion_sigma = suspicion_sigma
        self.reset()

    def reset(self) -> None:
        """Forget σ_e and the calibration errors."""
        self._errors: list[float] = []
        self.sigma = math.nan
        """σ_e, signal units; NaN while learning."""
        self._sq_sum = 0.0  # squared errors judged fault-free (refinement)
        self._sq_n = 0

    @property
    def learning(self) -> bool:
        """σ_e is not known yet."""
        return math.isnan(self.sigma)

    def collect(self, error: float) -> bool:
        """Add a calibration error (signal units; non-finite ones are left out); True
        when the window is full."""
        if math.isfinite(error):
            self._errors.append(error)
        return len(self._errors) >= self.samples

    def square_sum(self) -> float:
        """Sum of the squared calibration errors, signal units²."""
        return float(np.sum(np.square(self._errors)))

    def rescale(self, factor: float) -> None:
        """Scale the calibration errors (another predictor's were smaller)."""
        self._errors = [e * factor for e in self._errors]

    def learn(self) -> None:
        """End of calibration: σ_e from the collected errors (:func:`calibrated_sigma`,
        at least ``floor``)."""
        e = np.asarray(self._errors)
        self.sigma = max(calibrated_sigma(e), self.floor)
        centre = float(np.median(e))
        self._sq_sum = float(np.sum((e - centre) ** 2))
        self._sq_n = e.size
        self._errors = []

    def refine(self, error: float) -> None:
        """σ_e learns from a sample judged fault-free (error in signal units).

        Such samples are only those within ``suspicion_sigma``, whose mean square is
        that fraction of the full variance (a truncated normal), and the
        upper-confidence factor shrinks as they add up; σ_e never falls below the
        calibration window's point estimate by more than the noise of the estimate
        allows, and never below the floor.
        """
        if not math.isfinite(error):
            return
        self._sq_sum += error * error
        self._sq_n += 1
        s = self.suspicion_sigma
        # E[z² | |z| < s] for z ~ N(0, 1)
        from scipy.special import erf

        kept = erf(s / math.sqrt(2.0))
        truncated = 1.0 - 2.0 * s * math.exp(-0.5 * s * s) / math.sqrt(2.0 * math.pi) / kept
        n = self._sq_n
        rms = math.sqrt(self._sq_sum / n / truncated)
        self.sigma = max(rms * math.sqrt(n / chi2_ppf(0.05, n)), self.floor)

    def get_state(self) -> dict[str, Any]:
        """State as a flat plain dict."""
        return {"cal_errors": np.asarray(self._errors, dtype=float),
                "sigma": float(self.sigma), "sq_sum": float(self._sq_sum),
                "sq_n": int(self._sq_n)}

    def set_state(self, state: Mapping[str, Any]) -> None:
        """Restore :meth:`get_state`."""
        self._errors = [float(x) for x in np.asarray(state["cal_errors"]).reshape(-1)]
        self.sigma = float(state["sigma"])
        self._sq_sum = float(state["sq_sum"])
        self._sq_n = int(state["sq_n"])


class PredictorChoice:
    """Candidate predictors compared with the configured one on the calibration window.

    Parameters
    ----------
    candidates : sequence of predictors
        Run beside the configured predictor; their squared one-step errors (signal
        units²) add up from their first prediction on.
    """

    def __init__(self, candidates: Sequence[GreyPredictor]) -> None:
        self.candidates = list(candidates)
        self.reset()

    def reset(self) -> None:
        """Reset the candidates and their errors; the configured predictor is chosen."""
        for cand in self.candidates:
            cand.reset()
        self.pending = [math.nan] * len(self.candidates)
        self._sq = [0.0] * len(self.candidates)
        self.chosen = 0
        """0: the configured predictor is in use, i: ``candidates[i − 1]``."""

    def feed(self, value: float) -> None:
        """A calibration sample (signal units) for every candidate."""
        for i, cand in enumerate(self.candidates):
            previous = self.pending[i]
            if math.isfinite(previous):
                self._sq[i] += (value - previous) ** 2
            self.pending[i] = cand.update(value)

    def choose(self, own_square_sum: float) -> tuple[int, float]:
        """End of calibration: keep the candidate with the least squared error if it is
        below ``own_square_sum`` (the configured predictor's; it wins ties).

        Returns
        -------
        chosen : int
            :attr:`chosen`: 0 for the configured predictor, i for ``candidates[i − 1]``.
        ratio : float
            The chosen candidate's root-sum-square error over the configured one's
            (1 when the configured one stays).
        """
        best = min(range(len(self.candidates)), key=self._sq.__getitem__)
        if self._sq[best] < own_square_sum:
            self.chosen = best + 1
            ratio = (math.sqrt(self._sq[best] / own_square_sum) if own_square_sum > 0.0
                     else 1.0)
            return self.chosen, ratio
        return 0, 1.0

    def get_state(self) -> dict[str, Any]:
        """State as a flat plain dict (``candidate{i}.`` prefixes the candidates')."""
        state: dict[str, Any] = {
            "chosen": int(self.chosen),
            "cand_pending": np.asarray(self.pending, dtype=float),
            "cand_sq": np.asarray(self._sq, dtype=float),
        }
        for i, cand in enumerate(self.candidates):
            for key, val in cand.get_state().items():
                state[f"candidate{i}.{key}"] = copy.deepcopy(val)
        return state

    def set_state(self, state: Mapping[str, Any]) -> None:
        """Restore :meth:`get_state`.

        Raises
        ------
        ValueError
            If ``state['chosen']`` names no candidate.
        """
        chosen = int(state["chosen"])
        if not 0 <= chosen <= len(self.candidates):
            raise ValueError(f"state['chosen'] must be in [0, {len(self.candidates)}]")
        for i, cand in enumerate(self.candidates):
            pre = f"candidate{i}."
            cand.set_state({k[len(pre):]: copy.deepcopy(v) for k, v in state.items()
                            if k.startswith(pre)})
        self.chosen = chosen
        self.pending = [float(x) for x in np.asarray(state["cand_pending"]).reshape(-1)]
        self._sq = [float(x) for x in np.asarray(state["cand_sq"]).reshape(-1)]
