"""The paper's decision rule for the detection-filter channel.

Per-sample k·σ thresholds with k-of-n persistence on the detection filter's residual,
isolation by the generalised observer scheme, detection latched
(:class:`~gyrodiag.df.isolation.SensorFaultIsolator`), behind
:class:`~gyrodiag.df.decision.DFDecision`.
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from .calibration import CalibrationWindow
from .channel_output import NONE_DETECTED, NOT_ISOLATED, DFChannelOutput
from .decision import DFDecision
from .filter import ResidualThresholds
from .isolation import SensorFaultIsolator

__all__ = ["PaperRule"]


class PaperRule(DFDecision):
    """k·σ thresholds, observer-bank isolation, latched detection (module notes)."""

    name: ClassVar[str] = "paper"

    def uninstall(self) -> None:
        """Drop the isolator, noise and thresholds."""
        self._engine: SensorFaultIsolator | None = None
        self._thresholds: list[NDArray[np.float64]] | None = None
        self._noise_std = None

    @property
    def engine(self) -> SensorFaultIsolator | None:
        """The isolator (None until installed)."""
        return self._engine

    @property
    def thresholds(self) -> list[NDArray[np.float64]] | None:
        """Residual thresholds, main filter first, then observer j."""
        return self._thresholds

    def _isolator(self) -> SensorFaultIsolator:
        c, d = self.config, self.design
        return SensorFaultIsolator(
            d.A, d.B, d.C, d.K, d.T, persistence_k=c.persistence_k,
            persistence_n=c.persistence_n, confirm_samples=c.confirm_samples,
            energy_window_s=c.isolation_window_in_use,
            energy_baseline_s=c.isolation_baseline_s)

    def install(self, window: CalibrationWindow | None) -> None:
        """Thresholds from the window's residuals (k_sigma), or the configured ones."""
        c = self.config
        iso = self._isolator()
        if window is None:
            k = float(c.k_sigma)
            main = np.asarray(c.main_thresholds, dtype=float)
            bank = np.asarray(c.bank_thresholds, dtype=float)
            std = main / k if c.noise_std is None else np.asarray(c.noise_std, float)
            thresholds = [_thresholds(main, k)] + [_thresholds(row, k) for row in bank]
            iso.set_thresholds(thresholds[0], thresholds[1:], std)
            iso.reset(self.design.x0)
            self._noise_std = std
        else:
            # The same computation the streaming filters would do: run them over the
            # window, thresholds from the residuals after the burn-in, then go on.
            iso.calibrate(window.u, window.y, k_sigma=c.k_sigma, burn_in=window.burn,
                          x0=self.design.x0, continue_after=True)
            self._noise_std = iso.noise_std
        self._thresholds = [iso.main_thresholds.threshold] + [
            t.threshold for t in iso.bank_thresholds]
        self._engine = iso

    def decide(self, u: NDArray[np.float64], y: NDArray[np.float64], delay: int
               ) -> DFChannelOutput:
        """One sample through the isolator (the channel checked it)."""
        engine = self._engine
        assert engine is not None
        m = self.design.m
        res = engine.advance(u, y)
        residual = engine.main_filter.residual
        if res.isolated >= 0:
            iso = res.isolated + 1
        else:
            iso = NOT_ISOLATED if res.detected else NONE_DETECTED
        mask = (1 << res.isolated) if res.isolated >= 0 else 0
        sensor_types = np.zeros(m, dtype=int)
        sensor_mags = np.zeros(m)
        valid = bool(math.isfinite(res.magnitude)) and res.isolated >= 0
        if res.isolated >= 0:
            sensor_types[res.isolated] = int(res.fault_type)
            sensor_mags[res.isolated] = res.magnitude if valid else 0.0
        return DFChannelOutput(
            True, False, residual, res.main_alarms, np.abs(res.main_normalised),
            res.detected, int(res.detected), iso, mask, int(res.fault_type),
            float(res.magnitude) if valid else 0.0, valid, sensor_types, sensor_mags,
            delay,
        )

    def get_state(self) -> dict[str, Any]:
        """Noise, isolator state, thresholds and their residual statistics."""
        engine = self._engine
        assert engine is not None and self._noise_std is not None
        return {
            "noise_std": self._noise_std.copy(),
            "gust_note": "",
            "noise_var": None,
            "engine": engine.get_state(),
            "thresholds": None if self._thresholds is None else [
                t.copy() for t in self._thresholds],
            # the residual statistics (mean, std) beside the thresholds: the evaluators
            # normalise by the mean, the energy isolation by the std as well
            "threshold_stats": (
                [[t.mean.copy(), t.std.copy()] for t in
                 [engine.main_thresholds, *engine.bank_thresholds]]
                if self._thresholds is not None else None),
        }

    def set_state(self, state: dict[str, Any], has_window: bool) -> None:
        """Rebuild the isolator from the saved thresholds (or the configured ones,
        without a window) and restore its state."""
        if has_window:
            self._rebuild(state)
        else:
            self.install(None)
        assert self._engine is not None
        self._engine.set_state(state["engine"])

    def _rebuild(self, state: dict[str, Any]) -> None:
        thresholds = [np.asarray(t, dtype=float) for t in state["thresholds"]]
        noise = np.asarray(state["noise_std"], dtype=float)
        iso = self._isolator()
        k = float(self.config.k_sigma)
        stats = state["threshold_stats"]
        if stats is None:  # none saved (state version 0): rebuilt from the thresholds
            rebuilt = [_thresholds(t, k) for t in thresholds]
        else:
            if len(stats) != len(thresholds):
                raise ValueError("state['threshold_stats'] must hold one (mean, std) per "
                                 "threshold vector")
            rebuilt = [ResidualThresholds(mean=np.asarray(ms[0], dtype=float),
                                          std=np.asarray(ms[1], dtype=float),
                                          threshold=t, k_sigma=k)
                       for ms, t in zip(stats, thresholds, strict=True)]
        iso.set_thresholds(rebuilt[0], rebuilt[1:], noise)
        self._engine, self._thresholds, self._noise_std = iso, thresholds, noise


def _thresholds(threshold: NDArray[np.float64], k_sigma: float) -> ResidualThresholds:
    """Zero-mean thresholds ``threshold`` at ``k_sigma`` (σ = threshold / k)."""
    thr = np.asarray(threshold, dtype=float)
    return ResidualThresholds(
        mean=np.zeros_like(thr), std=thr / k_sigma, threshold=thr, k_sigma=k_sigma
    )
