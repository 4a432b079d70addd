"""Streaming Butterworth low-pass prefilter.

The DTG paper filters all four gyro signals (Ux, Uy, Utx, Uty, sampled at 1 kHz) with a
6th-order Butterworth low-pass at 50 Hz before identification. Filtering every signal
with the same LTI filter keeps the regression exact, so the filter must be identical on
all channels and must run sample by sample (a co-simulation step delivers one sample).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import signal

from gyrodiag.common._validation import check_finite_array, check_int, check_positive

__all__ = ["ButterworthPrefilter"]


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
        self.sos: NDArray[np.float64] = signal.butter(
            self.order, self.cutoff_hz, btype="low", fs=self.sample_rate_hz, output="sos"
        )
        self.highpass_hz = None if highpass_hz is None else check_positive(
            "highpass_hz", highpass_hz)
        if self.highpass_hz is not None:
            if self.highpass_hz >= self.cutoff_hz:
                raise ValueError(
                    f"highpass_hz must be below cutoff_hz ({self.cutoff_hz} Hz), "
                    f"got {highpass_hz!r}"
                )
            hp_order = check_int("highpass_order", highpass_order, minimum=1)
            hp = signal.butter(
                hp_order, self.highpass_hz, btype="high", fs=self.sample_rate_hz, output="sos"
            )
            self.sos = np.vstack([self.sos, hp])
        self._zi = np.zeros((self.sos.shape[0], 2, self.n_channels))

    def reset(self) -> None:
        """Return to zero state (as at construction)."""
        self._zi[...] = 0.0

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
        y, zf = signal.sosfilt(self.sos, arr, axis=0, zi=self._zi)
        self._zi = zf
        return y[0] if single else y

    def get_state(self) -> dict[str, Any]:
        """Copy of the internal state (section delay lines), for save/restore."""
        return {"zi": self._zi.copy()}

    def set_state(self, state: dict[str, Any]) -> None:
        """Restore a state produced by :meth:`get_state` of an identical filter."""
        zi = check_finite_array("state['zi']", state["zi"], shape=self._zi.shape)
        self._zi = zi.copy()
