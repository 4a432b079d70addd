"""Fault typing of the sequential diagnosis: the fault signatures on the main filter's
whitened residual, their running sums, and the fit of the fault types.

Typing is a generalised likelihood ratio on the main filter's whitened residual z: a
fault signal φ on sensor i enters z linearly, z_k = z⁰_k + G_k θ, where the signature
G_k is the response of the (whitened) main filter to φ up to k, computed by running a
copy of its dynamics on φ. z⁰ is white N(0, I), so least squares on the running sums of
GᵀG, Gᵀz and zᵀz is the maximum-likelihood fit and differences of residual sums of
squares are χ² tests, whatever the colour of the detection filter's own residual. This
uses every sensor, not only a fault-free estimate of the faulty one (the pitch rate's
estimate from the other sensors has 42 times the sensor noise at low frequency on the
seed aircraft).

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
import scipy.linalg
from numpy.typing import NDArray

from ..common._validation import check_finite_array
from .settings import FaultKind, SequentialSettings

__all__ = ["PRESENCE_CONSTANT", "PRESENCE_MODEL", "PRESENCE_NONE", "PRESENCE_VARIANCE",
           "FaultTyper"]

_FloatArray = NDArray[np.float64]

#: Fault-signal regressors per sensor, from the episode's change time on: a step
#: (bias), time since the change in s (ramp) and the sensor's own reading (gain: y = g x
#: means the fault is (1 − 1/g)·y).
_BIAS, _RAMP, _GAIN = range(3)
_N_REG = 3
#: How the presence of an isolated fault is followed: not (the main alarm decides), by
#: the fitted mean model, by the variance, by the constant output.
PRESENCE_NONE, PRESENCE_MODEL, PRESENCE_VARIANCE, PRESENCE_CONSTANT = range(4)

#: Float arrays among the typer's keys of the diagnoser's saved state.
_ARRAY_KEYS = ("sig", "gram_c", "gz_c", "zz_c", "g_last", "z_last", "y_prev", "mags")


class FaultTyper:
    """Signatures, their sums, and the fit of the fault types (module notes).

    Parameters
    ----------
    n_sensors, n_inputs : int
        m and p of the plant.
    sample_period_s : float
        Sample period, s (the ramp regressor's time unit).
    sensor_variances : ndarray, shape (m,)
        Sensor noise variances, sensor units squared.
    settings : SequentialSettings
    n_hist : int
        Samples of history the diagnoser keeps (length of the step responses).

    Attributes
    ----------
    types, mags, mag_valid : ndarray, shape (m,)
        :class:`FaultKind` code, size and its validity per sensor (the diagnosis).
    presence_mode : int
        ``PRESENCE_*``: how the fault found is followed.
    step_response : ndarray, shape (n_hist, m, m)
        z response (sample, channel) to a unit step on each sensor.
    step_state : ndarray, shape (n_hist, n_state, m)
        Main filter state after j samples of a unit step on each sensor.
    """

    def __init__(self, n_sensors: int, n_inputs: int, sample_period_s: float,
                 sensor_variances: _FloatArray, settings: SequentialSettings,
                 n_hist: int) -> None:
        self.m, self.p, self.T = n_sensors, n_inputs, sample_period_s
        self.sensor_variances = sensor_variances
        self.settings = settings
        self._n_hist = n_hist
        self._type_min = max(2, round(settings.type_min_s / sample_period_s))
        self._reg_sensor = np.repeat(np.arange(n_sensors), _N_REG)

    # ------------------------------------------------------------------ signatures

    def install(self, system: tuple[_FloatArray, _FloatArray, _FloatArray, _FloatArray]
                ) -> None:
        """Main filter dynamics seen from a fault signal on each sensor and, per sensor,
        the summed variance of z per unit variance of extra white noise on it, per
        channel (for the size of a noise increase).

        ``system``: (A, B, Cz, Dz) of the main filter with its current channel scales
        (:meth:`~gyrodiag.df.generators.ObserverStack.system`).
        """
        a_c, b_all, c_z, d_all = system
        b_s, d_s = b_all[:, self.p:], d_all[:, self.p:]
        self._sig_a = a_c
        self._sig_b = b_s[:, self._reg_sensor]
        self._sig_c = c_z
        self._sig_d = d_s[:, self._reg_sensor]
        power = np.zeros((self.m, self.m))
        for i in range(self.m):
            pi = scipy.linalg.solve_discrete_lyapunov(a_c, np.outer(b_s[:, i], b_s[:, i]))
            power[:, i] = np.diag(c_z @ pi @ c_z.T) + d_s[:, i] ** 2
        self._noise_power_c = power
        self._install_responses(a_c, b_s, c_z, d_s)

    def _install_responses(self, a_c: _FloatArray, b_s: _FloatArray, c_z: _FloatArray,
                           d_s: _FloatArray) -> None:
        """z response to a unit step on each sensor, for the onset refinement, and the
        expected noise energy a reading used as a regressor brings into the sums."""
        steps = np.zeros((self._n_hist, self.m, self.m))
        impulse = np.zeros((self._n_hist, self.m, self.m))
        x = np.zeros((a_c.shape[0], self.m))
        xi = b_s.copy()
        impulse[0] = d_s
        for j in range(self._n_hist):
            steps[j] = c_z @ x + d_s
            x = a_c @ x + b_s
            if j > 0:
                impulse[j] = c_z @ xi
                xi = a_c @ xi
        self.step_response = steps
        # filter state after j samples of a unit step on each sensor (j = 0 … history)
        state = np.zeros((self._n_hist, a_c.shape[0], self.m))
        for j in range(1, self._n_hist):
            state[j] = a_c @ state[j - 1] + b_s
        self.step_state = state
        energy = np.cumsum(impulse**2, axis=0)  # (l, channel, sensor): Σ_{j≤l} h(j)²
        self._noise_sums = np.concatenate([np.zeros((1, self.m, self.m)),
                                           np.cumsum(energy, axis=0)])

    def reset(self, n_state: int) -> None:
        """No sums, no diagnosis, no previous episode (``n_state``: main filter states)."""
        m, nr = self.m, _N_REG * self.m
        self.previous: tuple[tuple[int, ...], NDArray[np.int_], _FloatArray] = (
            (), np.zeros(m, dtype=int), np.zeros(m))
        self._sig = np.zeros((n_state, nr))
        self._gram_c = np.zeros((m, nr, nr))
        self._gz_c = np.zeros((m, nr))
        self._zz_c = np.zeros(m)
        self._n_rec = 0
        self.n_after = 0
        self._g_last = np.zeros((m, nr))
        self.z_last = np.zeros(m)
        self._y_prev = np.zeros(m)
        self._model_cols = np.zeros(0, dtype=int)
        self._theta = np.zeros(0)
        self.presence_mode = PRESENCE_NONE
        self.types = np.zeros(m, dtype=int)
        self.mags = np.zeros(m)
        self.mag_valid = np.zeros(m, dtype=bool)

    def start(self, y_prev: _FloatArray) -> None:
        """Zero the signatures and their sums (a new record from the sample after the
        one that read ``y_prev``) and the diagnosis."""
        self._y_prev = y_prev
        self._sig[:] = 0.0
        self._gram_c[:] = 0.0
        self._gz_c[:] = 0.0
        self._zz_c[:] = 0.0
        self._n_rec, self.n_after = 0, 0
        self.clear()

    def step(self, w: _FloatArray, z: _FloatArray, j: int, change: int) -> None:
        """Signatures and sums for sample j (``w = [u; y]``, main filter output z);
        the fault signals start at sample ``change``."""
        if j >= change:
            phi = np.empty((self.m, _N_REG))
            phi[:, _BIAS] = 1.0
            phi[:, _RAMP] = (j - change) * self.T
            phi[:, _GAIN] = w[self.p:]
            phi = phi.reshape(-1)
            self.n_after += 1
        else:
            phi = np.zeros(_N_REG * self.m)
        g = self._sig_c @ self._sig + self._sig_d * phi
        self._sig = self._sig_a @ self._sig + self._sig_b * phi
        self._gram_c += g[:, :, None] * g[:, None, :]
        self._gz_c += g * z[:, None]
        self._zz_c += z * z
        self._n_rec += 1
        self._g_last, self.z_last = g, z
        self._y_prev = w[self.p:].copy()

    def model_misfit(self) -> _FloatArray:
        """z of the last sample less the fitted fault model's signature in it."""
        return self.z_last - self._g_last[:, self._model_cols] @ self._theta

    def fault_trace(self, gone: int) -> _FloatArray | None:
        """The fitted fault's trace in the main filter's state (its state is linear in
        the fault: the signature states times θ), None without a fitted model.

        ``gone``: samples since the fault ended by the presence test (its statistic
        was last zero), whose bias response is not in the filter.
        """
        cols = self._model_cols
        if not cols.size:
            return None
        trace = self._sig[:, cols] @ self._theta
        # The test saw the end a few samples late: a bias was already gone from the
        # sample after its statistic was last zero; its response to those samples is
        # not in the filter (a 20 σ burst left 1–2 σ otherwise, enough to spoil the
        # next episode's fit)
        if 0 < gone < self.step_state.shape[0]:
            for pos, col in enumerate(cols):
                if col % _N_REG == _BIAS:
                    trace = trace - self._theta[pos] * self.step_state[
                        gone, :, col // _N_REG]
        return trace

    def clear_signatures(self) -> None:
        """Zero the signature states (the fault's trace left the main filter)."""
        self._sig[:] = 0.0

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
            saved = (self.types.copy(), self.mags.copy(), self.mag_valid.copy(),
                     self._model_cols.copy(), self._theta.copy())
            same = self._type_now(k, isolated, record_episodes, constant_output)
            if self.presence_mode == PRESENCE_NONE:
                (self.types, self.mags, self.mag_valid, self._model_cols,
                 self._theta) = saved
                self.presence_mode = PRESENCE_MODEL
            return same
        return self._type_now(k, isolated, record_episodes, constant_output)

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
        if self.n_after < self._type_min:
            for i in sensors:
                self.types[i] = int(FaultKind.UNKNOWN)
            return
        n_rec = self._n_rec
        tau0 = self.settings.type_significance
        choice, explained_bias = self._choose_models(sensors)
        cols = _columns(sensors, choice)
        _, theta, rss_c = self._fit(cols)
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
                if explained_bias < tau0 * worst and kinds == [_BIAS]:
                    self._set_type(i, FaultKind.NOISE, self._noise_ratio(i, level_c))
                else:
                    self.types[i] = int(FaultKind.UNKNOWN)
                continue
            if kinds == [_BIAS, _RAMP]:
                self._set_type(i, FaultKind.RAMP, float(values[1]))
            elif kinds == [_BIAS, _GAIN]:
                c = float(values[1])
                self._set_type(i, FaultKind.GAIN, 1.0 / (1.0 - c) if c < 1.0 else math.inf)
            elif self._repeats_bias(i, float(values[0]), sensors, record_episodes):
                self._set_type(i, FaultKind.INTERMITTENT, float(values[0]))
            else:
                self._set_type(i, FaultKind.BIAS, float(values[0]))
        self._model_cols, self._theta = np.array(cols, dtype=int), theta
        self._choose_presence(sensors)

    def _choose_models(self, sensors: tuple[int, ...]) -> tuple[dict[int, list[int]], float]:
        """(regressors per sensor, zᵀz the bias model explains).

        Greedy model building: a bias on every isolated sensor, then each sensor's
        richer model where the likelihood ratio says so. z is white N(0, 1) per channel
        when the model fits, but a noise increase raises the variance of the channels
        the faulty sensor feeds: an improvement counts only against the largest
        per-channel residual variance of the model it improves on (else a larger noise
        would make chance improvements look significant).
        """
        n_rec = self._n_rec
        tau0 = self.settings.type_significance
        choice = {i: [_BIAS] for i in sensors}
        rss_base, _, rss_c = self._fit(_columns(sensors, choice))
        explained_bias = float(self._zz_c.sum()) - rss_base
        for i in sensors:
            alternatives = [[_BIAS, _RAMP]]
            if self._gain_identifiable(i):
                alternatives.append([_BIAS, _GAIN])
            tau = tau0 * max(1.0, float(rss_c.max()) / n_rec)
            best = (rss_base, choice[i], rss_c)
            for alt in alternatives:
                rss, _, rss_alt = self._fit(_columns(sensors, {**choice, i: alt}))
                if rss_base - rss > tau and rss < best[0]:
                    best = (rss, alt, rss_alt)
            rss_base, choice[i], rss_c = best
        return choice, explained_bias

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

    def _reading_noise(self) -> _FloatArray:
        """Expected Σ‖G(v_i)‖² per channel and sensor over the samples since the change,
        G(v_i) the response to sensor i's own noise (per unit noise variance)."""
        n = self.n_after
        sums = self._noise_sums
        if n < sums.shape[0]:
            return sums[n]
        steady = sums[-1] - sums[-2]  # the full impulse-response energy per sample
        return sums[-1] + (n - sums.shape[0] + 1) * steady

    def _fit(self, cols: list[int]) -> tuple[float, _FloatArray, _FloatArray]:
        """(residual sum of squares, θ, per-channel residual sums of squares) of z on
        the signatures ``cols``.

        A gain regressor is the faulty reading itself, noise included: its noise's
        response is part of z⁰ as well, so both its sum of squares and its cross sum
        with z carry the expected noise energy, which is taken out (corrected least
        squares; θ then estimates (g − 1)/g without the pull of the noise)."""
        if not cols:
            return float(self._zz_c.sum()), np.zeros(0), self._zz_c.copy()
        gram_c = self._gram_c[:, cols][:, :, cols].copy()
        gz_c = self._gz_c[:, cols].copy()
        gains = [(pos, col // _N_REG) for pos, col in enumerate(cols)
                 if col % _N_REG == _GAIN]
        if gains:
            noise = self._reading_noise()
            for pos, sensor in gains:
                e = noise[:, sensor] * self.sensor_variances[sensor]
                gram_c[:, pos, pos] -= e
                gz_c[:, pos] -= e
        gram, xz = gram_c.sum(axis=0), gz_c.sum(axis=0)
        ridge = 1e-12 * max(float(np.trace(gram)), 1e-300)
        theta = np.linalg.solve(gram + ridge * np.eye(len(cols)), xz)
        rss_c = self._zz_c - 2.0 * gz_c @ theta + np.einsum("cij,i,j->c", gram_c, theta, theta)
        return float(self._zz_c.sum() - theta @ xz), theta, rss_c

    def _gain_identifiable(self, sensor: int) -> bool:
        """The reading's signature varies beyond a constant (the bias signature) by
        more than its own noise: else a gain cannot be told from a bias (a flat
        signal, such as the seed aircraft's speed)."""
        b, g = _N_REG * sensor + _BIAS, _N_REG * sensor + _GAIN
        gram = self._gram_c[:, [b, g]][:, :, [b, g]].sum(axis=0)
        noise = float(self._reading_noise()[:, sensor].sum()) * self.sensor_variances[sensor]
        if gram[0, 0] <= 0.0:
            return False
        partial = gram[1, 1] - noise - gram[0, 1] ** 2 / gram[0, 0]
        return partial > 4.0 * noise

    def _repeats_bias(self, sensor: int, value: float, isolated: tuple[int, ...],
                      record_episodes: int) -> bool:
        """The previous episode of this record isolated the same sensors and found a
        bias (or intermittent bias) of about the same size on this sensor."""
        sensors, types, mags = self.previous
        return (record_episodes >= 2 and tuple(sensors) == isolated
                and int(types[sensor]) in (FaultKind.BIAS, FaultKind.INTERMITTENT)
                and abs(mags[sensor] - value) <= 0.5 * abs(value))

    def _noise_ratio(self, sensor: int, level_c: _FloatArray) -> float:
        """Total noise std of ``sensor`` as a multiple of the nominal, from the excess
        residual variance per channel after the change (least squares over channels
        of excess_c = (r² − 1)·σ²·power_c, power_c the channel's variance per unit
        extra noise variance on the sensor)."""
        excess = np.maximum(level_c - 1.0, 0.0) * self._n_rec / max(self.n_after, 1)
        power = self._noise_power_c[:, sensor]
        extra = float(excess @ power / max(float(power @ power), 1e-300))
        return math.sqrt(1.0 + max(extra, 0.0) / self.sensor_variances[sensor])

    def _set_type(self, sensor: int, kind: FaultKind, value: float) -> None:
        self.types[sensor] = int(kind)
        if math.isfinite(value):
            self.mags[sensor], self.mag_valid[sensor] = value, True

    # ------------------------------------------------------------------------ state

    def get_state(self) -> dict[str, Any]:
        """The typer's part of the diagnoser's state (deep copies)."""
        return {
            "sig": self._sig.copy(), "gram_c": self._gram_c.copy(),
            "gz_c": self._gz_c.copy(), "zz_c": self._zz_c.copy(),
            "n_rec": int(self._n_rec), "n_after": int(self.n_after),
            "g_last": self._g_last.copy(), "z_last": self.z_last.copy(),
            "y_prev": self._y_prev.copy(),
            "model_cols": self._model_cols.copy(), "theta": self._theta.copy(),
            "previous_isolated": list(self.previous[0]),
            "previous_types": self.previous[1].copy(), "previous_mags": self.previous[2].copy(),
            "presence_mode": int(self.presence_mode),
            "types": self.types.copy(), "mags": self.mags.copy(),
            "mag_valid": self.mag_valid.astype(float),
        }

    def check_state(self, state: dict[str, Any], n_state: int) -> dict[str, Any]:
        """The typer's part of a saved state, checked (ValueError, KeyError for a
        missing key); ``n_state``: main filter states."""
        m, nr = self.m, _N_REG * self.m

        def arr(key: str, shape: tuple[int, ...]) -> _FloatArray:
            return check_finite_array(f"state[{key!r}]", state[key], shape=shape)

        shapes = {"sig": (n_state, nr), "gram_c": (m, nr, nr), "gz_c": (m, nr),
                  "zz_c": (m,), "g_last": (m, nr), "z_last": (m,), "y_prev": (m,),
                  "mags": (m,)}
        got: dict[str, Any] = {key: arr(key, shapes[key]) for key in _ARRAY_KEYS}
        got["mag_valid"] = arr("mag_valid", (m,)) != 0.0
        types = np.asarray(state["types"], dtype=int).reshape(-1)
        cols = np.asarray(state["model_cols"], dtype=int).reshape(-1)
        got["theta"] = check_finite_array("state['theta']", state["theta"],
                                          shape=(cols.size,))
        if types.shape != (m,):
            raise ValueError(f"state['types'] must have {m} entries")
        if np.any((cols < 0) | (cols >= nr)):
            raise ValueError(f"state['model_cols'] must be in [0, {nr})")
        got["types"], got["model_cols"] = types, cols
        presence_mode = int(state["presence_mode"])
        if not 0 <= presence_mode <= PRESENCE_CONSTANT:
            raise ValueError("state['presence_mode'] out of range")
        got["presence_mode"] = presence_mode
        got["previous"] = (tuple(int(i) for i in state["previous_isolated"]),
                           np.asarray(state["previous_types"], dtype=int).reshape(m),
                           arr("previous_mags", (m,)))
        got["n_rec"], got["n_after"] = int(state["n_rec"]), int(state["n_after"])
        return got

    def set_state(self, got: dict[str, Any]) -> None:
        """Install a state :meth:`check_state` returned (after :meth:`install`)."""
        self._sig, self._gram_c = got["sig"], got["gram_c"]
        self._gz_c, self._zz_c = got["gz_c"], got["zz_c"]
        self._g_last, self.z_last = got["g_last"], got["z_last"]
        self._y_prev = got["y_prev"]
        self.types, self.mags, self.mag_valid = got["types"], got["mags"], got["mag_valid"]
        self._model_cols, self._theta = got["model_cols"], got["theta"]
        self.presence_mode = got["presence_mode"]
        self.previous = got["previous"]
        self._n_rec, self.n_after = got["n_rec"], got["n_after"]


def _columns(sensors: tuple[int, ...], choice: dict[int, list[int]]) -> list[int]:
    """Signature columns of the regressors ``choice`` of every sensor."""
    return [_N_REG * i + r for i in sensors for r in choice[i]]
