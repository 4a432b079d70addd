"""Streaming Butterworth low-pass prefilter.

The DTG paper filters all four gyro signals (Ux, Uy, Utx, Uty, sampled at 1 kHz) with a
6th-order Butterworth low-pass at 50 Hz before identification. Filtering every signal
with the same LTI filter keeps the regression exact, so the filter must be identical on
all channels and must run sample by sample (a co-simulation step delivers one sample).
"""

from __future__ import annotations

import cmath
import math
from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from . import _accel
from ._validation import check_finite_array, check_int, check_positive

__all__ = ["ButterworthPrefilter", "butterworth_sos", "ringing_samples"]


def butterworth_sos(order: int, corner_hz: float, sample_rate_hz: float,
                    btype: str = "low") -> list[list[float]]:
    """Digital Butterworth second-order sections, as ``scipy.signal.butter(..., output="sos")``.

    Parameters
    ----------
    order : int
        Filter order (>= 1).
    corner_hz : float
        -3 dB corner in Hz, 0 < corner_hz < sample_rate_hz / 2.
    sample_rate_hz : float
        Sampling rate in Hz.
    btype : {"low", "high"}
        Low-pass or high-pass.

    Returns
    -------
    list of [b0, b1, b2, a0, a1, a2]
        Sections in cascade order (a0 = 1), the gain in the first.

    Notes
    -----
    Same steps as SciPy (analog prototype poles −e^{iπm/(2N)}, pre-warped bilinear
    transform at fs = 2, ``zpk2sos`` with "nearest" pairing, the pole nearest to the unit
    circle last), so the sections agree with SciPy's to rounding (tests/test_prefilter.py
    checks 1e−13 over orders 1-10, low and high). Written here so that a DTG channel
    needs no SciPy at run time: importing ``scipy.signal`` costs 0.6-0.9 s per process,
    most of an FMU's instantiation.
    """
    if btype not in ("low", "high"):
        raise ValueError(f"btype must be 'low' or 'high', got {btype!r}")
    wn = 2.0 * corner_hz / sample_rate_hz
    warped = 4.0 * math.tan(math.pi * wn / 2.0)
    poles = [-cmath.exp(1j * math.pi * m / (2 * order)) for m in range(-order + 1, order, 2)]
    if btype == "low":
        p_analog = [warped * p for p in poles]
        z_analog: list[complex] = []
        k = warped ** order
    else:
        p_analog = [warped / p for p in poles]
        z_analog = [0j] * order
        prod_p = 1 + 0j
        for p in poles:
            prod_p *= -p
        k = (1.0 / prod_p).real
    # bilinear transform at fs = 2 (fs2 = 4)
    z_d = [(4.0 + z) / (4.0 - z) for z in z_analog] + [-1 + 0j] * (order - len(z_analog))
    p_d = [(4.0 + p) / (4.0 - p) for p in p_analog]
    num = 1 + 0j
    for z in z_analog:
        num *= 4.0 - z
    den = 1 + 0j
    for p in p_analog:
        den *= 4.0 - p
    k = k * (num / den).real
    return _zpk2sos_nearest(z_d, p_d, k)


def _cplxreal(values: list[complex]) -> list[complex]:
    """One of each conjugate pair (positive imaginary part) sorted, then the reals sorted."""
    tol = 100 * 2.220446049250313e-16
    ordered = sorted(values, key=lambda v: (v.real, abs(v.imag)))
    reals = [complex(v.real, 0.0) for v in ordered if abs(v.imag) <= tol * abs(v)]
    cplx = [v for v in ordered if abs(v.imag) > tol * abs(v)]
    pos = [v for v in cplx if v.imag > 0]
    neg = [v for v in cplx if v.imag < 0]
    if len(pos) != len(neg):
        raise ValueError("poles/zeros without conjugate")
    return [(a + b.conjugate()) / 2 for a, b in zip(pos, neg, strict=True)] + reals


def _poly2(roots: list[complex]) -> list[float]:
    coef = [1 + 0j]
    for r in roots:
        coef = [c - r * prev for c, prev in zip([*coef, 0j], [0j, *coef], strict=True)]
    return [c.real for c in coef]


def _section(zeros: list[complex], poles: list[complex]) -> list[float]:
    b, a = _poly2(zeros), _poly2(poles)
    return [0.0] * (3 - len(b)) + b + [0.0] * (3 - len(a)) + a


def _zpk2sos_nearest(z: list[complex], p: list[complex], k: float) -> list[list[float]]:
    """scipy.signal.zpk2sos with pairing "nearest" (digital), for as many zeros as poles."""
    n_sections = (len(p) + 1) // 2
    if len(p) % 2 == 1:
        p, z = [*p, 0j], [*z, 0j]
    z, p = _cplxreal(z), _cplxreal(p)

    def isreal(v: complex) -> bool:
        return v.imag == 0.0

    def worst(vals: list[complex]) -> int:
        dist = [abs(1 - abs(v)) for v in vals]
        return dist.index(min(dist))

    def nearest(vals: list[complex], to: complex, which: str) -> int:
        order = sorted(range(len(vals)), key=lambda i: abs(vals[i] - to))
        if which == "any":
            return order[0]
        return next(i for i in order if isreal(vals[i]) == (which == "real"))

    sos: list[list[float]] = [[]] * n_sections
    for si in range(n_sections - 1, -1, -1):
        p1 = p.pop(worst(p))
        if isreal(p1) and not any(isreal(v) for v in p):
            z1 = z.pop(nearest(z, p1, "real"))
            sos[si] = _section([z1, 0j], [p1, 0j])
        elif (len(p) + 1 == len(z) and not isreal(p1) and sum(map(isreal, p)) == 1
              and sum(map(isreal, z)) == 1):
            z1 = z.pop(nearest(z, p1, "complex"))
            sos[si] = _section([z1, z1.conjugate()], [p1, p1.conjugate()])
        else:
            if isreal(p1):
                reals = [i for i, v in enumerate(p) if isreal(v)]
                p2 = p.pop(reals[worst([p[i] for i in reals])])
            else:
                p2 = p1.conjugate()
            if z:
                z1 = z.pop(nearest(z, p1, "any"))
                if not isreal(z1):
                    sos[si] = _section([z1, z1.conjugate()], [p1, p2])
                elif z:
                    z2 = z.pop(nearest(z, p1, "real"))
                    sos[si] = _section([z1, z2], [p1, p2])
                else:
                    sos[si] = _section([z1], [p1, p2])
            else:
                sos[si] = _section([], [p1, p2])
    sos[0] = [v * k for v in sos[0][:3]] + sos[0][3:]
    return sos


class ButterworthPrefilter:
    """Digital Butterworth low-pass in second-order sections, with carried state.

    Parameters
    ----------
    order : int
        Filter order (>= 1). The paper uses 6.
    cutoff_hz : float
        -3 dB cut-off frequency in Hz; must be below the Nyquist frequency.
    sample_rate_hz : float
        Sampling rate in Hz.
    n_channels : int, optional
        Number of channels filtered in parallel by identical filters (default 1).
    highpass_hz : float, optional
        If given, a Butterworth high-pass of ``highpass_order`` at this corner (Hz) is
        cascaded with the low-pass, making a band-pass. It removes slow content that
        the DTG regression does not model (e.g. the torquer response to a case rate),
        while applying one LTI filter to every channel keeps the regression exact.
    highpass_order : int, optional
        Order of the high-pass (default 2).

    Notes
    -----
    ``update`` accepts one sample ``(n_channels,)`` or a record
    ``(n_samples, n_channels)``; the state carried between calls makes any split of a
    record give the same output as :func:`scipy.signal.sosfilt` on the whole record
    started from zero state.
    """

    def __init__(
        self, order: int, cutoff_hz: float, sample_rate_hz: float, n_channels: int = 1,
        highpass_hz: float | None = None, highpass_order: int = 2,
    ) -> None:
        self.order = check_int("order", order, minimum=1)
        self.sample_rate_hz = check_positive("sample_rate_hz", sample_rate_hz)
        self.cutoff_hz = check_positive("cutoff_hz", cutoff_hz)
        nyquist = 0.5 * self.sample_rate_hz
        if self.cutoff_hz >= nyquist:
            raise ValueError(
                f"cutoff_hz must be below the Nyquist frequency {nyquist} Hz "
                f"(sample_rate_hz / 2), got {cutoff_hz!r}"
            )
        self.n_channels = check_int("n_channels", n_channels, minimum=1)
        sections = butterworth_sos(self.order, self.cutoff_hz, self.sample_rate_hz, "low")
        self.highpass_hz = None if highpass_hz is None else check_positive(
            "highpass_hz", highpass_hz)
        if self.highpass_hz is not None:
            if self.highpass_hz >= self.cutoff_hz:
                raise ValueError(
                    f"highpass_hz must be below cutoff_hz ({self.cutoff_hz} Hz), "
                    f"got {highpass_hz!r}"
                )
            hp_order = check_int("highpass_order", highpass_order, minimum=1)
            sections += butterworth_sos(hp_order, self.highpass_hz, self.sample_rate_hz,
                                        "high")
        self.sos: NDArray[np.float64] = np.array(sections)
        self._n_sections = len(sections)
        self._kernel = _accel.kernels.SosCascade(
            [v for sec in sections for v in (sec[0], sec[1], sec[2], sec[4], sec[5])],
            self._n_sections, self.n_channels,
        )

    @property
    def _zi(self) -> NDArray[np.float64]:
        """Section delay lines, shape (n_sections, 2, n_channels) as scipy's ``zi``."""
        return np.array(self._kernel.get_state()).reshape(self._n_sections, 2, self.n_channels)

    def reset(self) -> None:
        """Return to zero state (as at construction)."""
        self._kernel.reset()

    def step(self, x: Sequence[float]) -> Sequence[float]:
        """Filter one sample of plain floats, unchecked (the per-sample hot path).

        Parameters
        ----------
        x : sequence of float
            ``n_channels`` finite values (the caller has checked them).

        Returns
        -------
        sequence of float
            The filtered sample (a tuple or list; same values as :meth:`update`).
        """
        return self._kernel.step(x)

    def update(self, x: ArrayLike, *, validate: bool = True) -> NDArray[np.float64]:
        """Filter one sample or a record, advancing the state.

        Parameters
        ----------
        x : array_like
            Shape ``(n_channels,)`` for one sample or ``(n_samples, n_channels)`` for a
            record (a scalar is accepted when ``n_channels == 1``). Units are preserved.

        Returns
        -------
        ndarray
            Filtered values, same shape as ``x``.

        Raises
        ------
        ValueError
            If ``x`` has the wrong shape or contains NaN/Inf; the state is untouched.
        """
        # validate=False: the caller checked finiteness already (hot path of a channel)
        arr = check_finite_array("x", x) if validate else np.asarray(x, dtype=float)
        single = arr.ndim <= 1
        if arr.ndim == 0:
            arr = arr.reshape(1)
        if single:
            if arr.shape != (self.n_channels,):
                raise ValueError(
                    f"x must have shape ({self.n_channels},) for one sample, got {arr.shape}"
                )
            arr = arr.reshape(1, self.n_channels)
        elif arr.ndim != 2 or arr.shape[1] != self.n_channels:
            raise ValueError(
                f"x must have shape (n_samples, {self.n_channels}), got {arr.shape}"
            )
        if single:
            return np.array(self._kernel.step(arr[0].tolist()))
        # a record: SciPy's loop (imported only here, not needed for streaming)
        from scipy.signal import sosfilt

        y, zf = sosfilt(self.sos, arr, axis=0, zi=self._zi)
        self._kernel.set_state(zf.ravel().tolist())
        return y

    def get_state(self) -> dict[str, Any]:
        """Copy of the internal state (section delay lines), for save/restore."""
        return {"zi": self._zi.copy()}

    def set_state(self, state: dict[str, Any]) -> None:
        """Restore a state produced by :meth:`get_state` of an identical filter."""
        zi = check_finite_array(
            "state['zi']", state["zi"], shape=(self._n_sections, 2, self.n_channels))
        self._kernel.set_state(zi.ravel().tolist())


def ringing_samples(f: ButterworthPrefilter, horizon: int) -> int:
    """Samples after which the impulse response of ``f``'s first channel stays below 1e-3
    of its peak (looked at over ``horizon`` samples, run sample by sample: the record
    path needs SciPy, which a lean host may not have). ``f`` is left rung."""
    zeros = (0.0,) * (f.n_channels - 1)
    h = np.abs([f.step((1.0 if k == 0 else 0.0, *zeros))[0] for k in range(horizon)])
    above = np.flatnonzero(h > 1e-3 * h.max())
    return int(above[-1]) + 1 if above.size else 0
