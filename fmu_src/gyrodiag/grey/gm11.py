"""GM(1,1): the grey model behind the HRG predictors and detector (fit, prediction, shift).

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
or infinite sample; :class:`gyrodiag.grey.detector.GreyFaultDetector` instead skips such
a sample without touching its state and flags it invalid, so a co-simulation can keep
running.
"""


from __future__ import annotations

import math
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..common._validation import (
    check_finite_array,
    check_int,
    check_positive,
)

__all__ = [
    "DEFAULT_LEVEL_RATIO",
    "GM11_MIN_LENGTH",
    "gm11_fit",
    "gm11_fitted_values",
    "gm11_optimal_initial_value",
    "gm11_predict_classic",
    "gm11_predict_next",
    "gm11_predict_optimized",
    "positive_shift",
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
