"""The sequential decision rule for the detection-filter channel.

:class:`~gyrodiag.df.sequential_diagnosis.SequentialDiagnoser` behind
:class:`~gyrodiag.df.decision.DFDecision`: the sensor noise fitted to the calibration
window (with the gust model, or without it when its whitening fails), the CUSUM scales
calibrated there, and the diagnoser's output turned into the channel's codes.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from .calibration import CalibrationWindow, equalised_noise_variances, initial_state
from .channel_output import MULTIPLE, NONE_DETECTED, NOT_ISOLATED, DFChannelOutput
from .decision import DFDecision
from .generators import _gust_disturbance
from .gust import GustModel
from .residual import ResidualModel, estimate_sensor_variances
from .sequential_diagnosis import FaultKind, SequentialDiagnoser

__all__ = ["SequentialRule"]

_STATUS_CODES = {"none": NONE_DETECTED, "not isolated": NOT_ISOLATED, "pair": MULTIPLE,
                 "multiple": MULTIPLE}


class SequentialRule(DFDecision):
    """Whitened residuals, CUSUMs, hypothesis isolation, episodes (module notes)."""

    name: ClassVar[str] = "sequential"
    stacked: ClassVar[bool] = True

    def reset(self) -> None:
        """Not installed, no gust note."""
        self._gust_note = ""
        self.uninstall()

    def uninstall(self) -> None:
        """Drop the diagnoser and noise (the gust note of the last one stays)."""
        self._engine: SequentialDiagnoser | None = None
        self._noise_std = None

    @property
    def engine(self) -> SequentialDiagnoser | None:
        """The diagnoser (None until installed)."""
        return self._engine

    @property
    def cusum_thresholds(self) -> tuple[float, float] | None:
        """(mean-CUSUM threshold σ, variance-CUSUM threshold)."""
        return None if self._engine is None else self._engine.thresholds

    @property
    def gust_note(self) -> str:
        """Why the gust model is not in use ("" when it is, or none is configured)."""
        return self._gust_note

    @property
    def gust_in_use(self) -> bool:
        """The diagnoser models the turbulence."""
        return self._engine is not None and self._engine.gust is not None

    def _diagnoser(self, variances: NDArray[np.float64], gust: GustModel | None
                   ) -> SequentialDiagnoser:
        d = self.design
        return SequentialDiagnoser(d.A, d.B, d.C, d.K, d.T, variances,
                                   self.config.settings(), x0=d.x0, gust=gust)

    def install(self, window: CalibrationWindow | None) -> None:
        """Noise from the window (or configured), the diagnoser, its CUSUM scales."""
        c = self.config
        x_start = self.design.x0 if window is None else initial_state(self.design, window)
        variances = self._variances(window, x_start, c.gust)
        self._noise_std = np.sqrt(variances)
        try:
            engine = self._diagnoser(variances, c.gust)
            self._gust_note = ""
        except (ValueError, np.linalg.LinAlgError) as exc:
            if c.gust is None:
                raise
            # a gust far above the noise (a noise-free window, very slow sampling)
            # leaves no stable whitening: monitor without the turbulence model, with the
            # noise as that model explains the window
            variances = self._variances(window, x_start, None)
            self._noise_std = np.sqrt(variances)
            engine = self._diagnoser(variances, None)
            self._gust_note = (f"gust model not used (its whitening filter failed: {exc}); "
                               "turbulence may raise alarms")
        if window is not None:
            engine.calibrate_scales(np.hstack([window.u, window.y]), window.burn,
                                    x_start=x_start)
        self._engine = engine

    def _variances(self, window: CalibrationWindow | None, x_start: NDArray[np.float64],
                   gust: GustModel | None) -> NDArray[np.float64]:
        """Sensor noise variances: given, or those that explain the window's residuals
        (with the gust model ``gust`` if any)."""
        c, d = self.config, self.design
        if c.noise_std is not None:
            return np.asarray(c.noise_std, dtype=float) ** 2
        assert window is not None
        f = d.new_filter()
        model = ResidualModel(f.closed_loop_matrix, f.discrete_gain, d.C,
                              _gust_disturbance(gust, d.A, d.T, np.eye(d.n)))
        res = d.residuals(window.u, window.y, x_start)[window.burn:]
        known = (None if gust is None or c.sensor_dynamics is None
                 else equalised_noise_variances(window, c.sensor_dynamics))
        variances = estimate_sensor_variances(res, model, known)
        # A noise-free sensor would make rounding look like faults: floor at 1e−7 of the
        # signal's RMS (plus 1e−12 absolute).
        rms = np.sqrt(np.mean(window.y**2, axis=0))
        return np.maximum(variances, (1e-7 * rms + 1e-12) ** 2)

    def decide(self, u: NDArray[np.float64], y: NDArray[np.float64], delay: int
               ) -> DFChannelOutput:
        """One aligned sample through the diagnoser."""
        return self.decide_stacked(np.concatenate((u, y)), delay)

    def decide_stacked(self, w: NDArray[np.float64], delay: int) -> DFChannelOutput:
        """One sample stacked as (u, y) through the diagnoser."""
        engine = self._engine
        assert engine is not None
        out = engine.update(w)
        if out.status == "none":  # the per-sample case, without the lookups below
            return DFChannelOutput(
                True, False, out.residual, out.alarms, out.statistic, out.detected,
                out.episodes, NONE_DETECTED, 0, 0, 0.0, False, out.fault_type,
                out.magnitude, delay,
            )
        iso = out.isolated[0] + 1 if out.status == "single" else _STATUS_CODES[out.status]
        mask = sum(1 << i for i in out.isolated)
        types = out.fault_type
        if out.isolated:
            kinds = {int(types[i]) for i in out.isolated}
            ftype = kinds.pop() if len(kinds) == 1 else int(FaultKind.UNKNOWN)
        else:
            ftype = int(FaultKind.UNKNOWN) if out.status != "none" else 0
        valid = len(out.isolated) == 1 and bool(out.magnitude_valid[out.isolated[0]])
        mag = float(out.magnitude[out.isolated[0]]) if valid else 0.0
        return DFChannelOutput(
            True, False, out.residual, out.alarms, out.statistic, out.detected,
            out.episodes, iso, mask, ftype, mag, valid, types, out.magnitude, delay,
        )

    def get_state(self) -> dict[str, Any]:
        """Noise, the exact variances the diagnoser was built from, its state."""
        engine = self._engine
        assert engine is not None and self._noise_std is not None
        return {
            "noise_std": self._noise_std.copy(),
            "gust_note": self._gust_note,
            # the variances the engine was built from, exactly (σ² of a saved σ may
            # differ in the last bit, and so would every matrix designed from it)
            "noise_var": engine.sensor_variances.copy(),
            "engine": engine.get_state(),
            "thresholds": None,
            "threshold_stats": None,
        }

    def set_state(self, state: dict[str, Any], has_window: bool) -> None:
        """Rebuild the diagnoser from the saved variances (without the gust model if
        the saved note says so) and restore its state."""
        variances = np.asarray(state["noise_var"], dtype=float)
        self._gust_note = str(state.get("gust_note", ""))
        self._engine = self._diagnoser(variances, None if self._gust_note else self.config.gust)
        self._noise_std = np.asarray(state["noise_std"], dtype=float).copy()
        self._engine.set_state(state["engine"])
