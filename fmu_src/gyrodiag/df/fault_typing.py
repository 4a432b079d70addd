"""Fault typing of the sequential diagnosis: which fault model explains the main
filter's whitened residual z since the change time, and how big the fault is.

Typing is a generalised likelihood ratio on z, fitted on the running sums of the fault
signatures (:mod:`gyrodiag.df.signatures`): z⁰ is white N(0, I), so least squares is
the maximum-likelihood fit and differences of residual sums of squares are χ² tests,
whatever the colour of the detection filter's own residual. This uses every sensor, not
only a fault-free estimate of the faulty one (the pitch rate's estimate from the other
sensors has 42 times the sensor noise at low frequency on the seed aircraft).

The models compared per isolated sensor (penalised likelihood): a bias, a ramp, a gain
(f̂ = (g − 1)·ŷ) and an intermittent bias (a bias the previous episode of the record
found too); a constant output is stuck (0: complete failure); a variance well above
nominal that no mean model explains is a noise increase. The type found also chooses
how the episode follows the fault's presence (``PRESENCE_*``).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..common._validation import check_finite_array
from .settings import FaultKind, SequentialSettings
from .signatures import N_REG, REG_BIAS, REG_GAIN, REG_RAMP, FaultSignatures

__all__ = ["PRESENCE_CONSTANT", "PRESENCE_MODEL", "PRESENCE_NONE", "PRESENCE_VARIANCE",
           "FaultTyper"]

_FloatArray = NDArray[np.float64]

#: How the presence of an isolated fault is followed: not (the main alarm decides), by
#: the fitted mean model, by the variance, by the constant output.
PRESENCE_NONE, PRESENCE_MODEL, PRESENCE_VARIANCE, PRESENCE_CONSTANT = range(4)


_BIASES = (int(FaultKind.BIAS), int(FaultKind.INTERMITTENT))
_RICHER = (int(FaultKind.RAMP), int(FaultKind.GAIN))


class FaultTyper:
    """The fault types and sizes of the isolated sensors (module notes).

    Parameters
    ----------
    signatures : FaultSignatures
        The record's signature sums the fits use (the diagnoser feeds them).
    sensor_variances : ndarray, shape (m,)
        Sensor noise variances, sensor units squared.
    settings : SequentialSettings

    Attributes
    ----------
    types, mags, mag_valid : ndarray, shape (m,)
        :class:`FaultKind` code, size and its validity per sensor (the diagnosis).
    presence_mode : int
        ``PRESENCE_*``: how the fault found is followed.
    """

    def __init__(self, signatures: FaultSignatures, sensor_variances: _FloatArray,
                 settings: SequentialSettings) -> None:
        self.signatures = signatures
        self.m = signatures.m
        self.sensor_variances = sensor_variances
        self.settings = settings
        self._type_min = max(2, round(settings.type_min_s / signatures.T))

    def reset(self) -> None:
        """No diagnosis, no previous episode."""
        m = self.m
        self.previous: tuple[tuple[int, ...], NDArray[np.int_], _FloatArray] = (
            (), np.zeros(m, dtype=int), np.zeros(m))
        self._model_cols = np.zeros(0, dtype=int)
        self._theta = np.zeros(0)
        self.presence_mode = PRESENCE_NONE
        self.types = np.zeros(m, dtype=int)
        self.mags = np.zeros(m)
        self.mag_valid = np.zeros(m, dtype=bool)

    def model_misfit(self) -> tuple[_FloatArray, _FloatArray]:
        """(z of the last sample less the fitted fault model's signature in it, that
        signature)."""
        return self.signatures.misfit(self._model_cols, self._theta)

    def fault_trace(self, gone: int) -> _FloatArray | None:
        """The fitted fault's trace in the main filter's state, None without a fitted
        model (``gone``: see :meth:`FaultSignatures.trace`)."""
        if not self._model_cols.size:
            return None
        return self.signatures.trace(self._model_cols, self._theta, gone)

    # ------------------------------------------------------------------ diagnosis

    def clear(self) -> None:
        """No type, no fitted model, presence not followed."""
        self.types[:] = int(FaultKind.NONE)
        self.mags[:] = 0.0
        self.mag_valid[:] = False
        self._model_cols = np.zeros(0, dtype=int)
        self._theta = np.zeros(0)
        self.presence_mode = PRESENCE_NONE

    def remember(self, isolated: tuple[int, ...] | None) -> None:
        """Keep the diagnosis of ``isolated`` as the previous episode's (None: no
        previous episode)."""
        if isolated is None:
            self.previous = ((), np.zeros(self.m, dtype=int), np.zeros(self.m))
        else:
            self.previous = (isolated, self.types.copy(), self.mags.copy())

    def type(self, k: int, isolated: tuple[int, ...], record_episodes: int,
             constant_output: Callable[[int, int], float | None], hold: bool) -> bool:
        """Fault type and size of every isolated sensor at sample k (module notes).

        A fitted mean model is kept while a new fit is worse than "typed": the misfit
        that follows the end of the fault is the presence test's to judge; ``hold``
        (the presence test is judging a misfit): no refit under it.
        ``constant_output(sensor, k)``: the sensor's constant output or None.

        Returns
        -------
        bool
            The presence test goes on (False: the way of following it changed).
        """
        if self.presence_mode == PRESENCE_MODEL:
            if hold:
                return True
            saved = self._snapshot()
            same = self._type_now(k, isolated, record_episodes, constant_output)
            if self.presence_mode == PRESENCE_NONE:
                self._restore(saved)
            return same
        return self._type_now(k, isolated, record_episodes, constant_output)

    def refit_richer(self, k: int, isolated: tuple[int, ...], record_episodes: int,
                     constant_output: Callable[[int, int], float | None]) -> bool:
        """Refit a fault that outgrew its fitted mean model; keep the refit only if it
        turns a sensor's bias into a ramp or a gain (True), else the model as it was."""
        saved = self._snapshot()
        self._type_now(k, isolated, record_episodes, constant_output)
        richer = self.presence_mode == PRESENCE_MODEL and any(
            int(saved[0][i]) in _BIASES and int(self.types[i]) in _RICHER for i in isolated)
        if not richer:
            self._restore(saved)
        return richer

    def _snapshot(self) -> tuple[Any, ...]:
        """The diagnosis and fitted model (copies), for :meth:`_restore`."""
        return (self.types.copy(), self.mags.copy(), self.mag_valid.copy(),
                self._model_cols.copy(), self._theta.copy(), self.presence_mode)

    def _restore(self, saved: tuple[Any, ...]) -> None:
        (self.types, self.mags, self.mag_valid, self._model_cols, self._theta,
         self.presence_mode) = saved

    def _type_now(self, k: int, isolated: tuple[int, ...], record_episodes: int,
                  constant_output: Callable[[int, int], float | None]) -> bool:
        mode = self.presence_mode
        self.clear()
        self._fit_types(k, isolated, record_episodes, constant_output)
        return self.presence_mode == mode

    def _fit_types(self, k: int, sensors: tuple[int, ...], record_episodes: int,
                   constant_output: Callable[[int, int], float | None]) -> None:
        if not sensors:
            return
        constant = {i: constant_output(i, k) for i in sensors}
        if self.signatures.n_after < self._type_min:
            for i in sensors:
                self.types[i] = int(FaultKind.UNKNOWN)
            return
        n_rec = self.signatures.n_rec
        tau0 = self.settings.type_significance
        choice, explained_bias, theta, rss_c = self._choose_models(sensors)
        cols = _columns(sensors, choice)
        level_c = rss_c / n_rec
        worst = float(level_c.max())
        noisy = worst > 1.0 + max(0.2, 6.0 * math.sqrt(2.0 / n_rec))
        pos = 0
        for i in sensors:
            kinds = choice[i]
            values = theta[pos:pos + len(kinds)]
            pos += len(kinds)
            if constant[i] is not None:
                value = constant[i]
                kind = FaultKind.FAILURE if abs(value) <= 3.0 * math.sqrt(
                    self.sensor_variances[i]) else FaultKind.STUCK
                self._set_type(i, kind, 0.0 if kind is FaultKind.FAILURE else value)
                continue
            if noisy:
                if explained_bias < tau0 * worst and kinds == [REG_BIAS]:
                    self._set_type(i, FaultKind.NOISE, self.signatures.noise_ratio(i, level_c))
                else:
                    self.types[i] = int(FaultKind.UNKNOWN)
                continue
            if kinds == [REG_BIAS, REG_RAMP]:
                self._set_type(i, FaultKind.RAMP, float(values[1]))
            elif kinds == [REG_BIAS, REG_GAIN]:
                c = float(values[1])
                self._set_type(i, FaultKind.GAIN, 1.0 / (1.0 - c) if c < 1.0 else math.inf)
            elif self._repeats_bias(i, float(values[0]), sensors, record_episodes):
                self._set_type(i, FaultKind.INTERMITTENT, float(values[0]))
            else:
                self._set_type(i, FaultKind.BIAS, float(values[0]))
        self._model_cols, self._theta = np.array(cols, dtype=int), theta
        self._choose_presence(sensors)

    def _choose_models(self, sensors: tuple[int, ...]
                       ) -> tuple[dict[int, list[int]], float, _FloatArray, _FloatArray]:
        """(regressors per sensor, zᵀz the bias model explains, and the chosen model's
        θ and per-channel residual sums of squares, :meth:`FaultSignatures.fit`).

        Greedy model building: a bias on every isolated sensor, then each sensor's
        richer model where the likelihood ratio says so. z is white N(0, 1) per channel
        when the model fits, but a noise increase raises the variance of the channels
        the faulty sensor feeds: an improvement counts only against the largest
        per-channel residual variance of the model it improves on (else a larger noise
        would make chance improvements look significant).
        """
        n_rec = self.signatures.n_rec
        tau0 = self.settings.type_significance
        choice = {i: [REG_BIAS] for i in sensors}
        rss_base, theta, rss_c = self.signatures.fit(_columns(sensors, choice))
        explained_bias = self.signatures.energy - rss_base
        for i in sensors:
            alternatives = [[REG_BIAS, REG_RAMP]]
            if self.signatures.gain_identifiable(i):
                alternatives.append([REG_BIAS, REG_GAIN])
            tau = tau0 * max(1.0, float(rss_c.max()) / n_rec)
            best = (rss_base, choice[i], theta, rss_c)
            for alt in alternatives:
                rss, theta_alt, rss_alt = self.signatures.fit(
                    _columns(sensors, {**choice, i: alt}))
                if rss_base - rss > tau and rss < best[0]:
                    best = (rss, alt, theta_alt, rss_alt)
            rss_base, choice[i], theta, rss_c = best
        # the fit of the model chosen (the same sums: the fit the caller needs)
        return choice, explained_bias, theta, rss_c

    def _choose_presence(self, sensors: tuple[int, ...]) -> None:
        """How the episode follows the fault of these types."""
        types = [FaultKind(int(self.types[i])) for i in sensors]
        if all(t in (FaultKind.STUCK, FaultKind.FAILURE) for t in types):
            self.presence_mode = PRESENCE_CONSTANT
        elif all(t is FaultKind.NOISE for t in types):
            self.presence_mode = PRESENCE_VARIANCE
        elif all(t in (FaultKind.BIAS, FaultKind.RAMP, FaultKind.GAIN,
                       FaultKind.INTERMITTENT) for t in types):
            self.presence_mode = PRESENCE_MODEL
        # else (a type unknown, or kinds mixed): the main alarm decides

    def _repeats_bias(self, sensor: int, value: float, isolated: tuple[int, ...],
                      record_episodes: int) -> bool:
        """The previous episode of this record isolated the same sensors and found a
        bias (or intermittent bias) of about the same size on this sensor."""
        sensors, types, mags = self.previous
        return (record_episodes >= 2 and tuple(sensors) == isolated
                and int(types[sensor]) in (FaultKind.BIAS, FaultKind.INTERMITTENT)
                and abs(mags[sensor] - value) <= 0.5 * abs(value))

    def _set_type(self, sensor: int, kind: FaultKind, value: float) -> None:
        self.types[sensor] = int(kind)
        if math.isfinite(value):
            self.mags[sensor], self.mag_valid[sensor] = value, True

    # ------------------------------------------------------------------------ state

    def get_state(self) -> dict[str, Any]:
        """The typer's part of the diagnoser's state (deep copies)."""
        return {
            "model_cols": self._model_cols.copy(), "theta": self._theta.copy(),
            "previous_isolated": list(self.previous[0]),
            "previous_types": self.previous[1].copy(), "previous_mags": self.previous[2].copy(),
            "presence_mode": int(self.presence_mode),
            "types": self.types.copy(), "mags": self.mags.copy(),
            "mag_valid": self.mag_valid.astype(float),
        }

    def check_state(self, state: dict[str, Any]) -> dict[str, Any]:
        """The typer's part of a saved state, checked (ValueError; KeyError for a
        missing key)."""
        m, nr = self.m, N_REG * self.m

        def arr(key: str, shape: tuple[int, ...]) -> _FloatArray:
            return check_finite_array(f"state[{key!r}]", state[key], shape=shape)

        got: dict[str, Any] = {"mags": arr("mags", (m,)),
                               "mag_valid": arr("mag_valid", (m,)) != 0.0}
        types = np.asarray(state["types"], dtype=int).reshape(-1)
        cols = np.asarray(state["model_cols"], dtype=int).reshape(-1)
        got["theta"] = check_finite_array("state['theta']", state["theta"],
                                          shape=(cols.size,))
        if types.shape != (m,):
            raise ValueError(f"state['types'] must have {m} entries")
        if np.any((cols < 0) | (cols >= nr)):
            raise ValueError(f"state['model_cols'] must be in [0, {nr})")
        got["types"], got["model_cols"] = types, cols
        got["presence_mode"] = int(state["presence_mode"])
        if not 0 <= got["presence_mode"] <= PRESENCE_CONSTANT:
            raise ValueError("state['presence_mode'] out of range")
        got["previous"] = (tuple(int(i) for i in state["previous_isolated"]),
                           np.asarray(state["previous_types"], dtype=int).reshape(m),
                           arr("previous_mags", (m,)))
        return got

    def set_state(self, got: dict[str, Any]) -> None:
        """Install a state :meth:`check_state` returned."""
        self.types, self.mags, self.mag_valid = got["types"], got["mags"], got["mag_valid"]
        self._model_cols, self._theta = got["model_cols"], got["theta"]
        self.presence_mode = got["presence_mode"]
        self.previous = got["previous"]


def _columns(sensors: tuple[int, ...], choice: dict[int, list[int]]) -> list[int]:
    """Signature columns of the regressors ``choice`` of every sensor."""
    return [N_REG * i + r for i in sensors for r in choice[i]]
