"""Sequential sensor-fault diagnosis on a linear plant: detection, isolation of one or two
faulty sensors, fault typing, episodes.

Building blocks
---------------
* :mod:`gyrodiag.df.generators`: the residual generators (an observer on a subset of
  the sensors plus the whitening of its residual; the *main* generator is the
  Beard–Jones detection filter on all sensors, generator ``¬S`` leaves out the sensors
  of S and so cannot see their faults) and :class:`ObserverStack`, which runs any set
  of them as one linear system; :class:`~gyrodiag.common.cusum.CusumBank` tests their
  outputs.
* :mod:`gyrodiag.df.settings`: :class:`SequentialSettings`, :class:`DiagnosisOutput`,
  :class:`FaultKind` and the ``isolated`` codes.
* :mod:`gyrodiag.df.hypotheses`: the hypothesis bank and the isolation decision (step
  2 below); :mod:`gyrodiag.df.onset`: change-time estimates.
* :mod:`gyrodiag.df.signatures` and :mod:`gyrodiag.df.fault_typing`: the fault
  signatures on the main filter's whitened residual and the fit of the fault types
  (step 3 below); :mod:`gyrodiag.df.presence`: the presence test (step 4).

The public names of ``generators`` and ``settings`` are importable from this module
too, as before the split.

Decision (:class:`SequentialDiagnoser`)
---------------------------------------
1. *Detection*: the main generator and a CUSUM bank (mean and variance, thresholds for
   a stated false-alarm rate) run every sample. An alarm opens a fault *episode*.
2. *Isolation* runs only as much as the decision needs: at the first episode the
   hypothesis generators (every ¬{i}, and every ¬{i, j} with ``max_faults = 2``) start
   from the main filter's state at the estimated change time (minus a margin), kept in
   a short history, and replay the samples since then. A hypothesis "the faulty sensors
   are S" is consistent while no CUSUM of generator ¬S has alarmed since; the diagnosis
   is the only consistent single sensor, else the only consistent pair, else
   "multiple" — never a guess among several consistent hypotheses.
3. *Typing* of each isolated sensor i compares it with the fault-free estimate
   ŷ_i = C_i x̂ of generator ¬S (which does not use it), fault estimate f̂ = y_i − ŷ_i,
   from the change time on: least-squares fits of a bias, a ramp, a gain
   (f̂ = (g − 1)·ŷ) and an intermittent bias (on in the episodes only) compared by a
   penalised likelihood; a constant output is stuck (0: complete failure); a variance
   well above nominal that no mean model explains is a noise increase.
4. *Episodes*: once isolated, the fault's presence is tested on f̂ directly (a CUSUM
   that starts in alarm); when it clears the episode ends and the main filter restarts
   from generator ¬S's state (it has absorbed the fault, ¬S has not), so the detection
   follows the fault, and an intermittent fault gives one episode per burst. Without an
   estimate of the faulty sensor the episode ends when the main alarm clears. The
   hypothesis generators stop ``memory_s`` after the last episode; the last diagnosis
   stays readable.

Sensors no other sensor observes (v and h of the seed aircraft) have no fault-free
estimate in generator ¬i: their bias is seen only in the transient after its onset, is
isolated by that transient, and the generator's estimate of them is the open-loop
continuation of the state from the change time (exact for v, which is constant in the
model; drifting for h, which integrates γ).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..common._distributions import chi2_ppf
from ..common._validation import (
    check_finite_array,
    check_int,
    check_positive,
)
from ..common.cusum import (
    CusumBank,
    arl_for_rate,
    mean_cusum_threshold,
    variance_cusum_increment,
    variance_cusum_threshold,
)
from .fault_typing import (
    PRESENCE_CONSTANT,
    PRESENCE_MODEL,
    PRESENCE_NONE,
    FaultTyper,
)
from .generators import (
    ObserverStack,
    ResidualGenerator,
    _gust_disturbance,  # noqa: F401  (re-exported: callers import it from here)
    design_residual_generator,
)
from .gust import GustModel
from .hypotheses import HypothesisBank, hypotheses_of
from .onset import refine_onset, walk_back
from .presence import PresenceTest
from .scale_calibration import calibrate_scales
from .sequential_state import diagnoser_state, restore_diagnoser_state
from .settings import (
    MULTIPLE,
    NOT_ISOLATED,
    DiagnosisOutput,
    FaultKind,
    SequentialSettings,
)
from .signatures import FaultSignatures

__all__ = [
    "MULTIPLE",
    "NOT_ISOLATED",
    "DiagnosisOutput",
    "FaultKind",
    "ObserverStack",
    "ResidualGenerator",
    "SequentialDiagnoser",
    "SequentialSettings",
    "design_residual_generator",
    "simulate_fault_free",
]

_FloatArray = NDArray[np.float64]

#: With a gust model, no refit while the presence test's statistic is at this fraction
#: of its threshold: a fault's whitened signature is short, and a refit (a ramp for a
#: burst that ended) would explain away the misfit that ends the episode.
PRESENCE_HOLD = 0.5
#: FaultKind.UNKNOWN as the int the typer's array holds.
_UNKNOWN = int(FaultKind.UNKNOWN)


class SequentialDiagnoser:
    """Detection, isolation, typing and episodes on a linear plant (module notes).

    Parameters
    ----------
    A, B, C : array_like
        Continuous plant model (n × n, n × p, m × n).
    K : array_like, shape (n, m)
        Beard–Jones gain of the main detection filter.
    sample_period_s : float
        Sample period, s.
    sensor_variances : array_like, shape (m,)
        Sensor noise variances (> 0), sensor units squared: the residual model the
        whitening filters come from.
    settings : SequentialSettings
    x0 : array_like, shape (n,), optional
        Initial state estimate of the main filter.
    gust : GustModel, optional
        Turbulence the whitening filters model (None: sensor noise only).

    Notes
    -----
    :meth:`update` takes aligned samples ``w = [u; y]`` (u the input that drives the
    plant from the sample of y on) and does not validate them: the owning channel
    checks each sample once.

    This class runs the detection and the episodes and keeps the sample history; its
    parts are the hypothesis bank (``hypothesis_bank``,
    :class:`~gyrodiag.df.hypotheses.HypothesisBank`), the fault signatures
    (``signatures``, :class:`~gyrodiag.df.signatures.FaultSignatures`), the typing
    (``typer``, :class:`~gyrodiag.df.fault_typing.FaultTyper`) and the presence test
    (``presence``, :class:`~gyrodiag.df.presence.PresenceTest`).
    """

    def __init__(self, A: ArrayLike, B: ArrayLike, C: ArrayLike, K: ArrayLike,
                 sample_period_s: float, sensor_variances: ArrayLike,
                 settings: SequentialSettings | None = None,
                 x0: ArrayLike | None = None, gust: GustModel | None = None) -> None:
        self.settings = settings or SequentialSettings()
        self.gust = gust
        self.settings.validate()
        a = check_finite_array("A", A, ndim=2)
        n = a.shape[0]
        b = check_finite_array("B", B, shape=(n, None))
        c = check_finite_array("C", C, shape=(None, n))
        self.n, self.p, self.m = n, b.shape[1], c.shape[0]
        gain = check_finite_array("K", K, shape=(n, self.m))
        self.T = check_positive("sample_period_s", sample_period_s)
        var = check_finite_array("sensor_variances", sensor_variances, shape=(self.m,))
        if np.any(var <= 0.0):
            raise ValueError("sensor_variances must be > 0 on every sensor")
        self.sensor_variances = var
        self.x0 = np.zeros(n) if x0 is None else check_finite_array("x0", x0, shape=(n,))
        self._design(a, b, c, gain)
        self._install_signature_matrices()
        self.reset()

    def _design(self, a: _FloatArray, b: _FloatArray, c: _FloatArray,
                gain: _FloatArray) -> None:
        """Residual generators, CUSUM thresholds, window lengths and the parts."""
        st = self.settings
        var, gust = self.sensor_variances, self.gust
        lam = None if st.bank_eigenvalues is None else np.asarray(st.bank_eigenvalues, float)
        reg = st.regularisation
        self.main_generator = design_residual_generator(
            a, b, c, self.T, (), var, main_gain=gain, regularisation=reg, gust=gust)
        self.hypotheses = hypotheses_of(self.m, st.max_faults)
        self.bank_generators = [
            design_residual_generator(a, b, c, self.T, h, var, eigenvalues=lam,
                                      regularisation=reg, gust=gust)
            for h in self.hypotheses
        ]
        self.main = ObserverStack([self.main_generator], self.p, self.m, residuals=True)
        #: size of the disturbance (gust) state at the end of every whitening state
        self._n_dist = 0 if gust is None else self.main.n_state - self.n
        self.c_matrix = c

        # CUSUM thresholds for the design rate over the 3 m main charts (union bound);
        # hypothesis and presence charts get the same per-chart run length.
        arl = arl_for_rate(st.false_alarms_per_h, self.T, 3 * self.m)
        self.h_mean = mean_cusum_threshold(arl, st.cusum_k)
        self.h_variance = variance_cusum_threshold(arl, st.variance_ratio)
        self.chart_arl = arl
        self.main_cusum = self._new_cusum(self.m)
        self.hypothesis_bank = HypothesisBank(self.bank_generators, self.p, self.m,
                                              self._new_cusum)
        self.bank = self.hypothesis_bank.stack
        self._bank_gen_of_channel = self.hypothesis_bank.gen_of_channel
        self._n_hist = max(2, round(st.history_s / self.T))
        self._margin = round(st.replay_margin_s / self.T)
        self._memory = round(st.memory_s / self.T)
        self._stuck_n = max(2, round(st.stuck_window_s / self.T))
        self._onset_window = max(10, round(0.1 / self.T))
        self._isolation_window = max(self._onset_window, round(0.5 / self.T))
        self._type_every = max(1, round(st.type_period_s / self.T))
        # walking a CUSUM back, "zero" is below a tiny fraction of the threshold
        self._zero_tol = 1e-9 * self.h_mean
        self.signatures = FaultSignatures(self.m, self.p, self.T, var, self._n_hist)
        self.typer = FaultTyper(self.signatures, var, st)
        self.presence = PresenceTest(self.m, self._n_hist, self._new_cusum, self._zero_tol)

    def _new_cusum(self, n_channels: int) -> CusumBank:
        st = self.settings
        return CusumBank(n_channels, st.cusum_k, self.h_mean, st.variance_ratio,
                         self.h_variance, st.release)

    def _install_signature_matrices(self) -> None:
        """The signature matrices for the main filter's current channel scales."""
        self.signatures.install(self.main.system())

    @property
    def bank_cusum(self) -> CusumBank:
        """CUSUM charts of the hypothesis generators."""
        return self.hypothesis_bank.cusum

    # ------------------------------------------------------------------- calibration

    @property
    def thresholds(self) -> tuple[float, float]:
        """(mean-CUSUM threshold σ, variance-CUSUM threshold) of every chart."""
        return self.h_mean, self.h_variance

    def calibrate_scales(self, w: ArrayLike, burn_in: int, confidence: float = 0.95,
                         x_start: ArrayLike | None = None) -> list[_FloatArray]:
        """Widen the generators' channels to their whitened variance on fault-free data
        (:func:`~gyrodiag.df.scale_calibration.calibrate_scales`); returns the factors."""
        return calibrate_scales(self, w, burn_in, confidence, x_start)

    def set_scales(self, scales: list[_FloatArray]) -> None:
        """Install per-channel scale factors (main generator first) and reset."""
        if len(scales) != 1 + len(self.bank_generators):
            raise ValueError(f"scales must hold {1 + len(self.bank_generators)} arrays")
        self.main.set_channel_scale(scales[:1])
        self.bank.set_channel_scale(scales[1:])
        self._install_signature_matrices()
        self.reset()

    # --------------------------------------------------------------------- streaming

    def reset(self) -> None:
        """Main filter to x0, no episode, no hypothesis running, history empty."""
        self.main.reset()
        self.main.set_observer_state(0, self.x0)
        self.main_cusum.reset()
        self.hypothesis_bank.reset()
        m = self.m
        self._count = 0
        self._hist_w = np.zeros((self._n_hist, self.p + m))
        self._hist_x = np.zeros((self._n_hist, self.n))
        self._hist_d = np.zeros((self._n_hist, self._n_dist))
        self._hist_z = np.zeros((self._n_hist, m))
        self._in_episode = False
        self._wait_clear = False
        self._episodes = 0
        self._bank_active = False
        self._last_end = -1
        self._change = -1
        self._record_episodes = 0
        self._status = "none"
        self._isolated: tuple[int, ...] = ()
        self._iso_gen = -1
        self.signatures.reset(self.main.n_state)
        self.typer.reset()
        self.presence.reset()
        self._out_types = self.typer.types.copy()
        self._out_mags = self.typer.mags.copy()
        self._out_valid = self.typer.mag_valid.copy()
        self._last = DiagnosisOutput(
            np.zeros(m), np.zeros(m, dtype=bool), np.zeros(m), False, 0, "none", (),
            self._out_types, self._out_mags, self._out_valid)

    @property
    def last_output(self) -> DiagnosisOutput:
        """Output of the last update (the initial one before any)."""
        return self._last

    @property
    def bank_active(self) -> bool:
        """The hypothesis generators are running."""
        return self._bank_active

    def update(self, w: _FloatArray) -> DiagnosisOutput:
        """Process one aligned sample ``w = [u; y]`` (not validated)."""
        k = self._count
        slot = k % self._n_hist
        self._hist_w[slot] = w
        self._hist_x[slot] = self.main.x[:self.n]
        if self._n_dist:
            self._hist_d[slot] = self.main.x[self.main.n_state - self._n_dist:]
        z, residual = self.main.update(w)
        self._hist_z[slot] = z
        alarm = self.main_cusum.update(z)
        self._count = k + 1

        if alarm or self._in_episode or self._bank_active:
            self._episode_logic(w, z, k, alarm)
        elif self._wait_clear:
            self._wait_clear = False
        out = DiagnosisOutput(
            residual, self.main_cusum.alarms, self.main_cusum.statistic(),
            self._in_episode, self._episodes, self._status, self._isolated,
            self._out_types, self._out_mags, self._out_valid)
        self._last = out
        return out

    def _episode_logic(self, w: _FloatArray, z: _FloatArray, k: int, alarm: bool) -> None:
        replayed = False
        if self._wait_clear and not alarm:
            self._wait_clear = False
        if alarm and not self._in_episode and not self._wait_clear:
            replayed = self._start_episode(k)
        if self._bank_active:
            if not replayed:
                self._record_step(w, z, k)
            if self._in_episode and not replayed:
                self._follow_presence(k)
            if self._in_episode:
                self._decide(k)
            elif k - self._last_end > self._memory:
                self._bank_active = False
        elif self._in_episode and not self.main_cusum.any_alarm:
            self._end_episode(k, "none")
        self._publish()

    def _publish(self) -> None:
        """Snapshot the diagnosis for the outputs when it changed."""
        typer = self.typer
        # plain lists: the arrays are m long (as np.array_equal: NaN never equal)
        if not (typer.types.tolist() == self._out_types.tolist()
                and typer.mags.tolist() == self._out_mags.tolist()
                and typer.mag_valid.tolist() == self._out_valid.tolist()):
            self._out_types = typer.types.copy()
            self._out_mags = typer.mags.copy()
            self._out_valid = typer.mag_valid.copy()

    # ------------------------------------------------------------------ episodes

    def _start_episode(self, k: int) -> bool:
        """Open an episode; True if the record (hypothesis generators) was started and
        has processed sample k in its replay."""
        self._in_episode = True
        self._episodes += 1
        if self._status == "none":
            self._status = "not isolated"
        oldest = max(0, k - self._n_hist + 1)
        change = walk_back(self.main_cusum, self._hist_z, k, oldest, self._zero_tol)
        self._change = refine_onset(self._hist_z, self.signatures.step_response, change,
                                    oldest, k, self._onset_window)
        # not before the previous episode's end: its samples carry that fault
        start = max(oldest, self._change - self._margin, self._last_end + 1)
        if self._bank_active:
            self._record_episodes += 1
            if self._iso_gen >= 0:
                self.typer.remember(self._isolated)
            self._start_signatures(start, k)
            return False
        self._record_episodes = 1
        self.typer.remember(None)
        self.hypothesis_bank.start(self._hist_x[start % self._n_hist],
                                   self._hist_d[start % self._n_hist], start)
        self._bank_active = True
        self._status, self._isolated, self._iso_gen = "not isolated", (), -1
        for j in range(start, k + 1):
            self.hypothesis_bank.step(self._hist_w[j % self._n_hist])
        self._start_signatures(start, k)
        return True

    def _start_signatures(self, start: int, k: int) -> None:
        """Fault signatures and their sums for this episode, from ``start`` (before the
        change time) to sample k, replayed from the history; no diagnosis yet."""
        self.signatures.start(self._hist_w[(start - 1) % self._n_hist, self.p:].copy())
        self.typer.clear()
        self.presence.stop()
        for j in range(start, k + 1):
            h = j % self._n_hist
            self.signatures.step(self._hist_w[h], self._hist_z[h], j, self._change)

    def _record_step(self, w: _FloatArray, z: _FloatArray, j: int) -> None:
        """Hypothesis generators and (in an episode) fault signatures for sample j."""
        self.hypothesis_bank.step(w)
        if self._in_episode:
            self.signatures.step(w, z, j, self._change)

    def _end_episode(self, k: int, how: str) -> None:
        """Close the episode.

        ``how``: "model" removes the fitted fault's trace from the main filter, so that
        it monitors on at once; "none" leaves the main filter to forget the fault by
        itself, and no new episode starts before its alarm has cleared.
        """
        self._in_episode = False
        self._last_end = k
        if how == "model":
            trace = self.typer.fault_trace(k + 1 - self.presence.zero)
            if trace is not None:
                self.main.x = self.main.x - trace
            self.main_cusum.reset(k + 1)
            self.signatures.clear_states()
        else:
            self._wait_clear = True
        self.presence.stop()

    # ------------------------------------------------------------------ isolation

    def _decide(self, k: int) -> None:
        """Isolation (the bank's verdict) at sample k; on a new verdict, the onset
        refined for the sensors isolated; then the typing when due."""
        gen, self._status = self.hypothesis_bank.verdict()
        changed = gen != self._iso_gen
        if changed:
            self._iso_gen = gen
            self._isolated = self.hypotheses[gen] if gen >= 0 else ()
            self.presence.stop()
            if gen >= 0:
                oldest = max(0, k - self._n_hist + 1)
                onset = refine_onset(self._hist_z, self.signatures.step_response,
                                     self._change, oldest, k, self._isolation_window,
                                     self._isolated)
                if onset != self._change:
                    self._change = onset
                    self._start_signatures(
                        max(oldest, onset - self._margin, self._last_end + 1), k)
        if changed or (k - self._change) % self._type_every == 0:
            self._type(k)
        else:
            types = self.typer.types
            if any(types[i] == _UNKNOWN for i in self._isolated):
                self._type(k)

    def _type(self, k: int) -> None:
        """Type the isolated faults (:meth:`FaultTyper.type`); with a gust model, no
        refit of a mean model while the presence test is judging its misfit."""
        hold = (self.typer.presence_mode == PRESENCE_MODEL and bool(self._n_dist)
                and self.presence.at_least(PRESENCE_HOLD))
        if not self.typer.type(k, self._isolated, self._record_episodes,
                               self._constant_output, hold):
            self.presence.stop()  # a new way of following the fault: a new test

    def _constant_output(self, sensor: int, k: int) -> float | None:
        """Mean of the sensor's last samples if they are constant (std below a tenth
        of its noise) and all after the change time, else None."""
        n = self._stuck_n
        if k - self._change + 1 < n:
            return None
        first, last = (k - n + 1) % self._n_hist, k % self._n_hist
        col = self.p + sensor
        if first <= last:  # no wrap: a contiguous copy of the same values
            y = self._hist_w[first:last + 1, col].copy()
        else:
            y = self._hist_w[np.arange(k - n + 1, k + 1) % self._n_hist, col]
        limit = 0.1 * math.sqrt(self.sensor_variances[sensor])
        # std >= range / sqrt(2 n): a range well above limit * sqrt(2 n) is not constant
        # (the margin covers the std's rounding), without computing the std
        if float(y.max()) - float(y.min()) > 1.01 * limit * math.sqrt(2.0 * n):
            return None
        if y.std() < limit:
            return float(y.mean())
        return None

    # ------------------------------------------------------------------ presence

    def _follow_presence(self, k: int) -> None:
        """End the episode when the isolated fault is gone (module notes), judged with
        the fault model of the previous sample."""
        mode = self.typer.presence_mode
        if self._iso_gen < 0 or mode == PRESENCE_NONE:
            if not self.main_cusum.any_alarm:
                self._end_episode(k, "none")
            return
        if mode == PRESENCE_CONSTANT:
            if all(self._constant_output(i, k) is None for i in self._isolated):
                self._end_episode(k, "none")
            return
        if mode == PRESENCE_MODEL:
            gone = self.presence.follow_model(k, *self.typer.model_misfit())
            if gone and self.presence.grew and self.typer.refit_richer(
                    k, self._isolated, self._record_episodes, self._constant_output):
                # a ramp or gain first typed as a bias: the same episode, a new test
                self.presence.stop()
                return
        else:  # a noise increase
            gone = self.presence.follow_variance(k, self.signatures.z_last)
        if gone:
            self._end_episode(k, "model")

    # ------------------------------------------------------------------------ state

    def get_state(self) -> dict[str, Any]:
        """Every piece of dynamic state (deep copies; :mod:`~gyrodiag.df.sequential_state`)."""
        return diagnoser_state(self)

    def set_state(self, state: dict[str, Any]) -> None:
        """Restore :meth:`get_state` output of an identically built diagnoser; checked
        first, so a bad state leaves this one untouched."""
        restore_diagnoser_state(self, state)


def simulate_fault_free(diagnoser: SequentialDiagnoser, hours: float, *,
                        n_parallel: int = 1000, seed: int = 0,
                        sensor_std: ArrayLike | None = None) -> dict[str, float]:
    """False alarms of the detection over ``hours`` of simulated fault-free operation.

    The residual of an observer whose model is exact depends on the sensor noise only
    (:mod:`gyrodiag.df.residual`), so the detection path (main filter, whitening,
    scales, CUSUM bank with its cap and release) is run on white sensor noise alone,
    ``n_parallel`` independent runs at a time as one matrix product per sample. An
    alarm is a rising edge of "any channel in alarm".

    Parameters
    ----------
    diagnoser : SequentialDiagnoser
        Supplies the filter, its scales, the thresholds and the sample period.
    hours : float
        Total simulated time over all parallel runs, h (each run lasts hours/n_parallel).
    n_parallel : int
        Runs simulated side by side.
    seed : int
        Noise generator seed.
    sensor_std : array_like, optional
        True sensor noise standard deviations (default: the diagnoser's own model), to
        measure what a misestimated noise does.

    Returns
    -------
    dict
        ``alarms``, ``hours``, ``rate_per_h``, ``upper95_per_h`` (Garwood bound),
        ``design_per_h``.
    """
    h = check_positive("hours", hours)
    runs = check_int("n_parallel", n_parallel, minimum=1)
    d = diagnoser
    std = (np.sqrt(d.sensor_variances) if sensor_std is None
           else check_finite_array("sensor_std", sensor_std, shape=(d.m,)))
    n_steps = max(1, math.ceil(h * 3600.0 / d.T / runs))
    a, b, cz, dz = d.main.system()
    b_y, d_y = b[:, d.p:] * std, dz[:, d.p:] * std
    rng = np.random.default_rng(seed)
    m = d.m
    x = np.zeros((a.shape[0], runs))
    # burn-in: start every run from the stationary error distribution's neighbourhood
    for _ in range(min(n_steps, round(10.0 / d.T))):
        x = a @ x + b_y @ rng.standard_normal((m, runs))
    cap = np.concatenate([np.full(2 * m, d.h_mean), np.full(m, d.h_variance)])[:, None]
    release = d.settings.release * cap
    st = d.settings
    a_v, c_v = variance_cusum_increment(st.variance_ratio)
    drift = np.concatenate([np.full(2 * m, -st.cusum_k), np.full(m, -c_v)])[:, None]
    s = np.zeros((3 * m, runs))
    chart = np.zeros((3 * m, runs), dtype=bool)
    any_prev = np.zeros(runs, dtype=bool)
    alarms = 0
    for _ in range(n_steps):
        v = rng.standard_normal((m, runs))
        z = cz @ x + d_y @ v
        x = a @ x + b_y @ v
        inc = np.concatenate((z, -z, a_v * z * z))
        s = np.minimum(np.maximum(s + inc + drift, 0.0), cap)
        raised = s >= cap
        chart = (chart & (s >= release)) | raised
        now = chart.any(axis=0)
        alarms += int(np.count_nonzero(now & ~any_prev))
        any_prev = now
    total_h = n_steps * runs * d.T / 3600.0
    return {
        "alarms": alarms, "hours": total_h, "rate_per_h": alarms / total_h,
        "upper95_per_h": float(chi2_ppf(0.975, 2 * (alarms + 1)) / 2.0
                               / total_h),
        "design_per_h": st.false_alarms_per_h,
    }
