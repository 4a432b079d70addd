"""Grey prediction (GM(1,1)) and the improved moving-window grey fault detector (HRG).

Method B (docs/methods.md §3, seed 001): a hemispherical resonator gyro's
output is predicted one sample ahead by a grey model fitted to the last ``m`` samples;
a measured sample farther than a threshold from its prediction raises a fault alarm.

GM(1,1) on a positive window x⁰(1..m)::

    x¹(k) = Σ_{i≤k} x⁰(i)                      (accumulated series)
    z¹(k) = ½ (x¹(k) + x¹(k−1)),  k = 2..m     (trapezoid background value)
    x⁰(k) + a·z¹(k) = b,          k = 2..m     (least squares for a, b)
    x̂¹(k) = (C − b/a)·e^{−a(k−1)} + b/a        (time response)
    x̂⁰(k+1) = x̂¹(k+1) − x̂¹(k)                 (one-step prediction)

The classic model takes C = x⁰(1); the optimized model takes the C that minimises
Σ_k (x̂¹(k) − x¹(k))² over the window (closed form, see :func:`gm11_optimal_initial_value`).

Every expression with ``b/a`` is evaluated here in a form that stays exact as a → 0::

    x̂¹(k) = C·u(k) + b·g(k),  u(k) = e^{−a(k−1)},  g(k) = −expm1(−a(k−1))/a  (→ k−1)
    x̂⁰(m+1) = (b − a·C)·h(a)·e^{−a(m−1)},  h(a) = −expm1(−a)/a  (→ 1)

which is algebraically the textbook (1 − e^{a})·(C − b/a)·e^{−a·m}. The textbook
evaluation is available as ``evaluation="textbook"`` only to reproduce the paper's
"classic GM collapses on a flat signal" result: on an exactly constant window
least squares returns |a| ~ 1e−17, ``exp(a)`` rounds to 1 (or to 1 ± 1 ulp) and the
textbook prediction becomes 0 or an arbitrary multiple of the level. The careful form
predicts that window to rounding error. The paper's false alarm on the flat tail is
therefore a floating-point artefact of the textbook formula, not of GM(1,1) itself.

Non-finite input: the model functions and the predictors raise ``ValueError`` on a NaN
or infinite sample; :class:`GreyFaultDetector` instead skips such a sample without
touching its state and flags it invalid, so a co-simulation can keep running.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Literal, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gyrodiag.common._validation import (
    check_finite_array,
    check_int,
    check_nonnegative,
    check_positive,
)

__all__ = [
    "DEFAULT_LEVEL_RATIO",
    "GM11_MIN_LENGTH",
    "ClassicGreyPredictor",
    "GreyDetectorOutput",
    "GreyFaultDetector",
    "GreyPredictor",
    "ImprovedGreyPredictor",
    "gm11_fit",
    "gm11_fitted_values",
    "gm11_optimal_initial_value",
    "gm11_predict_classic",
    "gm11_predict_next",
    "gm11_predict_optimized",
    "positive_shift",
    "prediction_errors_percent",
]

GM11_MIN_LENGTH = 4
"""Shortest window accepted by :func:`gm11_fit` (3 regression rows for 2 unknowns)."""

Evaluation = Literal["careful", "textbook"]


# --------------------------------------------------------------------------- GM(1,1)


def _check_window(name: str, x0: ArrayLike) -> NDArray[np.float64]:
    arr = check_finite_array(name, x0, ndim=1)
    if arr.size < GM11_MIN_LENGTH:
        raise ValueError(
            f"{name} must have at least {GM11_MIN_LENGTH} samples, got {arr.size}"
        )
    if np.any(arr <= 0.0):
        raise ValueError(f"{name} must be strictly positive (shift the signal first)")
    return arr


def gm11_fit(x0: ArrayLike) -> tuple[float, float]:
    """Fit GM(1,1) to a positive window by least squares.

    Parameters
    ----------
    x0 : array_like, shape (m,)
        Window of the (shifted) signal, m >= 4, finite and strictly positive. Units
        arbitrary (volts for the HRG output).

    Returns
    -------
    a : float
        Development coefficient (1/sample); a < 0 for a growing window.
    b : float
        Grey input, in the units of ``x0``.

    Raises
    ------
    ValueError
        If ``x0`` is not 1-D, shorter than 4, non-finite or not strictly positive.

    Notes
    -----
    Solves x⁰(k) + a·z¹(k) = b, k = 2..m, with ``numpy.linalg.lstsq`` (an orthogonal
    factorisation) rather than the normal equations, whose squared condition number
    loses half the digits on a nearly constant window.
    """
    return _gm11_fit(_check_window("x0", x0))


def _gm11_fit(x0: NDArray[np.float64]) -> tuple[float, float]:
    x1 = np.cumsum(x0)
    z1 = 0.5 * (x1[1:] + x1[:-1])
    design = np.column_stack([-z1, np.ones_like(z1)])
    (a, b), *_ = np.linalg.lstsq(design, x0[1:], rcond=None)
    return float(a), float(b)


def _response_basis(a: float, k: NDArray[np.float64]) -> tuple[NDArray, NDArray]:
    """u(k) = e^{−a(k−1)} and g(k) = (1 − u(k))/a, the latter exact as a → 0."""
    s = k - 1.0
    u = np.exp(-a * s)
    g = s.copy() if a == 0.0 else -np.expm1(-a * s) / a
    return u, g


def _h(a: float) -> float:
    """(1 − e^{−a})/a, equal to 1 at a = 0."""
    return 1.0 if a == 0.0 else -math.expm1(-a) / a


def gm11_optimal_initial_value(x0: ArrayLike, a: float, b: float) -> float:
    """Initial value C minimising Σ_k (x̂¹(k) − x¹(k))² over the window.

    Parameters
    ----------
    x0 : array_like, shape (m,)
        The window the model was fitted on (units of the signal).
    a, b : float
        GM(1,1) coefficients from :func:`gm11_fit`.

    Returns
    -------
    float
        C* = Σ u(k)·(x¹(k) − b·g(k)) / Σ u(k)², with x̂¹(k) = C·u(k) + b·g(k).

    Notes
    -----
    x̂¹ is linear in C, so the least-squares optimum is this closed form. The paper
    (its ref. 9) writes the optimum as a weight β between x¹(1) and x¹(m); docs/methods.md §3
    states that this is the same optimum. The β formula itself is not legible in our
    copy of the paper, so that equivalence is taken from docs/methods.md §3, not re-derived.
    """
    arr = _check_window("x0", x0)
    return _optimal_c(arr, float(a), float(b))


def _optimal_c(x0: NDArray[np.float64], a: float, b: float) -> float:
    k = np.arange(1, x0.size + 1, dtype=float)
    u, g = _response_basis(a, k)
    x1 = np.cumsum(x0)
    return float(np.dot(u, x1 - b * g) / np.dot(u, u))


def gm11_fitted_values(a: float, b: float, c: float, m: int) -> NDArray[np.float64]:
    """In-window model values x̂⁰(1..m) (x̂⁰(1) = C, x̂⁰(k) = x̂¹(k) − x̂¹(k−1))."""
    m = check_int("m", m, minimum=1)
    k = np.arange(1, m + 1, dtype=float)
    u, g = _response_basis(float(a), k)
    x1_hat = c * u + b * g
    return np.diff(x1_hat, prepend=0.0)


def gm11_predict_next(
    a: float, b: float, c: float, m: int, *, evaluation: Evaluation = "careful"
) -> float:
    """One-step prediction x̂⁰(m+1) = x̂¹(m+1) − x̂¹(m) of a window of length m.

    Parameters
    ----------
    a, b : float
        GM(1,1) coefficients.
    c : float
        Initial value C of the time response (x⁰(1) for the classic model).
    m : int
        Window length.
    evaluation : {"careful", "textbook"}
        ``"careful"``: (b − a·C)·h(a)·e^{−a(m−1)}, h(a) = −expm1(−a)/a, exact as
        a → 0. ``"textbook"``: (1 − e^{a})·(C − b/a)·e^{−a·m} as printed in the GM
        literature; kept only to reproduce the paper's collapse on flat signals.

    Returns
    -------
    float
        Predicted next sample (units of the window). The textbook form returns NaN
        for a == 0.
    """
    m = check_int("m", m, minimum=1)
    a, b, c = float(a), float(b), float(c)
    if evaluation == "careful":
        return (b - a * c) * _h(a) * math.exp(-a * (m - 1))
    if evaluation == "textbook":
        if a == 0.0:
            return math.nan
        return (1.0 - math.exp(a)) * (c - b / a) * math.exp(-a * m)
    raise ValueError(f"evaluation must be 'careful' or 'textbook', got {evaluation!r}")


def gm11_predict_classic(x0: ArrayLike, *, evaluation: Evaluation = "careful") -> float:
    """Classic GM(1,1) one-step prediction of a positive window (C = x⁰(1))."""
    arr = _check_window("x0", x0)
    a, b = _gm11_fit(arr)
    return gm11_predict_next(a, b, float(arr[0]), arr.size, evaluation=evaluation)


def gm11_predict_optimized(x0: ArrayLike) -> float:
    """GM(1,1) one-step prediction of a positive window with the optimized C."""
    arr = _check_window("x0", x0)
    a, b = _gm11_fit(arr)
    return gm11_predict_next(a, b, _optimal_c(arr, a, b), arr.size)


# ------------------------------------------------------------------ positive shift

DEFAULT_LEVEL_RATIO = 10.0
"""Default ratio of a shifted window's minimum to its range (see :func:`positive_shift`).

Measured on noise-free sine, ramp and exponential-approach records (m = 10 and 20): the
improved predictor's mean one-step error falls by 1–2 decades from ratio 0.5 to 10 and
is flat beyond; the classic one keeps improving slowly toward the linear-trend limit."""


def _lift(window: NDArray[np.float64], level_ratio: float) -> tuple[NDArray, float, float]:
    """Shifted window ``(window − lo) + level`` and the pair ``(lo, level)``.

    Subtracting the minimum first rounds at the scale of the spread (exactly, for
    samples within a factor 2 of the minimum, Sterbenz); adding one precomputed offset
    would round at the scale of |min| and lose the digits of a small spread far from 0.
    """
    lo = float(window.min())
    span = float(window.max()) - lo
    if span > 0.0:
        level = level_ratio * span
    else:
        level = abs(lo) if lo != 0.0 else 1.0
    return (window - lo) + level, lo, level


def positive_shift(window: ArrayLike, level_ratio: float = DEFAULT_LEVEL_RATIO) -> float:
    """Offset added to a window to make it strictly positive before GM(1,1).

    Parameters
    ----------
    window : array_like, shape (m,)
        Finite samples of any sign, units of the signal.
    level_ratio : float
        Ratio of the shifted window's minimum to the window's range (max − min), > 0.

    Returns
    -------
    float
        ``shift`` such that ``window + shift`` has minimum ``level_ratio·range``. For a
        constant window (range 0) the shifted level is ``|value|`` (1 for zeros), so a
        positive constant is left as it is. Units of the signal.

    Notes
    -----
    The shift depends on the current window only (past data), never on later samples;
    predictions are shifted back by the same amount. Internally the window is lifted
    as ``(x − min) + level`` and the prediction lowered as ``(p − level) + min``,
    which is exact to rounding even when the spread is tiny compared to the level.

    Why tie the level to the window's own range instead of shifting only negative
    data: the GM(1,1) prediction of ``s·x`` is ``s`` times that of ``x`` (``a`` is
    scale-free, ``b`` scales), but it changes with an added offset — a window far above
    its spread looks like a nearly straight exponential, one close to zero like a
    steep one. A gyro output's zero is arbitrary (a bias fault moves it, the output may
    cross zero), so every window is lifted to the same *relative* level. The
    predictors are then equivariant under offset and positive scale:
    predict(s·y + d) = s·predict(y) + d to rounding, and the flat-window test |a| <
    a_min is unaffected by where the signal sits. Shifting "only when negative" would
    make the prediction jump whenever the signal crosses zero.
    """
    arr = check_finite_array("window", window, ndim=1)
    if arr.size == 0:
        raise ValueError("window must not be empty")
    ratio = check_positive("level_ratio", level_ratio)
    _, lo, level = _lift(arr, ratio)
    return level - lo


# ------------------------------------------------------------------ polynomial fits


def _poly_extrapolate(k: NDArray, values: NDArray, order: int, k_next: float) -> float:
    """Least-squares polynomial of ``order`` in k through ``values``, evaluated at k_next.

    k is centred and scaled to [−1, 1] first so the Vandermonde matrix stays well
    conditioned for any window length.
    """
    centre = 0.5 * (k[0] + k[-1])
    half = max(0.5 * (k[-1] - k[0]), 1.0)
    design = np.vander((k - centre) / half, order + 1)
    coef, *_ = np.linalg.lstsq(design, values, rcond=None)
    row = np.vander(np.array([(k_next - centre) / half]), order + 1)
    return float((row @ coef)[0])


# ------------------------------------------------------------------ predictors


class GreyPredictor(Protocol):
    """What :class:`GreyFaultDetector` needs from a one-step predictor."""

    @property
    def min_samples(self) -> int: ...

    @property
    def ready(self) -> bool: ...

    def update(self, y: float) -> float: ...

    def reset(self) -> None: ...

    def get_state(self) -> dict[str, Any]: ...

    def set_state(self, state: Mapping[str, Any]) -> None: ...


def _check_sample(y: float) -> float:
    if isinstance(y, bool):
        raise TypeError(f"y must be a number, got {y!r}")
    try:
        v = float(y)
    except (TypeError, ValueError):
        raise TypeError(f"y must be a number, got {y!r}") from None
    if not math.isfinite(v):
        raise ValueError(f"y must be finite, got {y!r}")
    return v


class _WindowedPredictor:
    """Sample buffer, state handling and the update loop shared by both predictors."""

    def __init__(self, window: int | None, level_ratio: float) -> None:
        self.window = None if window is None else check_int(
            "window", window, minimum=GM11_MIN_LENGTH
        )
        self.level_ratio = check_positive("level_ratio", level_ratio)
        self._samples: NDArray[np.float64] = np.empty(0)
        self._prediction = math.nan
        self._a = math.nan
        self._fallback = False

    @property
    def min_samples(self) -> int:
        """Samples needed before the first prediction."""
        return GM11_MIN_LENGTH if self.window is None else self.window

    @property
    def ready(self) -> bool:
        """True once enough samples are held for a prediction."""
        return self._samples.size >= self.min_samples

    @property
    def samples(self) -> NDArray[np.float64]:
        """Copy of the samples currently modelled (oldest first), signal units."""
        return self._samples.copy()

    @property
    def last_a(self) -> float:
        """Development coefficient a of the last fit (1/sample), NaN before it."""
        return self._a

    @property
    def last_used_fallback(self) -> bool:
        """True if the last prediction came from the flat-window polynomial."""
        return self._fallback

    def reset(self) -> None:
        """Forget all samples (as at construction)."""
        self._samples = np.empty(0)
        self._prediction = math.nan
        self._a = math.nan
        self._fallback = False

    def update(self, y: float) -> float:
        """Add one sample and predict the next one.

        Parameters
        ----------
        y : float
            New sample, signal units. Must be finite.

        Returns
        -------
        float
            Prediction of the next sample (signal units); NaN until ``min_samples``
            samples have been seen.

        Raises
        ------
        ValueError
            If ``y`` is NaN or infinite (the detector filters those out first).
        """
        v = _check_sample(y)
        samples = np.append(self._samples, v)
        if self.window is not None and samples.size > self.window:
            samples = samples[-self.window :]
        self._samples = samples
        if samples.size < self.min_samples:
            self._prediction = math.nan
            return self._prediction
        lifted, lo, level = _lift(samples, self.level_ratio)
        self._prediction = (self._predict_lifted(lifted) - level) + lo
        return self._prediction

    def _predict_lifted(self, lifted: NDArray) -> float:
        raise NotImplementedError

    def get_state(self) -> dict[str, Any]:
        """Full state as a plain dict (deep copy); see :meth:`set_state`."""
        return {
            "samples": self._samples.copy(),
            "prediction": float(self._prediction),
            "a": float(self._a),
            "fallback": int(self._fallback),
        }

    def set_state(self, state: Mapping[str, Any]) -> None:
        """Restore a state produced by :meth:`get_state` of an identically built instance.

        Raises
        ------
        ValueError
            If ``state`` lacks a key or holds more samples than the window.
        """
        missing = {"samples", "prediction", "a", "fallback"} - set(state)
        if missing:
            raise ValueError(f"state is missing keys {sorted(missing)}")
        samples = np.array(state["samples"], dtype=float).reshape(-1)
        if not np.all(np.isfinite(samples)):
            raise ValueError("state['samples'] must be finite")
        if self.window is not None and samples.size > self.window:
            raise ValueError(
                f"state['samples'] holds {samples.size} samples, window is {self.window}"
            )
        self._samples = samples
        self._prediction = float(state["prediction"])
        self._a = float(state["a"])
        self._fallback = bool(state["fallback"])


class ClassicGreyPredictor(_WindowedPredictor):
    """Classic GM(1,1) one-step predictor (C = x⁰(1)), streaming.

    Parameters
    ----------
    window : int or None
        Moving-window length m >= 4 in samples, or None for the paper's "ordinary"
        GM(1,1), which models the whole record seen so far (memory and cost per
        sample grow linearly; use it for reference runs, not in a long co-simulation).
    level_ratio : float, optional
        Positive-shift level, see :func:`positive_shift`.
    evaluation : {"careful", "textbook"}, optional
        How the time response is evaluated, see :func:`gm11_predict_next`.
        ``"textbook"`` reproduces the paper's collapse on an exactly constant window.

    Notes
    -----
    ``update`` returns NaN until ``min_samples`` (``window``, or 4 for the growing
    record) samples have been seen, and raises ``ValueError`` on a non-finite sample.
    """

    def __init__(
        self, window: int | None, *, level_ratio: float = DEFAULT_LEVEL_RATIO,
        evaluation: Evaluation = "careful",
    ) -> None:
        super().__init__(window, level_ratio)
        if evaluation not in ("careful", "textbook"):
            raise ValueError(
                f"evaluation must be 'careful' or 'textbook', got {evaluation!r}"
            )
        self.evaluation: Evaluation = evaluation

    def _predict_lifted(self, lifted: NDArray) -> float:
        a, b = _gm11_fit(lifted)
        self._a = a
        self._fallback = False
        return gm11_predict_next(
            a, b, float(lifted[0]), lifted.size, evaluation=self.evaluation
        )


class ImprovedGreyPredictor(_WindowedPredictor):
    """Improved moving-window GM(1,1) one-step predictor (the paper's method), streaming.

    Parameters
    ----------
    window : int
        Moving-window length m in samples, >= max(4, residual_order + 2).
    a_min : float, optional
        Flat-window threshold on |a| (1/sample, >= 0). Below it the prediction is the
        least-squares polynomial of degree ``residual_order`` through the window,
        extrapolated one sample. Default 1e-6.
    residual_order : int, optional
        Degree of the residual polynomial φ(k) (paper: 2, φ = a2·k² + a1·k + a0).
    level_ratio : float, optional
        Positive-shift level, see :func:`positive_shift`.

    Notes
    -----
    Per sample: lift the window positive; fit GM(1,1); take the optimized initial
    value C; compute the in-window residuals ε(k) = x⁰(k) − x̂⁰(k) for k = 2..m, fit
    φ(k) to them by least squares and add φ(m+1) to the GM prediction x̂⁰(m+1); shift
    back. ε(1) = x⁰(1) − C is left out (the paper lists m residuals): x̂⁰(1) = C is the
    initial condition, not an output of the exponential law, and including it
    degraded noise-free one-step errors on ramps about 20-fold in our trials.

    With the careful evaluation GM(1,1) itself does not fail as a → 0 (see the module
    notes), so ``a_min`` is a modelling switch, not a numerical guard: when |a|·m ≪ 1
    the exponential carries no information beyond a constant and the polynomial of
    the window is the better model. Because windows are lifted to a fixed relative
    level, |a| is of order ln(1 + 1/level_ratio)/m for any window with a trend and
    ~1e−17 for a constant window; 1e-6 separates the two with a wide margin.

    ``update`` returns NaN until ``window`` samples have been seen and raises
    ``ValueError`` on a non-finite sample.
    """

    def __init__(
        self, window: int, *, a_min: float = 1e-6, residual_order: int = 2,
        level_ratio: float = DEFAULT_LEVEL_RATIO,
    ) -> None:
        if window is None:
            raise ValueError("window must be an integer >= 4 (the improved model is windowed)")
        order = check_int("residual_order", residual_order, minimum=0)
        super().__init__(window, level_ratio)
        assert self.window is not None
        if self.window < order + 2:
            raise ValueError(
                f"window must be >= residual_order + 2 = {order + 2}, got {window!r}"
            )
        self.residual_order = order
        self.a_min = check_nonnegative("a_min", a_min)

    def _predict_lifted(self, lifted: NDArray) -> float:
        m = lifted.size
        k = np.arange(1, m + 1, dtype=float)
        a, b = _gm11_fit(lifted)
        self._a = a
        if abs(a) < self.a_min:
            self._fallback = True
            return _poly_extrapolate(k, lifted, self.residual_order, m + 1.0)
        self._fallback = False
        c = _optimal_c(lifted, a, b)
        residual = lifted - gm11_fitted_values(a, b, c, m)
        correction = _poly_extrapolate(k[1:], residual[1:], self.residual_order, m + 1.0)
        return gm11_predict_next(a, b, c, m) + correction


# ------------------------------------------------------------------ detector


@dataclass(frozen=True)
class GreyDetectorOutput:
    """Result of one :meth:`GreyFaultDetector.update`.

    Attributes
    ----------
    time_s : float
        Time of the sample, s.
    measurement : float
        The sample as received (signal units; may be NaN/inf when ``valid`` is False).
    prediction : float
        ŷ(k), predicted for this sample from the samples before it (signal units);
        NaN during warm-up. While in alarm this is the bounded substitute (see
        :class:`GreyFaultDetector`), i.e. the value that was also fed to the predictor.
    error : float
        y(k) − ŷ(k), signal units; NaN during warm-up or for an invalid sample.
    alarm : bool
        Fault alarm after this sample.
    alarm_onset_time_s : float
        Onset time of the current alarm, s; NaN when not in alarm.
    valid : bool
        False if the sample was NaN/inf and was skipped (state untouched).
    cleared : bool
        True if the alarm was cleared at this sample after ``clear_after_s``.
    """

    time_s: float
    measurement: float
    prediction: float
    error: float
    alarm: bool
    alarm_onset_time_s: float
    valid: bool
    cleared: bool


class GreyFaultDetector:
    """One-step grey-prediction fault detector with substitution and timed clearing.

    Parameters
    ----------
    predictor : ClassicGreyPredictor or ImprovedGreyPredictor
        Streaming one-step predictor; the detector owns it from now on (it is reset).
    threshold : float
        Alarm threshold on |y(k) − ŷ(k)|, signal units (V for the HRG output), > 0.
    sample_period_s : float
        Sample period, s, > 0; the sample clock when ``update`` gets no ``time_s``.
    clear_after_s : float or None, optional
        Clear an alarm that has lasted this long (s, > 0) and re-seed the predictor
        with the most recent measured samples so the next fault can be seen (paper:
        20 s). None: alarms end only when the error falls below the threshold.
    reseed_length : int or None, optional
        Measured samples kept for re-seeding; default ``predictor.min_samples``.
    envelope_margin : float, optional
        Bound on the substituted prediction, in units of the fault-free span (>= 0,
        dimensionless): while in alarm ŷ is kept within
        [lo − margin·(hi − lo), hi + margin·(hi − lo)], lo/hi the smallest and largest
        fault-free sample seen since reset. Default 1.

    Notes
    -----
    Per valid sample y(k): error e = y(k) − ŷ(k); alarm = |e| > threshold. While in
    alarm the predictor is fed ŷ(k) instead of y(k), so the model keeps extrapolating
    the fault-free signal and the alarm lasts as long as the fault instead of a single
    pulse (after one faulty sample a plain predictor would already have absorbed it).

    Bounded substitution: once the window holds only substituted samples the
    predictor extrapolates its own extrapolation, and the GM exponential and the
    quadratic residual compound without limit over a long alarm (measured with the
    unbounded detector: 2e7 V after a pitch manoeuvre at 100 Hz, −1184 V on the
    seed-001 timeline at 10 Hz after the stuck fault). While in alarm, ŷ is therefore
    clipped to the envelope of the fault-free samples seen since reset widened by
    ``envelope_margin`` times its span, and once it has been clipped it is held at
    that value for the rest of the alarm (see :meth:`_bounded` for why). Inside the
    envelope the substitute is the predictor's own, as in the paper. The reported
    prediction (and so the error) is the bounded value.

    No alarm is possible before the predictor's window is full: the first
    ``min_samples`` samples are assumed fault-free. A non-finite prediction with a full
    window (only the textbook classic model on an exactly degenerate window produces
    one) raises the alarm: the detector cannot vouch for that sample.

    A NaN/inf sample is skipped: the state is not touched (the pending prediction
    stays for the next valid sample) and the output has ``valid=False``.
    """

    def __init__(
        self, predictor: GreyPredictor, threshold: float, sample_period_s: float,
        clear_after_s: float | None = None, *, reseed_length: int | None = None,
        envelope_margin: float = 1.0,
    ) -> None:
        for attr in ("update", "reset", "get_state", "set_state", "min_samples", "ready"):
            if not hasattr(predictor, attr):
                raise TypeError(f"predictor must provide {attr!r}, got {type(predictor)!r}")
        self.predictor = predictor
        self.threshold = check_positive("threshold", threshold)
        self.sample_period_s = check_positive("sample_period_s", sample_period_s)
        self.clear_after_s = (
            None if clear_after_s is None else check_positive("clear_after_s", clear_after_s)
        )
        self.reseed_length = (
            predictor.min_samples if reseed_length is None
            else check_int("reseed_length", reseed_length, minimum=1)
        )
        self.envelope_margin = check_nonnegative("envelope_margin", envelope_margin)
        self.reset()

    def reset(self) -> None:
        """Return to the state right after construction."""
        self.predictor.reset()
        self._pending = math.nan
        self._in_alarm = False
        self._onset = math.nan
        self._recent: NDArray[np.float64] = np.empty(0)
        self._n_accepted = 0
        self._envelope_min = math.inf
        self._envelope_max = -math.inf
        self._hold = math.nan

    @property
    def alarm(self) -> bool:
        """Current alarm state."""
        return self._in_alarm

    @property
    def pending_prediction(self) -> float:
        """Prediction for the next sample (signal units), NaN during warm-up.

        Bounded while in alarm (the value the next output will report)."""
        return self._pending

    @property
    def envelope(self) -> tuple[float, float]:
        """(min, max) of the fault-free samples seen since reset, signal units.

        (inf, −inf) before the first sample."""
        return self._envelope_min, self._envelope_max

    def update(self, y: float, time_s: float | None = None) -> GreyDetectorOutput:
        """Process one sample.

        Parameters
        ----------
        y : float
            Measured sample, signal units. NaN/inf is skipped, see class notes.
        time_s : float, optional
            Sample time, s. Default: ``n·sample_period_s`` with n the number of valid
            samples accepted so far (a skipped sample does not advance this clock;
            pass ``time_s`` from the host when samples can be dropped).

        Returns
        -------
        GreyDetectorOutput
        """
        if isinstance(y, bool):
            raise TypeError(f"y must be a number, got {y!r}")
        try:
            value = float(y)
        except (TypeError, ValueError):
            raise TypeError(f"y must be a number, got {y!r}") from None
        if time_s is None:
            t = self._n_accepted * self.sample_period_s
        else:
            t = float(time_s)
            if not math.isfinite(t):
                raise ValueError(f"time_s must be finite, got {time_s!r}")
        predicted = self._pending
        if not math.isfinite(value):
            return GreyDetectorOutput(
                t, value, predicted, math.nan, self._in_alarm, self._onset, False, False
            )

        was_ready = self.predictor.ready
        self._n_accepted += 1
        self._recent = np.append(self._recent, value)[-self.reseed_length :]
        error = value - predicted
        if not was_ready:
            alarm = False
        elif not math.isfinite(predicted):
            alarm = True
        else:
            alarm = abs(error) > self.threshold
        if alarm and not self._in_alarm:
            self._onset = t

        if alarm and self.clear_after_s is not None and (
            t - self._onset >= self.clear_after_s - 1e-6 * self.sample_period_s
        ):
            self._reseed()
            self._in_alarm = False
            self._onset = math.nan
            return GreyDetectorOutput(t, value, predicted, error, False, math.nan, True, True)

        substitute = alarm and math.isfinite(predicted)
        if not alarm:
            self._widen_envelope(value)
        self._pending = self.predictor.update(predicted if substitute else value)
        self._in_alarm = alarm
        if alarm:
            self._pending = self._bounded(self._pending)
        else:
            self._onset = math.nan
            self._hold = math.nan
        return GreyDetectorOutput(
            t, value, predicted, error, alarm, self._onset, True, False
        )

    def _widen_envelope(self, value: float) -> None:
        self._envelope_min = min(self._envelope_min, value)
        self._envelope_max = max(self._envelope_max, value)

    def _bounded(self, prediction: float) -> float:
        """The substitute for the next sample while in alarm (signal units).

        Choice, measured on the seed-001 timeline (improved predictor, m = 10,
        threshold 0.05 V, 20 s clearing, noise-free, at 2 Hz and 10 Hz) and on an
        HRG output following a ±0.1 rad/s (±1 V) pitch-rate manoeuvre at 100 Hz,
        with and without 2 mV noise:

        * Envelope of the fault-free window at onset (± 1–3 ranges): bounded, but the
          5 % scale-fault alarm ends at 431–433 s instead of 439.5 s. That window's
          range (0.0075 V at 2 Hz, about 50 times less at 100 Hz) is far below the
          signal's legitimate 0.11 V motion during the 20 s alarm, which the
          self-fed quadratic extrapolation does follow; a window-based bound cuts it.
        * Linear trend of the onset window (or a band moving with it): at 420 s the
          signal is at a peak (slope ≈ 0, curvature down), so the line departs
          upwards; after a re-seed on a window holding a fault's end the slope is
          that of the step and the band runs away (13.7 V on the manoeuvre).
        * Envelope of all fault-free samples since reset: wide enough for the
          legitimate motion (alarm intervals identical to the unbounded detector at
          2 Hz, 10 Hz and 100 Hz), and the runaway is caught at most one span outside the
          observed signal. Clipping alone is not enough: a polynomial extrapolator
          fed a clipped, kinked window turns around and re-enters, so the alarm
          chatters (noisy manoeuvre). Hence the hold: once the model's own
          extrapolation has left the plausible range it is not trusted again
          until the alarm ends or is cleared.
        """
        if not math.isfinite(prediction):
            return prediction
        if not math.isnan(self._hold):
            return self._hold
        span = self._envelope_max - self._envelope_min
        lo = self._envelope_min - self.envelope_margin * span
        hi = self._envelope_max + self.envelope_margin * span
        if lo <= prediction <= hi:
            return prediction
        self._hold = min(max(prediction, lo), hi)
        return self._hold

    def _reseed(self) -> None:
        self.predictor.reset()
        self._pending = math.nan
        self._hold = math.nan
        # the re-seeded samples are the new reference signal (the paper's clearing
        # accepts them), so they count as fault-free for the envelope too
        for v in self._recent:
            self._widen_envelope(float(v))
            self._pending = self.predictor.update(float(v))

    def get_state(self) -> dict[str, Any]:
        """Full state as a flat plain dict (deep copy); predictor keys are prefixed."""
        state: dict[str, Any] = {
            f"predictor.{key}": copy.deepcopy(val)
            for key, val in self.predictor.get_state().items()
        }
        state.update(
            pending_prediction=float(self._pending),
            in_alarm=int(self._in_alarm),
            onset_time_s=float(self._onset),
            recent=self._recent.copy(),
            n_accepted=int(self._n_accepted),
            envelope_min=float(self._envelope_min),
            envelope_max=float(self._envelope_max),
            hold=float(self._hold),
        )
        return state

    def set_state(self, state: Mapping[str, Any]) -> None:
        """Restore a state from :meth:`get_state` of an identically built detector.

        Raises
        ------
        ValueError
            If a key is missing or the stored window does not fit.
        """
        own = {
            "pending_prediction", "in_alarm", "onset_time_s", "recent", "n_accepted",
            "envelope_min", "envelope_max", "hold",
        }
        missing = own - set(state)
        if missing:
            raise ValueError(f"state is missing keys {sorted(missing)}")
        recent = np.array(state["recent"], dtype=float).reshape(-1)
        if recent.size > self.reseed_length:
            raise ValueError(
                f"state['recent'] holds {recent.size} samples, "
                f"reseed_length is {self.reseed_length}"
            )
        prefix = "predictor."
        self.predictor.set_state(
            {k[len(prefix):]: copy.deepcopy(v) for k, v in state.items() if k.startswith(prefix)}
        )
        self._pending = float(state["pending_prediction"])
        self._in_alarm = bool(state["in_alarm"])
        self._onset = float(state["onset_time_s"])
        self._recent = recent
        self._n_accepted = int(state["n_accepted"])
        self._envelope_min = float(state["envelope_min"])
        self._envelope_max = float(state["envelope_max"])
        self._hold = float(state["hold"])


# ------------------------------------------------------------------ metrics


def prediction_errors_percent(y: ArrayLike, y_hat: ArrayLike) -> tuple[float, float]:
    """Mean and maximum one-step prediction error in percent of the measured value.

    Parameters
    ----------
    y : array_like, shape (n,)
        Measured samples, signal units; finite and non-zero wherever ``y_hat`` is
        finite.
    y_hat : array_like, shape (n,)
        Predictions for the same samples (NaN where none was made, e.g. warm-up).

    Returns
    -------
    mean_percent, max_percent : float
        Mean and maximum of 100·|y(k) − ŷ(k)| / |y(k)| over the samples with a finite
        prediction. The reference is the measured sample in the signal's own units
        (not the shifted window), as the paper's 0.77 %/2.69 % (classic) and
        0.24 %/0.76 % (improved) figures appear to be; the figure therefore depends on
        where the signal's zero is.

    Raises
    ------
    ValueError
        On mismatched shapes, no finite prediction, or a zero/non-finite ``y`` where
        a prediction exists.
    """
    y_arr = np.asarray(y, dtype=float)
    p_arr = np.asarray(y_hat, dtype=float)
    if y_arr.ndim != 1 or p_arr.shape != y_arr.shape:
        raise ValueError(
            f"y and y_hat must be 1-D of equal length, got {y_arr.shape} and {p_arr.shape}"
        )
    used = np.isfinite(p_arr)
    if not np.any(used):
        raise ValueError("y_hat has no finite prediction")
    ref = y_arr[used]
    if not np.all(np.isfinite(ref)) or np.any(ref == 0.0):
        raise ValueError("y must be finite and non-zero wherever y_hat is finite")
    rel = 100.0 * np.abs(ref - p_arr[used]) / np.abs(ref)
    return float(rel.mean()), float(rel.max())
