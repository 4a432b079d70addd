"""Per-sample kernels in plain Python floats (the fallback of the compiled accelerator).

Same classes and functions as the C extension ``gyrodiag.common._ckernels`` (see
``_ckernels.c``), with the same arithmetic in the same order, so that both give the
same outputs to rounding. Callers go through :mod:`gyrodiag.common._accel`, which picks one.

Nothing here checks its arguments: the algorithm classes validate once at their
boundary and call these kernels on plain floats (a numpy call on a 5-element array
costs about a microsecond; the arithmetic of a whole sample costs less).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

__all__ = ["LinearObserver", "PotterRLS", "SosCascade", "improved_grey_predict"]


_STEP_CACHE: dict[tuple, object] = {}


def _compiled(key: tuple, source: str, name: str) -> object:
    """Compile generated straight-line code once per shape (the loops unrolled).

    CPython spends most of a small loop on the loop itself; unrolled expressions over
    local variables run 2-3 times faster (docs/notes.md, kernels).
    """
    fn = _STEP_CACHE.get(key)
    if fn is None:
        namespace: dict[str, object] = {"sqrt": math.sqrt, "exp": math.exp,
                                         "expm1": math.expm1}
        exec(compile(source, f"<gyrodiag kernel {name}>", "exec"), namespace)
        fn = _STEP_CACHE[key] = namespace[name]
    return fn


def _sos_source(n_sections: int, n_channels: int) -> str:
    lines = ["def sos_step(coef, z, x):"]
    lines.append("    " + ", ".join(f"x{c}" for c in range(n_channels))
                 + (", = x" if n_channels == 1 else " = x"))
    for s in range(n_sections):
        lines.append(f"    b0, b1, b2, a1, a2 = coef[{s}]")
        for c in range(n_channels):
            i0, i1 = 2 * (s * n_channels + c), 2 * (s * n_channels + c) + 1
            lines.append(f"    y = b0 * x{c} + z[{i0}]")
            lines.append(f"    z[{i0}] = b1 * x{c} - a1 * y + z[{i1}]")
            lines.append(f"    z[{i1}] = b2 * x{c} - a2 * y")
            lines.append(f"    x{c} = y")
    lines.append("    return [" + ", ".join(f"x{c}" for c in range(n_channels)) + "]")
    return "\n".join(lines) + "\n"


class SosCascade:
    """Second-order sections (direct form II transposed) on ``n_channels`` channels.

    Parameters
    ----------
    coefficients : sequence of float
        ``[b0, b1, b2, a1, a2]`` per section (a0 = 1), sections in cascade order.
    n_sections, n_channels : int
        Number of sections and of parallel channels.

    Notes
    -----
    The recursion is that of :func:`scipy.signal.sosfilt` in the same operation order:
    y = b0·x + z0, z0 ← b1·x − a1·y + z1, z1 ← b2·x − a2·y.
    """

    def __init__(self, coefficients: Sequence[float], n_sections: int, n_channels: int) -> None:
        self.n_sections = int(n_sections)
        self.n_channels = int(n_channels)
        c = [float(v) for v in coefficients]
        if len(c) != 5 * self.n_sections:
            raise ValueError(f"coefficients must hold 5 * n_sections = {5 * self.n_sections} "
                             f"values, got {len(c)}")
        self._coef = [tuple(c[5 * s:5 * s + 5]) for s in range(self.n_sections)]
        self._fn = _compiled(("sos", self.n_sections, self.n_channels),
                             _sos_source(self.n_sections, self.n_channels), "sos_step")
        self.reset()

    def reset(self) -> None:
        """Zero state."""
        # flat: section-major, then channel, then (z0, z1)
        self._z = [0.0] * (2 * self.n_sections * self.n_channels)

    def step(self, x: Sequence[float]) -> list[float]:
        """Filter one sample per channel and return the outputs."""
        return self._fn(self._coef, self._z, x)  # type: ignore[operator]

    def get_state(self) -> list[float]:
        """State flattened in the order of an array of shape (n_sections, 2, n_channels)."""
        n_ch = self.n_channels
        z = self._z
        return [z[2 * (s * n_ch + ch) + j] for s in range(self.n_sections) for j in range(2)
                for ch in range(n_ch)]

    def set_state(self, flat: Sequence[float]) -> None:
        """Restore a state from :meth:`get_state` (same ordering)."""
        vals = [float(v) for v in flat]
        n_ch = self.n_channels
        for s in range(self.n_sections):
            for j in range(2):
                for ch in range(n_ch):
                    self._z[2 * (s * n_ch + ch) + j] = vals[(s * 2 + j) * n_ch + ch]


def _rls_source(n: int, forgetting_is_one: bool, capped: bool) -> str:
    """Straight-line Potter step for n parameters; S flat row-major in ``st[0]``."""
    r = range(n)
    ind = "    "
    L = ["def rls_step(st, phi, y):", ind + "S = st[0]", ind + "lam = st[2]"]
    L.append(ind + "".join(f"p{i}, " for i in r) + "= phi")
    L.append(ind + "".join(f"t{i}, " for i in r) + "= st[1]")
    for j in r:
        L.append(ind + f"f{j} = " + " + ".join(f"S[{i * n + j}] * p{i}" for i in r))
    L.append(ind + "alpha = lam + (" + " + ".join(f"f{j} * f{j}" for j in r) + ")")
    L.append(ind + "err = y - (" + " + ".join(f"p{i} * t{i}" for i in r) + ")")
    L.append(ind + "gamma = 1.0 / (alpha + sqrt(lam * alpha))")
    for i in r:
        L.append(ind + f"sf{i} = " + " + ".join(f"S[{i * n + j}] * f{j}" for j in r))
        L.append(ind + f"n{i} = t{i} + (sf{i} / alpha) * err")
        L.append(ind + f"g{i} = gamma * sf{i}")
    L.append(ind + "st[1] = [" + ", ".join(f"n{i}" for i in r) + "]")
    L.append(ind + "step = max(" + ", ".join(f"abs(n{i} - t{i})" for i in r) + ")")
    div = "" if forgetting_is_one else " / st[3]"
    terms = ", ".join(f"(S[{i * n + j}] - g{i} * f{j}){div}" for i in r for j in r)
    L.append(ind + f"S = [{terms}]")
    if capped:
        L.append(ind + "tr = " + " + ".join(f"S[{k}] * S[{k}]" for k in range(n * n)))
        L.append(ind + "if tr > st[4]:")
        L.append(ind * 2 + "scale = sqrt(st[4] / tr)")
        L.append(ind * 2 + "S = [v * scale for v in S]")
    L.append(ind + "st[0] = S")
    L.append(ind + "return step")
    return "\n".join(L) + "\n"


class PotterRLS:
    """Square-root (Potter) RLS step with forgetting and a trace cap on P = S·Sᵀ.

    Parameters
    ----------
    n : int
        Number of parameters.
    forgetting : float
        Forgetting factor λ in (0, 1].
    max_trace : float
        Cap on trace(P); ``math.inf`` for none (plain RLS).

    Notes
    -----
    One step, with φ the regressor and y the target (sums in index order)::

        f = Sᵀφ;  α = λ + fᵀf;  Sf = S·f;  e = y − φᵀθ;  γ = 1/(α + √(λα))
        θ ← θ + (Sf/α)·e;  S ← (S − (γ·Sf)·fᵀ)/√λ  (no division when λ = 1)
        S ← S·√(max_trace/tr) if tr = trace(S·Sᵀ) > max_trace
    """

    def __init__(self, n: int, forgetting: float, max_trace: float) -> None:
        self.n = int(n)
        self.forgetting = float(forgetting)
        self.max_trace = float(max_trace)
        # [S (flat, row-major), θ, λ, √λ, max_trace]
        self._st: list = [[0.0] * (self.n * self.n), [0.0] * self.n, self.forgetting,
                          math.sqrt(self.forgetting), self.max_trace]
        self._fn = _compiled(
            ("rls", self.n, self.forgetting == 1.0, self.max_trace < math.inf),
            _rls_source(self.n, self.forgetting == 1.0, self.max_trace < math.inf),
            "rls_step")

    @property
    def theta(self) -> list[float]:
        """θ (a list)."""
        return self._st[1]

    def set(self, theta: Sequence[float], S: Sequence[float]) -> None:
        """Set θ (n values) and S (n·n values, row-major)."""
        self._st[1] = [float(v) for v in theta]
        self._st[0] = [float(v) for v in S]

    def get_S(self) -> list[float]:
        """S row-major."""
        return list(self._st[0])

    def step(self, phi: Sequence[float], y: float) -> float:
        """One update; returns max |Δθ| of this step."""
        return self._fn(self._st, phi, y)  # type: ignore[operator]


#: Longest window for which the grey kernel is generated as straight-line code.
_GREY_UNROLL_MAX = 256


def _grey_source(m: int) -> str:
    """Straight-line :func:`improved_grey_predict` for a window of m samples.

    The same operations in the same order as ``_improved_grey_loop`` and the C kernel
    (every sum accumulated left to right from the first term).
    """
    r = range(m)
    inner = range(1, m)
    ind = "    "
    L = ["def grey_predict(window, level_ratio, a_min, pw, rw):"]
    L.append(ind + "".join(f"w{k}, " for k in r) + "= window")
    L.append(ind + "lo = min(window)")
    L.append(ind + "span = max(window) - lo")
    L.append(ind + "if span > 0.0:")
    L.append(ind * 2 + "level = level_ratio * span")
    L.append(ind + "else:")
    L.append(ind * 2 + "level = abs(lo) if lo != 0.0 else 1.0")
    for k in r:
        L.append(ind + f"l{k} = (w{k} - lo) + level")
    L.append(ind + "x1 = l0")
    for k in inner:
        L.append(ind + f"x1 = x1 + l{k}")
        L.append(ind + f"z{k} = x1 - 0.5 * l{k}")
    L.append(ind + "z_mean = (" + " + ".join(f"z{k}" for k in inner) + f") / {m - 1}.0")
    L.append(ind + "l_mean = (" + " + ".join(f"l{k}" for k in inner) + f") / {m - 1}.0")
    for k in inner:
        L.append(ind + f"d{k} = z{k} - z_mean")
    L.append(ind + "szz = " + " + ".join(f"d{k} * d{k}" for k in inner))
    L.append(ind + "szl = " + " + ".join(f"d{k} * (l{k} - l_mean)" for k in inner))
    L.append(ind + "a = -szl / szz")
    L.append(ind + "b = l_mean + a * z_mean")
    L.append(ind + "if abs(a) < a_min:")
    L.append(ind * 2 + "".join(f"p{k}, " for k in r) + "= pw")
    L.append(ind * 2 + "pred = " + " + ".join(f"p{k} * l{k}" for k in r))
    L.append(ind * 2 + "return (pred - level) + lo, a, True")
    L.append(ind + "q = exp(-a)")
    L.append(ind + "az = a == 0.0")
    L.append(ind + "h = 1.0 if az else -expm1(-a) / a")
    L.append(ind + "u0 = 1.0")
    for k in range(1, m):
        L.append(ind + f"u{k} = u{k - 1} * q")
    L.append(ind + "c0 = l0")
    for k in inner:
        L.append(ind + f"c{k} = c{k - 1} + l{k}")
    for k in r:
        L.append(ind + f"g{k} = {k}.0 if az else -expm1(-a * {k}.0) / a")
    L.append(ind + "num = " + " + ".join(f"u{k} * (c{k} - b * g{k})" for k in r))
    L.append(ind + "den = " + " + ".join(f"u{k} * u{k}" for k in r))
    L.append(ind + "amp = (b - a * (num / den)) * h")
    L.append(ind + "".join(f"r{k}, " for k in inner) + "= rw")
    L.append(ind + "e1 = amp")
    for k in range(2, m + 1):
        L.append(ind + f"e{k} = e{k - 1} * q")
    L.append(ind + "corr = " + " + ".join(f"r{k} * (l{k} - e{k})" for k in inner))
    L.append(ind + f"return ((e{m} + corr) - level) + lo, a, False")
    return "\n".join(L) + "\n"


def improved_grey_predict(
    window: Sequence[float], level_ratio: float, a_min: float,
    poly_weights: Sequence[float], residual_weights: Sequence[float],
) -> tuple[float, float, bool]:
    """One-step prediction of the improved grey model for a full window.

    Parameters
    ----------
    window : sequence of float, length m >= 4
        Samples, oldest first, signal units.
    level_ratio : float
        Positive-shift level (see :func:`gyrodiag.grey.positive_shift`).
    a_min : float
        Flat-window threshold on |a|.
    poly_weights : sequence of float, length m
        w with Σ w_k·v_k = least-squares polynomial through v(1..m) evaluated at m + 1.
    residual_weights : sequence of float, length m − 1
        The same for the residual fit through k = 2..m.

    Returns
    -------
    prediction, a, fallback
        Prediction of the next sample (signal units), development coefficient a of the
        lifted window, and whether the flat-window polynomial was used.

    Notes
    -----
    Closed forms (lifted window L, x¹ = cumsum L, z(k) = x¹(k) − L(k)/2, rows k = 2..m):
    centred 2×2 normal equations a = −Σ(z − z̄)(L − L̄)/Σ(z − z̄)², b = L̄ + a·z̄;
    optimal initial value C = Σ u(k)(x¹(k) − b·g(k))/Σ u(k)², u(k) = e^{−a(k−1)},
    g(k) = (1 − u(k))/a; in-window model x̂⁰(k) = (b − a·C)·h(a)·e^{−a(k−2)}, k ≥ 2,
    h(a) = −expm1(−a)/a; the least-squares polynomial extrapolations are fixed linear
    combinations of their data (the weights).
    """
    m = len(window)
    if m > _GREY_UNROLL_MAX:
        return _improved_grey_loop(window, level_ratio, a_min, poly_weights, residual_weights)
    fn = _STEP_CACHE.get(("grey", m))
    if fn is None:
        fn = _compiled(("grey", m), _grey_source(m), "grey_predict")
    return fn(window, level_ratio, a_min, poly_weights, residual_weights)  # type: ignore[operator]


def _improved_grey_loop(
    window: Sequence[float], level_ratio: float, a_min: float,
    poly_weights: Sequence[float], residual_weights: Sequence[float],
) -> tuple[float, float, bool]:
    """:func:`improved_grey_predict` as loops (long windows)."""
    m = len(window)
    lo = min(window)
    span = max(window) - lo
    if span > 0.0:
        level = level_ratio * span
    else:
        level = abs(lo) if lo != 0.0 else 1.0
    lifted = [(v - lo) + level for v in window]
    # centred normal equations of L(k) + a·z(k) = b, k = 2..m
    x1 = lifted[0]
    zs = []
    for k in range(1, m):
        v = lifted[k]
        x1 += v
        zs.append(x1 - 0.5 * v)
    rows = m - 1
    z_sum = 0.0
    l_sum = 0.0
    for k in range(rows):  # no sum(): Python >= 3.12 compensates it, the C kernel does not
        z_sum += zs[k]
        l_sum += lifted[k + 1]
    z_mean = z_sum / rows
    l_mean = l_sum / rows
    szz = 0.0
    szl = 0.0
    for k in range(rows):
        dz = zs[k] - z_mean
        szz += dz * dz
        szl += dz * (lifted[k + 1] - l_mean)
    a = -szl / szz
    b = l_mean + a * z_mean
    if abs(a) < a_min:
        pred = 0.0
        for w, v in zip(poly_weights, lifted, strict=True):
            pred += w * v
        return (pred - level) + lo, a, True
    # optimal initial value: x̂¹(k) = C·u(k) + b·g(k) fitted to x¹(k), k = 1..m
    q = math.exp(-a)
    h = 1.0 if a == 0.0 else -math.expm1(-a) / a
    u = 1.0
    x1 = 0.0
    num = 0.0
    den = 0.0
    for k in range(m):
        x1 += lifted[k]
        g = float(k) if a == 0.0 else -math.expm1(-a * k) / a
        num += u * (x1 - b * g)
        den += u * u
        u *= q
    c = num / den
    amp = (b - a * c) * h
    # residual L(k) − x̂⁰(k), k = 2..m, extrapolated by the fixed weights
    corr = 0.0
    e = amp
    for k in range(1, m):
        corr += residual_weights[k - 1] * (lifted[k] - e)
        e *= q
    pred = e + corr  # e = amp·e^{−a(m−1)} = x̂⁰(m+1)
    return (pred - level) + lo, a, False


def _observer_source(phi: list[list[float]], gamma: list[list[float]], c: list[list[float]],
                     gain: list[list[float]]) -> str:
    """Straight-line observer step with the matrices as literals (zero terms left out).

    ``repr`` of a float round-trips exactly; leaving out a zero coefficient leaves every
    sum of finite terms unchanged, so the result equals the full matrix products
    computed in the same order (the C kernel's).
    """
    n, p, m = len(phi), len(gamma[0]) if gamma else 0, len(c)
    ind = "    "

    def dot(row: list[float], names: list[str]) -> str:
        terms = [f"{v!r} * {name}" for v, name in zip(row, names, strict=True) if v != 0.0]
        return " + ".join(terms) if terms else "0.0"

    zs = [f"z{j}" for j in range(n)]
    us = [f"u{j}" for j in range(p)]
    rs = [f"r{i}" for i in range(m)]
    L = ["def observer_step(st, u, y):"]
    L.append(ind + "".join(f"{z}, " for z in zs) + "= st[0]")
    if p:
        L.append(ind + "".join(f"{v}, " for v in us) + "= u")
    L.append(ind + "".join(f"y{i}, " for i in range(m)) + "= y")
    for i in range(m):
        L.append(ind + f"r{i} = y{i} - ({dot(c[i], zs)})")
    for k in range(n):
        parts = [f"({dot(phi[k], zs)})"]
        if p:
            parts.append(f"({dot(gamma[k], us)})")
        parts.append(f"({dot(gain[k], rs)})")
        L.append(ind + f"n{k} = " + " + ".join(parts))
    L.append(ind + "st[0] = [" + ", ".join(f"n{k}" for k in range(n)) + "]")
    L.append(ind + "return [" + ", ".join(rs) + "]")
    return "\n".join(L) + "\n"


class LinearObserver:
    """Discrete observer step z ← Φz + Γu + L(y − Cz), returning the residual y − Cz.

    Parameters
    ----------
    phi, gamma, C, L : sequence of float
        Matrices row-major: Φ (n×n), Γ (n×p), C (m×n), L (n×m).
    n, p, m : int
        States, inputs, outputs.

    Notes
    -----
    Sums left to right in index order; the new state is ((Φz) + (Γu)) + (L·r).
    """

    def __init__(self, phi: Sequence[float], gamma: Sequence[float], C: Sequence[float],
                 L: Sequence[float], n: int, p: int, m: int) -> None:
        self.n, self.p, self.m = int(n), int(p), int(m)

        def rows(flat: Sequence[float], r: int, k: int, name: str) -> list[list[float]]:
            vals = [float(v) for v in flat]
            if len(vals) != r * k:
                raise ValueError(f"{name} must hold {r * k} values, got {len(vals)}")
            return [vals[i * k:(i + 1) * k] for i in range(r)]

        source = _observer_source(rows(phi, n, n, "phi"), rows(gamma, n, p, "gamma"),
                                  rows(C, m, n, "C"), rows(L, n, m, "L"))
        namespace: dict[str, object] = {}
        exec(compile(source, "<gyrodiag kernel observer>", "exec"), namespace)
        self._fn = namespace["observer_step"]
        self._st: list = [[0.0] * self.n]

    def get_z(self) -> list[float]:
        """Observer state z."""
        return list(self._st[0])

    def set_z(self, z: Sequence[float]) -> None:
        """Set the observer state z (n values)."""
        vals = [float(v) for v in z]
        if len(vals) != self.n:
            raise ValueError(f"z must hold {self.n} values, got {len(vals)}")
        self._st[0] = vals

    def step(self, u: Sequence[float], y: Sequence[float]) -> list[float]:
        """One sample: returns the a-priori residual y − Cz and advances z."""
        return self._fn(self._st, u, y)  # type: ignore[operator]
