"""Fault signatures on the main filter's whitened residual and their running sums (the
regression behind the fault typing, :mod:`gyrodiag.df.fault_typing`).

A fault signal φ on sensor i enters the main filter's whitened residual linearly,
z_k = z⁰_k + G_k θ: the signature G_k is the response of the (whitened) main filter to φ
up to k, computed by running a copy of its dynamics on φ. The signals per sensor are a
step (bias), the time since the change (ramp) and the sensor's own reading (gain). The
running sums of GᵀG, Gᵀz and zᵀz per channel give the least-squares fit of any set of
them (:meth:`FaultSignatures.fit`).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import scipy.linalg
from numpy.typing import NDArray

from ..common._validation import check_finite_array

__all__ = ["N_REG", "REG_BIAS", "REG_GAIN", "REG_RAMP", "FaultSignatures"]

_FloatArray = NDArray[np.float64]

#: Fault-signal regressors per sensor, from the episode's change time on: a step
#: (bias), time since the change in s (ramp) and the sensor's own reading (gain: y = g x
#: means the fault is (1 − 1/g)·y). Signature column of regressor r of sensor i:
#: ``N_REG * i + r``.
REG_BIAS, REG_RAMP, REG_GAIN = range(3)
N_REG = 3

#: Float arrays of the signatures' part of the diagnoser's saved state.
_ARRAY_KEYS = ("sig", "gram_c", "gz_c", "zz_c", "g_last", "z_last", "y_prev")
#: Identity matrices by size, for the fits' ridge (never modified).
_EYE: dict[int, _FloatArray] = {}


class FaultSignatures:
    """Signatures of every fault signal on every sensor and their sums (module notes).

    Parameters
    ----------
    n_sensors, n_inputs : int
        m and p of the plant.
    sample_period_s : float
        Sample period, s (the ramp regressor's time unit).
    sensor_variances : ndarray, shape (m,)
        Sensor noise variances, sensor units squared.
    n_hist : int
        Samples of history the diagnoser keeps (length of the step responses).

    Attributes
    ----------
    n_rec, n_after : int
        Samples summed, and of them those from the change time on.
    z_last : ndarray, shape (m,)
        z of the last sample summed.
    step_response : ndarray, shape (n_hist, m, m)
        z response (sample, channel, sensor) to a unit step on each sensor.
    step_state : ndarray, shape (n_hist, n_state, m)
        Main filter state after j samples of a unit step on each sensor.
    """

    def __init__(self, n_sensors: int, n_inputs: int, sample_period_s: float,
                 sensor_variances: _FloatArray, n_hist: int) -> None:
        self.m, self.p, self.T = n_sensors, n_inputs, sample_period_s
        self.sensor_variances = sensor_variances
        self._n_hist = n_hist
        self._reg_sensor = np.repeat(np.arange(n_sensors), N_REG)

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
        self._sig_db = np.vstack([self._sig_d, self._sig_b])
        self._tmp_db = np.empty(self._sig_db.shape)
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
        """No sums (``n_state``: main filter states)."""
        m, nr = self.m, N_REG * self.m
        self._sig = np.zeros((n_state, nr))
        self._gram_c = np.zeros((m, nr, nr))
        self._gz_c = np.zeros((m, nr))
        self._zz_c = np.zeros(m)
        self.n_rec = 0
        self.n_after = 0
        self._g_last = np.zeros((m, nr))
        self.z_last = np.zeros(m)
        self._y_prev = np.zeros(m)
        # per-sample buffers of step(): the fault signals (bias column always 1) and
        # the products' temporaries
        self._phi = np.zeros(nr)
        self._phi3 = self._phi.reshape(m, N_REG)
        self._phi3[:, REG_BIAS] = 1.0
        self._phi_zero = np.zeros(nr)
        self._tmp_d = np.empty((m, nr))
        self._tmp_gram = np.empty((m, nr, nr))

    def start(self, y_prev: _FloatArray) -> None:
        """Zero the signatures and their sums: a new record from the sample after the
        one that read ``y_prev``."""
        self._y_prev = y_prev
        self._sig[:] = 0.0
        self._gram_c[:] = 0.0
        self._gz_c[:] = 0.0
        self._zz_c[:] = 0.0
        self.n_rec, self.n_after = 0, 0

    def step(self, w: _FloatArray, z: _FloatArray, j: int, change: int) -> None:
        """Signatures and sums for sample j (``w = [u; y]``, main filter output z);
        the fault signals start at sample ``change``."""
        if j >= change:
            phi = self._phi
            phi3 = self._phi3
            phi3[:, REG_RAMP] = (j - change) * self.T
            phi3[:, REG_GAIN] = w[self.p:]
            self.n_after += 1
        else:
            phi = self._phi_zero
        g = self._sig_c @ self._sig
        sig = self._sig_a @ self._sig
        # [Dz; B] * phi in one product: rows m on are the state's
        db_phi = np.multiply(self._sig_db, phi, out=self._tmp_db)
        g += db_phi[:self.m]
        sig += db_phi[self.m:]
        self._sig = sig
        self._gram_c += np.multiply(g[:, :, None], g[:, None, :], out=self._tmp_gram)
        self._gz_c += np.multiply(g, z[:, None], out=self._tmp_d)
        self._zz_c += z * z
        self.n_rec += 1
        self._g_last, self.z_last = g, z
        self._y_prev = w[self.p:].copy()

    def clear_states(self) -> None:
        """Zero the signature states (the fault's trace left the main filter)."""
        self._sig[:] = 0.0

    # ------------------------------------------------------------------ fits

    @property
    def energy(self) -> float:
        """zᵀz summed over the record and the channels."""
        return float(self._zz_c.sum())

    def fit(self, cols: list[int]) -> tuple[float, _FloatArray, _FloatArray]:
        """(residual sum of squares, θ, per-channel residual sums of squares) of z on
        the signatures ``cols``.

        A gain regressor is the faulty reading itself, noise included: its noise's
        response is part of z⁰ as well, so both its sum of squares and its cross sum
        with z carry the expected noise energy, which is taken out (corrected least
        squares; θ then estimates (g − 1)/g without the pull of the noise)."""
        if not cols:
            return float(self._zz_c.sum()), np.zeros(0), self._zz_c.copy()
        idx = np.array(cols)
        gram_c = self._gram_c[:, idx[:, None], idx].copy()  # C order, as the sums expect
        gz_c = self._gz_c[:, idx].copy()
        noise = None
        for pos, col in enumerate(cols):
            if col % N_REG == REG_GAIN:
                if noise is None:
                    noise = self._reading_noise()
                sensor = col // N_REG
                e = noise[:, sensor] * self.sensor_variances[sensor]
                gram_c[:, pos, pos] -= e
                gz_c[:, pos] -= e
        gram, xz = gram_c.sum(axis=0), gz_c.sum(axis=0)
        ridge = 1e-12 * max(float(np.trace(gram)), 1e-300)
        eye = _EYE.get(len(cols))
        if eye is None:
            eye = _EYE[len(cols)] = np.eye(len(cols))
        theta = np.linalg.solve(gram + ridge * eye, xz)
        rss_c = self._zz_c - 2.0 * gz_c @ theta + np.einsum("cij,i,j->c", gram_c, theta, theta)
        return float(self._zz_c.sum() - theta @ xz), theta, rss_c

    def _reading_noise(self) -> _FloatArray:
        """Expected Σ‖G(v_i)‖² per channel and sensor over the samples since the change,
        G(v_i) the response to sensor i's own noise (per unit noise variance)."""
        n = self.n_after
        sums = self._noise_sums
        if n < sums.shape[0]:
            return sums[n]
        steady = sums[-1] - sums[-2]  # the full impulse-response energy per sample
        return sums[-1] + (n - sums.shape[0] + 1) * steady

    def gain_identifiable(self, sensor: int) -> bool:
        """The reading's signature varies beyond a constant (the bias signature) by
        more than its own noise: else a gain cannot be told from a bias (a flat
        signal, such as the seed aircraft's speed)."""
        b, g = N_REG * sensor + REG_BIAS, N_REG * sensor + REG_GAIN
        gram = self._gram_c[:, [b, g]][:, :, [b, g]].sum(axis=0)
        noise = float(self._reading_noise()[:, sensor].sum()) * self.sensor_variances[sensor]
        if gram[0, 0] <= 0.0:
            return False
        partial = gram[1, 1] - noise - gram[0, 1] ** 2 / gram[0, 0]
        return partial > 4.0 * noise

    def noise_ratio(self, sensor: int, level_c: _FloatArray) -> float:
        """Total noise std of ``sensor`` as a multiple of the nominal, from the excess
        residual variance per channel after the change (least squares over channels
        of excess_c = (r² − 1)·σ²·power_c, power_c the channel's variance per unit
        extra noise variance on the sensor)."""
        excess = np.maximum(level_c - 1.0, 0.0) * self.n_rec / max(self.n_after, 1)
        power = self._noise_power_c[:, sensor]
        extra = float(excess @ power / max(float(power @ power), 1e-300))
        return math.sqrt(1.0 + max(extra, 0.0) / self.sensor_variances[sensor])

    def misfit(self, cols: _FloatArray, theta: _FloatArray) -> tuple[_FloatArray, _FloatArray]:
        """(z of the last sample less the signature of the model (``cols``, θ) in it,
        that signature)."""
        part = self._g_last[:, cols] @ theta
        return self.z_last - part, part

    def trace(self, cols: _FloatArray, theta: _FloatArray, gone: int) -> _FloatArray:
        """The trace of the model (``cols``, θ) in the main filter's state (its state is
        linear in the fault: the signature states times θ).

        ``gone``: samples since the fault ended by the presence test (its statistic
        was last zero), whose bias response is not in the filter.
        """
        trace = self._sig[:, cols] @ theta
        # The test saw the end a few samples late: a bias was already gone from the
        # sample after its statistic was last zero; its response to those samples is
        # not in the filter (a 20 σ burst left 1–2 σ otherwise, enough to spoil the
        # next episode's fit)
        if 0 < gone < self.step_state.shape[0]:
            for pos, col in enumerate(cols):
                if col % N_REG == REG_BIAS:
                    trace = trace - theta[pos] * self.step_state[gone, :, col // N_REG]
        return trace

    # ------------------------------------------------------------------------ state

    def get_state(self) -> dict[str, Any]:
        """The signatures' part of the diagnoser's state (deep copies)."""
        return {
            "sig": self._sig.copy(), "gram_c": self._gram_c.copy(),
            "gz_c": self._gz_c.copy(), "zz_c": self._zz_c.copy(),
            "n_rec": int(self.n_rec), "n_after": int(self.n_after),
            "g_last": self._g_last.copy(), "z_last": self.z_last.copy(),
            "y_prev": self._y_prev.copy(),
        }

    def check_state(self, state: dict[str, Any], n_state: int) -> dict[str, Any]:
        """The signatures' part of a saved state, checked (ValueError; KeyError for a
        missing key); ``n_state``: main filter states."""
        m, nr = self.m, N_REG * self.m
        shapes = {"sig": (n_state, nr), "gram_c": (m, nr, nr), "gz_c": (m, nr),
                  "zz_c": (m,), "g_last": (m, nr), "z_last": (m,), "y_prev": (m,)}
        got: dict[str, Any] = {
            key: check_finite_array(f"state[{key!r}]", state[key], shape=shapes[key])
            for key in _ARRAY_KEYS}
        got["n_rec"], got["n_after"] = int(state["n_rec"]), int(state["n_after"])
        return got

    def set_state(self, got: dict[str, Any]) -> None:
        """Install a state :meth:`check_state` returned (after :meth:`install`)."""
        self._sig, self._gram_c = got["sig"], got["gram_c"]
        self._gz_c, self._zz_c = got["gz_c"], got["zz_c"]
        self._g_last, self.z_last = got["g_last"], got["z_last"]
        self._y_prev = got["y_prev"]
        self.n_rec, self.n_after = got["n_rec"], got["n_after"]
