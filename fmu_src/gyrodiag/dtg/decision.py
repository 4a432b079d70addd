"""Fault decision on identified parameters (DTG paper, eqs. 6 and 7).

* Ratio test: η_i = |θ_i| / |θ0_i| against the nominal mean θ0; any η_i outside
  [low, high] (paper: 0.5, 1.5) is a fault.
* Feature vector: C_i = round(log10 η_i), an order-of-magnitude signature.
* Classification: the fault whose signature C_j is nearest to the observed C by
  d = (1/n)·Σ|C_ji − C_i| (eq. 7), or "unknown" beyond ``max_distance``.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..common._validation import check_finite_array, check_int, check_nonnegative, check_positive

__all__ = [
    "UNKNOWN_CODE",
    "Classification",
    "DecisionOutput",
    "SignatureClassifier",
    "ThresholdDecision",
    "WindowedMedianFeature",
    "feature_floats",
    "feature_vector",
    "median_feature",
    "parameter_ratios",
    "signature_distance",
]

#: Integer code of the "unknown fault" class (0 is reserved for "no fault").
UNKNOWN_CODE = -1

#: log10 of a ratio is taken of max(η, ETA_FLOOR) so that θ_i = 0 gives a finite feature.
ETA_FLOOR = 1e-12


def _round_half_away(x: NDArray[np.float64]) -> NDArray[np.int64]:
    return (np.sign(x) * np.floor(np.abs(x) + 0.5)).astype(np.int64)


def parameter_ratios(theta: ArrayLike, theta0: ArrayLike) -> NDArray[np.float64]:
    """η_i = |θ_i| / |θ0_i| (paper eq. 6).

    Raises
    ------
    ValueError
        If shapes differ, values are not finite, or some θ0_i = 0.
    """
    t0 = check_finite_array("theta0", theta0, ndim=1)
    t = check_finite_array("theta", theta, shape=t0.shape)
    if np.any(t0 == 0.0):
        raise ValueError(f"theta0 must have no zero entry (ratios divide by it), got {t0}")
    return np.abs(t) / np.abs(t0)


def feature_vector(eta: ArrayLike) -> NDArray[np.int64]:
    """C_i = round(log10 η_i), rounding half away from zero.

    η_i = 0 is clipped to ``ETA_FLOOR`` so that a vanished parameter gives a large
    negative, finite feature instead of −inf.
    """
    e = check_finite_array("eta", eta, ndim=1)
    if np.any(e < 0):
        raise ValueError("eta must be non-negative (it is a ratio of magnitudes)")
    lg = np.log10(np.maximum(e, ETA_FLOOR))
    return _round_half_away(lg)


def feature_floats(eta: Sequence[float], _log10: Any = math.log10,
                   _floor: Any = math.floor) -> tuple[int, ...]:
    """:func:`feature_vector` on plain floats, unchecked (the per-sample hot path of a
    channel whose η are finite and non-negative by construction): same values."""
    lgs = [_log10(e if e > ETA_FLOOR else ETA_FLOOR) for e in eta]
    return tuple([int(_floor(lg + 0.5)) if lg >= 0.0 else -int(_floor(0.5 - lg))
                  for lg in lgs])


def median_feature(features: ArrayLike) -> NDArray[np.int64]:
    """Element-wise median of feature vectors, rounded half away from zero.

    The robust summary of a run of per-sample features: a forgetting estimator's η
    jitters by a decade from sample to sample in a fault, so one sample's C is a poor
    witness. Signature learning and the DTG channel's classification use this same rule,
    so what is classified is what was learned.

    Parameters
    ----------
    features : array_like, shape (n, k) or (k,)
        n ≥ 1 feature vectors (rows).
    """
    f = check_finite_array("features", features)
    if f.ndim == 1:
        f = f[None, :]
    if f.ndim != 2 or f.shape[0] == 0 or f.shape[1] == 0:
        raise ValueError(f"features must have shape (n >= 1, k), got {f.shape}")
    med = np.median(f, axis=0)
    return _round_half_away(med)


class WindowedMedianFeature:
    """Streaming :func:`median_feature` of the flagged samples of a sliding window.

    Keeps the last ``window`` feature vectors with a flag each (the DTG channel flags
    alarm samples) and per component a count of each value, so that the median of the
    flagged vectors costs O(k · values) per sample instead of sorting the window.

    Parameters
    ----------
    n_features : int
        Length k of a feature vector.
    window : int
        Samples in the window (>= 1).

    Notes
    -----
    Features are integers (decade counts, :func:`feature_vector`); they are clipped to
    ±``LIMIT`` decades, far beyond any ratio of two finite parameters that matters.
    """

    #: Features are clipped to [−LIMIT, LIMIT].
    LIMIT = 64

    def __init__(self, n_features: int, window: int) -> None:
        self.n_features = check_int("n_features", n_features, minimum=1)
        self.window = check_int("window", window, minimum=1)
        self.reset()

    def reset(self) -> None:
        """Empty window."""
        # plain lists: one push is a handful of integer operations (numpy indexing cost
        # more than the channel's arithmetic at 1 kHz); arrays only in get_state
        zero = (0,) * self.n_features
        self._ring: list[tuple[int, ...]] = [zero] * self.window
        self._flags: list[bool] = [False] * self.window
        self._pos = 0
        # per component {value: count of flagged samples} (a few distinct decades)
        self._counts: list[dict[int, int]] = [{} for _ in range(self.n_features)]
        self._n_flagged = 0

    def update(self, feature: Sequence[int], flagged: bool) -> None:
        """Push one feature vector (ints, length k); ``flagged`` ones count in the
        median. Not validated: the caller passes :func:`feature_vector` output."""
        pos, lim, counts = self._pos, self.LIMIT, self._counts
        if self._flags[pos]:
            for row, c in zip(counts, self._ring[pos], strict=True):
                left = row[c] - 1
                if left:
                    row[c] = left
                else:
                    del row[c]
            self._n_flagged -= 1
        self._flags[pos] = flagged
        if flagged:
            f = tuple(min(max(int(c), -lim), lim) for c in feature)
            self._ring[pos] = f
            for row, c in zip(counts, f, strict=True):
                row[c] = row.get(c, 0) + 1
            self._n_flagged += 1
        else:  # an unflagged entry never counts: its values are not kept
            self._ring[pos] = (0,) * self.n_features
        pos += 1
        self._pos = 0 if pos == self.window else pos

    @property
    def n_flagged(self) -> int:
        """Flagged samples in the window."""
        return self._n_flagged

    def median(self) -> NDArray[np.int64] | None:
        """Median of the flagged vectors, rounded half away from zero (None if none)."""
        n = self._n_flagged
        if n == 0:
            return None
        lo_rank, hi_rank = (n - 1) // 2, n // 2
        med = []
        for row in self._counts:
            cum, lo, hi = 0, None, 0
            for value in sorted(row):
                cum += row[value]
                if lo is None and cum > lo_rank:
                    lo = value
                if cum > hi_rank:
                    hi = value
                    break
            assert lo is not None
            med.append((lo + hi) / 2.0)
        return _round_half_away(np.array(med))

    def get_state(self) -> dict[str, Any]:
        """Window contents (the counts are derived from them)."""
        return {"ring": np.array(self._ring, dtype=np.int64).reshape(self.window,
                                                                    self.n_features),
                "flags": np.array(self._flags, dtype=bool), "pos": self._pos}

    def set_state(self, state: dict[str, Any]) -> None:
        """Restore :meth:`get_state` output of a window of the same size; checked first,
        so a bad state leaves this one untouched."""
        ring = np.asarray(state["ring"], dtype=np.int64)
        flags = np.asarray(state["flags"], dtype=bool)
        pos = int(state["pos"])
        shape = (self.window, self.n_features)
        if ring.shape != shape or flags.shape != (self.window,):
            raise ValueError(
                f"state['ring'] / state['flags'] have shapes {ring.shape} / {flags.shape}, "
                f"this window needs {shape} / {(self.window,)}"
            )
        if not 0 <= pos < self.window:
            raise ValueError(f"state['pos'] must be in [0, {self.window}), got {pos}")
        if np.any(np.abs(ring) > self.LIMIT):
            raise ValueError(f"state['ring'] has features beyond ±{self.LIMIT}")
        ring = np.where(flags[:, None], ring, 0)
        self._ring = [tuple(int(c) for c in r) for r in ring]
        self._flags = [bool(f) for f in flags]
        self._pos = pos
        self._counts = [{} for _ in range(self.n_features)]
        for r in ring[flags]:
            for row, c in zip(self._counts, r.tolist(), strict=True):
                row[c] = row.get(c, 0) + 1
        self._n_flagged = int(flags.sum())


def signature_distance(c_a: ArrayLike, c_b: ArrayLike) -> float:
    """Eq. 7 distance (1/n)·Σ|c_a,i − c_b,i| between two feature vectors."""
    a = check_finite_array("c_a", c_a, ndim=1)
    b = check_finite_array("c_b", c_b, shape=a.shape)
    return float(np.mean(np.abs(a - b)))


@dataclass(frozen=True)
class DecisionOutput:
    """Result of one :meth:`ThresholdDecision.update`.

    Attributes
    ----------
    eta : ndarray
        Ratios |θ|/|θ0|.
    out_of_band : ndarray of bool
        Per parameter, η outside [low, high] (masked parameters are always False).
    violation : bool
        Any monitored parameter out of band at this sample.
    alarm : bool
        Violation confirmed by the persistence rule (and held if latching).
    first_alarm_sample : int
        Index (0-based count of updates) of the first alarm since reset, −1 if none.
    """

    eta: NDArray[np.float64]
    out_of_band: NDArray[np.bool_]
    violation: bool
    alarm: bool
    first_alarm_sample: int


class ThresholdDecision:
    """Ratio-threshold fault decision with persistence and optional latching.

    Parameters
    ----------
    theta0 : array_like, shape (n,)
        Nominal parameter mean θ0 (no zero entry).
    low, high : float, optional
        Band for η (paper: 0.5 and 1.5); 0 <= low < 1 < high.
    persistence_k, persistence_n : int, optional
        Alarm when at least k of the last n samples violate (default 1 of 1: the
        paper's instantaneous rule).
    latch : bool, optional
        Keep the alarm once raised until :meth:`reset` (default False).
    monitored : sequence of bool, optional
        Which parameters take part (default all). The paper's θ5 is two orders of
        magnitude below θ3, θ4 and is the noisiest ratio.
    """

    def __init__(
        self, theta0: ArrayLike, low: float = 0.5, high: float = 1.5,
        persistence_k: int = 1, persistence_n: int = 1, latch: bool = False,
        monitored: Sequence[bool] | None = None,
    ) -> None:
        self.theta0 = check_finite_array("theta0", theta0, ndim=1)
        if np.any(self.theta0 == 0.0):
            raise ValueError(f"theta0 must have no zero entry, got {self.theta0}")
        self.low = check_nonnegative("low", low)
        self.high = check_positive("high", high)
        if not self.low < 1.0 < self.high:
            raise ValueError(f"need low < 1 < high, got low={low!r}, high={high!r}")
        self.persistence_n = check_int("persistence_n", persistence_n, minimum=1)
        self.persistence_k = check_int("persistence_k", persistence_k, minimum=1)
        if self.persistence_k > self.persistence_n:
            raise ValueError(
                f"persistence_k must be <= persistence_n ({self.persistence_n}), "
                f"got {persistence_k!r}"
            )
        self.latch = bool(latch)
        n = self.theta0.shape[0]
        if monitored is None:
            self.monitored = np.ones(n, dtype=bool)
        else:
            m = np.asarray(monitored, dtype=bool)
            if m.shape != (n,) or not m.any():
                raise ValueError(
                    f"monitored must be {n} booleans with at least one True, got {monitored!r}"
                )
            self.monitored = m
        self._abs_theta0 = np.abs(self.theta0).tolist()
        self._monitored_list = self.monitored.tolist()
        # step(): the monitored ratios (None: all of them)
        idx = [i for i, m in enumerate(self._monitored_list) if m]
        self._watched: Any = (None if len(idx) == n else
                              (lambda eta, _i=tuple(idx): [eta[i] for i in _i]))
        self.reset()

    def reset(self) -> None:
        """Clear the persistence history, the latch and the first-alarm index."""
        self._history: deque[bool] = deque(maxlen=self.persistence_n)
        self._latched = False
        self._count = 0
        self._first_alarm = -1

    def update(self, theta: ArrayLike) -> DecisionOutput:
        """Judge one parameter estimate.

        Raises
        ------
        ValueError
            On a wrong shape or non-finite θ; the state is untouched.
        """
        eta = parameter_ratios(theta, self.theta0)
        oob = ((eta < self.low) | (eta > self.high)) & self.monitored
        violation = bool(oob.any())
        self._history.append(violation)
        alarm = sum(self._history) >= self.persistence_k
        if self.latch:
            self._latched = self._latched or alarm
            alarm = self._latched
        if alarm and self._first_alarm < 0:
            self._first_alarm = self._count
        self._count += 1
        return DecisionOutput(eta, oob, violation, alarm, self._first_alarm)

    def set_theta0(self, theta0: ArrayLike) -> None:
        """Replace θ0 (a refined reference); the persistence history is kept.

        Raises
        ------
        ValueError
            On a wrong shape, a non-finite or a zero entry; θ0 is then unchanged.
        """
        t0 = check_finite_array("theta0", theta0, shape=self.theta0.shape)
        if np.any(t0 == 0.0):
            raise ValueError(f"theta0 must have no zero entry, got {t0}")
        self.theta0 = t0.copy()
        self._abs_theta0 = np.abs(t0).tolist()

    def out_of_band(self, eta: Sequence[float]) -> list[int]:
        """Indices of the monitored ratios outside the band."""
        lo, hi = self.low, self.high
        return [i for i, (e, m) in enumerate(zip(eta, self._monitored_list, strict=True))
                if m and (e < lo or e > hi)]

    def step(self, theta: Sequence[float],
             confirm: Callable[[list[float]], bool] | None = None
             ) -> tuple[list[float], bool]:
        """:meth:`update` on plain floats, unchecked (the per-sample hot path of a
        channel that has checked its sample): returns (η, alarm) with the same values
        and the same state change.

        Parameters
        ----------
        theta : sequence of float
            n finite estimates.
        confirm : callable, optional
            Called with η only when a monitored ratio is outside the band; the sample
            counts as a violation only if it returns True (e.g. a significance test of
            the estimate against its standard error). None: the band alone.
        """
        eta = [abs(t) / a for t, a in zip(theta, self._abs_theta0, strict=True)]
        watched = self._watched(eta) if self._watched is not None else eta
        # min/max of the monitored ratios: two builtin calls instead of a loop
        violation = bool(watched) and (min(watched) < self.low or max(watched) > self.high)
        if violation and confirm is not None:
            violation = bool(confirm(eta))
        hist = self._history
        hist.append(violation)
        alarm = sum(hist) >= self.persistence_k
        if self.latch:
            self._latched = self._latched or alarm
            alarm = self._latched
        if alarm and self._first_alarm < 0:
            self._first_alarm = self._count
        self._count += 1
        return eta, alarm

    def get_state(self) -> dict[str, Any]:
        """Copy of the persistence history, latch and counters."""
        return {
            "history": np.array(self._history, dtype=bool),
            "latched": self._latched,
            "count": self._count,
            "first_alarm": self._first_alarm,
        }

    def set_state(self, state: dict[str, Any]) -> None:
        """Restore a state produced by :meth:`get_state`."""
        hist = np.asarray(state["history"], dtype=bool).ravel()
        if hist.size > self.persistence_n:
            raise ValueError(
                f"state['history'] has {hist.size} entries, more than persistence_n"
            )
        self._history = deque((bool(h) for h in hist), maxlen=self.persistence_n)
        self._latched = bool(state["latched"])
        self._count = int(state["count"])
        self._first_alarm = int(state["first_alarm"])


@dataclass(frozen=True)
class Classification:
    """Result of :meth:`SignatureClassifier.classify`.

    Attributes
    ----------
    label : str
        Name of the nearest signature, or ``"unknown"``.
    code : int
        1-based index of the signature in the library order, ``UNKNOWN_CODE`` if unknown.
    distance : float
        Eq. 7 distance to the nearest signature.
    distances : dict
        Distance to every signature.
    """

    label: str
    code: int
    distance: float
    distances: dict[str, float]


class SignatureClassifier:
    """Nearest-signature classifier of feature vectors (paper eq. 7).

    Parameters
    ----------
    signatures : mapping of str to array_like
        Fault name → feature vector C_j (all the same length). Codes are 1, 2, … in
        the mapping's order.
    max_distance : float, optional
        Observed vectors farther than this from every signature are "unknown"
        (default: no limit, as in the paper).
    """

    def __init__(
        self, signatures: Mapping[str, ArrayLike], max_distance: float | None = None
    ) -> None:
        if not signatures:
            raise ValueError("signatures must contain at least one fault signature")
        names = list(signatures)
        first = check_finite_array(f"signatures[{names[0]!r}]", signatures[names[0]], ndim=1)
        self.names = names
        self.library = np.vstack(
            [
                check_finite_array(f"signatures[{n!r}]", signatures[n], shape=first.shape)
                for n in names
            ]
        )
        self.max_distance = (
            None if max_distance is None else check_nonnegative("max_distance", max_distance)
        )

    def distances(self, c: ArrayLike) -> NDArray[np.float64]:
        """Eq. 7 distance from ``c`` to every signature, in library order."""
        cc = check_finite_array("c", c, shape=(self.library.shape[1],))
        return np.mean(np.abs(self.library - cc), axis=1)

    def classify(self, c: ArrayLike) -> Classification:
        """Nearest signature to feature vector ``c`` (ties go to the first listed)."""
        d = self.distances(c)
        j = int(np.argmin(d))
        dist = float(d[j])
        table = dict(zip(self.names, (float(x) for x in d), strict=True))
        if self.max_distance is not None and dist > self.max_distance:
            return Classification("unknown", UNKNOWN_CODE, dist, table)
        return Classification(self.names[j], j + 1, dist, table)

    def pairwise_distances(self) -> NDArray[np.float64]:
        """Matrix of eq. 7 distances between all library signatures."""
        lib = self.library
        return np.mean(np.abs(lib[:, None, :] - lib[None, :, :]), axis=2)
