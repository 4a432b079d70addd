"""Magnitude-free, axis-aware classification of DTG faults by response patterns.

A fault class is a fault type on one signal (or a physical fault of the gyro), and its
*signature* is how the channel statistics of :mod:`gyrodiag.dtg.reference` respond to
it per unit of fault size, learned from training runs (``harness learn-signatures``):

=========  ===========================================================================
type       signature and fit
=========  ===========================================================================
step       level response p (6 channels, per V): λ ≈ a·p, a ∈ ℝ (size a, V)
drift      the same level response; told from a step by the growth of the residual
           level inside the window (> ``growth_threshold``); rate from the slopes (V/s)
noise      variance response p (per V²): ratio ≈ 1 + a·p, a ≥ 0 (size √a, V)
loss       the lost signal's variance ratio ≈ a·p (replaced by noise of √a V), the
           others ≈ 1 + base + a·p (base: the decorrelation a loss causes)
spin,      log10 η ≈ a·p (p per decade of the physical change; size 10^a, a ratio)
torquer
=========  ===========================================================================

Each hypothesis is fitted to the observed statistics (its size is the free parameter)
and scored by a χ² whose per-channel spread is the nominal spread of the statistic
(noise model of the training runs, scaled with the window length) plus a relative model
error, each channel's term capped at ``component_cap``: a class is judged by how many
channels it explains, whatever the size. The best class wins; ``distance`` is its χ²
per channel. Because sizes are fitted, not matched, a class learned at 0.2–2 V
classifies 0.1 or 3 V as well.

Two cases cannot be told apart and are merged by rule:

* A loss whose replacement noise is several times the signal's own spread is a noise
  fault for every statistic (the lost signal is buried either way): when the noise class
  of the same signal fits within ``loss_margin`` of the loss class, noise is reported.
* Step and drift share the spatial response; until the window shows the level growing
  (a few tenths of a second), a drift is reported as a step.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..common._validation import check_finite_array, check_nonnegative, check_positive
from .decision import UNKNOWN_CODE
from .model import N_THETA
from .reference import N_CHANNELS, ClassificationStatistics, NominalPrior

__all__ = [
    "AXIS_CODES",
    "DEFAULT_LIBRARY_FILE",
    "FAULT_TYPES",
    "FORMAT",
    "SIGNALS",
    "NoiseModel",
    "PatternClass",
    "PatternClassifier",
    "PatternLibrary",
    "PatternResult",
    "default_library",
    "physical_class",
]

#: The shipped library: classes learned on the paper DTG bench at 1 kHz
#: (scenarios/training/patterns), its nominal prior applied to levels only; written by
#: ``fmu_src/tools/default_patterns.py`` from a ``harness learn-signatures`` file.
DEFAULT_LIBRARY_FILE = Path(__file__).with_name("default_patterns.json")

#: File format tag of a pattern library.
FORMAT = "gyrodiag.dtg-patterns/1"
#: Fault types; their codes (``dtg.fault_type``) are the 1-based positions.
FAULT_TYPES = ("step", "noise", "loss", "drift", "spin", "torquer")
SIGNAL_TYPES = ("step", "noise", "loss", "drift")
PHYSICAL_TYPES = ("spin", "torquer")
#: Signals; their codes (``dtg.fault_signal``) are the 1-based positions.
SIGNALS = ("Utx", "Uty", "Ux", "Uy")
#: Axis codes (``dtg.fault_axis``): 1 x, 2 y, 3 both.
AXIS_CODES = {"Utx": 1, "Ux": 1, "Uty": 2, "Uy": 2, None: 3}
N_ETA = 2 * N_THETA
#: ``fault_code`` of two faults at once (``fault_name`` names both).
SEVERAL_CODE = -2
#: Level χ² by which two faults must beat one (and each the other alone) to be named
#: (a correctly fitted single fault leaves 1-10: docs/notes.md).
PAIR_MARGIN = 16.0
#: log10 variance ratios are compared within these bounds (a silent channel is −∞).
LOG_VAR_MIN, LOG_VAR_MAX = -4.0, 8.0
#: Grid of the variance-response amplitude, V² (noise std 1e−6 … 1e4 V).
_AMPLITUDE_GRID = 10.0 ** np.linspace(-12.0, 8.0, 241)
#: The channels that are measured voltages (the rest are the regression's residuals).
_RAW_CHANNELS = np.arange(N_CHANNELS) < len(SIGNALS)


@dataclass(frozen=True)
class PatternClass:
    """One fault class and its signature (module docstring).

    Attributes
    ----------
    name : str
        Class name, e.g. ``"uty_step"``.
    type : str
        One of :data:`FAULT_TYPES`.
    signal : str or None
        One of :data:`SIGNALS`; None for the physical types.
    response : ndarray
        Level response per V (step, drift; 6), variance response per V² (noise, loss;
        6) or log10 η per decade (spin, torquer; 10).
    base : ndarray or None
        Loss only: variance ratio − 1 of each channel caused by the loss itself, NaN at
        the lost signal.
    """

    name: str
    type: str
    signal: str | None
    response: NDArray[np.float64]
    base: NDArray[np.float64] | None = None

    @property
    def axis(self) -> int:
        """:data:`AXIS_CODES` of the class."""
        return AXIS_CODES[self.signal]

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], where: str) -> PatternClass:
        """Read ``{name, type, signal, response, base}`` with checks naming ``where``."""
        if not isinstance(d, Mapping):
            raise ValueError(f"{where} must be an object")
        name = d.get("name")
        if not isinstance(name, str) or not name:
            raise ValueError(f"{where}.name must be a non-empty string")
        typ = d.get("type")
        if typ not in FAULT_TYPES:
            raise ValueError(f"{where}.type must be one of {FAULT_TYPES}, got {typ!r}")
        signal = d.get("signal")
        if typ in PHYSICAL_TYPES:
            if signal is not None:
                raise ValueError(f"{where}.signal must be null for type {typ!r}")
            n = N_ETA
        else:
            if signal not in SIGNALS:
                raise ValueError(f"{where}.signal must be one of {SIGNALS}, got {signal!r}")
            n = N_CHANNELS
        response = check_finite_array(f"{where}.response", d.get("response"), shape=(n,))
        base = None
        if typ == "loss":
            raw = d.get("base")
            if raw is None:
                raise ValueError(f"{where}.base is missing (type 'loss')")
            base = np.array([math.nan if v is None else float(v) for v in raw], dtype=float)
            if base.shape != (N_CHANNELS,):
                raise ValueError(f"{where}.base must have {N_CHANNELS} entries")
            lost = SIGNALS.index(signal)
            if not math.isnan(base[lost]):
                raise ValueError(f"{where}.base[{lost}] must be null (the lost signal)")
            others = np.delete(base, lost)
            if not np.all(np.isfinite(others)) or np.any(others < -1.0):
                raise ValueError(f"{where}.base must be finite and >= -1 except at the lost "
                                 "signal")
        if typ in ("noise", "loss") and np.any(response < 0):
            raise ValueError(f"{where}.response must be >= 0 for type {typ!r} (added noise "
                             "cannot lower a variance)")
        if not np.any(response != 0):
            raise ValueError(f"{where}.response must not be all zero")
        return cls(name, typ, signal, response, base)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready content."""
        out: dict[str, Any] = {"name": self.name, "type": self.type, "signal": self.signal,
                               "response": [float(v) for v in self.response]}
        if self.base is not None:
            out["base"] = [None if math.isnan(v) else float(v) for v in self.base]
        return out


@dataclass(frozen=True)
class NoiseModel:
    """Spread of the statistics on fault-free data, for a window of ``reference_blocks``.

    For a window of k blocks the spreads scale as (reference_blocks / k) ** exponent.
    """

    level_std: NDArray[np.float64]
    log_variance_std: NDArray[np.float64]
    log_eta_std: NDArray[np.float64]
    reference_blocks: int
    exponent: float = 0.4

    def scale(self, blocks: int) -> float:
        """Spread factor of a window of ``blocks`` blocks."""
        return (self.reference_blocks / max(blocks, 1)) ** self.exponent

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], where: str = "noise") -> NoiseModel:
        """Read and check the noise model."""
        if not isinstance(d, Mapping):
            raise ValueError(f"{where} must be an object")
        vals = {}
        for key, n in (("level_std", N_CHANNELS), ("log_variance_std", N_CHANNELS),
                       ("log_eta_std", N_ETA)):
            a = check_finite_array(f"{where}.{key}", d.get(key), shape=(n,))
            if np.any(a <= 0):
                raise ValueError(f"{where}.{key} must be positive")
            vals[key] = a
        rb = d.get("reference_blocks")
        if isinstance(rb, bool) or not isinstance(rb, int) or rb < 1:
            raise ValueError(f"{where}.reference_blocks must be an integer >= 1, got {rb!r}")
        exponent = check_nonnegative(f"{where}.exponent", d.get("exponent", 0.4))
        return cls(vals["level_std"], vals["log_variance_std"], vals["log_eta_std"], rb,
                   exponent)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready content."""
        return {"level_std": [float(v) for v in self.level_std],
                "log_variance_std": [float(v) for v in self.log_variance_std],
                "log_eta_std": [float(v) for v in self.log_eta_std],
                "reference_blocks": self.reference_blocks, "exponent": self.exponent}


@dataclass(frozen=True)
class PatternLibrary:
    """Learned classes, noise model and decision constants (a ``dtg.signature_file``).

    Attributes
    ----------
    classes : tuple of PatternClass
        Fault classes; fault codes are their 1-based positions.
    noise : NoiseModel
        Spread of the statistics without fault.
    sample_period_s, block_s : float
        Sampling and block period the library was learned with (checked on use).
    growth_threshold : float
        A level class is a drift when the window's growth exceeds this.
    loss_margin : float
        χ² by which a loss must beat the noise class of the same signal.
    level_model_error, log_variance_model_error, log_eta_model_error : float
        Relative (level, log η) and absolute (log10 variance) model errors.
    component_cap : float
        Cap of each channel's χ² term.
    max_distance : float or None
        χ² per channel beyond which a signal fault is "unknown" (None: no limit).
    physical_max_distance : float or None
        The same for the physical classes (their fits are judged on log η).
    prior : NominalPrior or None
        Nominal reference of the training runs (the learning guard's prior).
    """

    classes: tuple[PatternClass, ...]
    noise: NoiseModel
    sample_period_s: float
    block_s: float
    growth_threshold: float = 0.15
    loss_margin: float = 2.0
    level_model_error: float = 0.25
    log_variance_model_error: float = 0.1
    log_eta_model_error: float = 0.25
    component_cap: float = 25.0
    max_distance: float | None = None
    prior: NominalPrior | None = None
    physical_max_distance: float | None = None

    @property
    def names(self) -> list[str]:
        """Class names in code order."""
        return [c.name for c in self.classes]

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> PatternLibrary:
        """Read a library (the ``patterns`` object of a signature file), checking every
        entry with messages naming it."""
        if not isinstance(d, Mapping):
            raise ValueError("patterns must be an object")
        fmt = d.get("format")
        if fmt != FORMAT:
            raise ValueError(f"patterns.format must be {FORMAT!r}, got {fmt!r}")
        raw = d.get("classes")
        if not isinstance(raw, Sequence) or isinstance(raw, str) or not raw:
            raise ValueError("patterns.classes must be a non-empty list")
        classes = tuple(PatternClass.from_dict(c, f"patterns.classes[{i}]")
                        for i, c in enumerate(raw))
        names = [c.name for c in classes]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ValueError(f"patterns.classes: duplicate class names {dup}")
        noise = NoiseModel.from_dict(d.get("noise"), "patterns.noise")
        md = d.get("max_distance")
        pmd = d.get("physical_max_distance")
        prior = d.get("nominal")
        return cls(
            classes=classes, noise=noise,
            sample_period_s=check_positive("patterns.sample_period_s",
                                           d.get("sample_period_s")),
            block_s=check_positive("patterns.block_s", d.get("block_s")),
            growth_threshold=check_nonnegative("patterns.growth_threshold",
                                               d.get("growth_threshold", 0.15)),
            loss_margin=check_nonnegative("patterns.loss_margin", d.get("loss_margin", 2.0)),
            level_model_error=check_nonnegative("patterns.level_model_error",
                                                d.get("level_model_error", 0.25)),
            log_variance_model_error=check_nonnegative(
                "patterns.log_variance_model_error", d.get("log_variance_model_error", 0.1)),
            log_eta_model_error=check_nonnegative("patterns.log_eta_model_error",
                                                  d.get("log_eta_model_error", 0.25)),
            component_cap=check_positive("patterns.component_cap",
                                         d.get("component_cap", 25.0)),
            max_distance=None if md is None else check_nonnegative("patterns.max_distance",
                                                                   md),
            prior=None if prior is None else NominalPrior.from_dict(prior,
                                                                    "patterns.nominal"),
            physical_max_distance=None if pmd is None else check_nonnegative(
                "patterns.physical_max_distance", pmd),
        )

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready content (:meth:`from_dict` reads it back)."""
        out: dict[str, Any] = {
            "format": FORMAT, "sample_period_s": self.sample_period_s,
            "block_s": self.block_s, "classes": [c.to_dict() for c in self.classes],
            "noise": self.noise.to_dict(), "growth_threshold": self.growth_threshold,
            "loss_margin": self.loss_margin, "level_model_error": self.level_model_error,
            "log_variance_model_error": self.log_variance_model_error,
            "log_eta_model_error": self.log_eta_model_error,
            "component_cap": self.component_cap, "max_distance": self.max_distance,
            "physical_max_distance": self.physical_max_distance,
        }
        if self.prior is not None:
            out["nominal"] = self.prior.to_dict()
        return out


@dataclass(frozen=True)
class PatternResult:
    """A classification.

    Attributes
    ----------
    code : int
        1-based class position, ``UNKNOWN_CODE`` if unknown.
    name : str
        Class name or ``"unknown"``.
    fault_type, signal, axis : int
        Codes of :data:`FAULT_TYPES`, :data:`SIGNALS` (0 for physical classes) and
        :data:`AXIS_CODES`; −1 if unknown.
    distance : float
        χ² per channel of the best class.
    size : float
        Step offset (V, signed), noise std (V), remaining noise of a loss (V), current
        offset of a drift (V); NaN for physical classes and unknown.
    rate : float
        Drift rate, V/s (NaN otherwise).
    ratio : float
        Physical classes: estimated parameter ratio (e.g. Ω/Ω_nom); NaN otherwise.
    runner_up : str
        Second-best class.
    margin : float
        χ² per channel of the runner-up minus that of the best class.
    signal_mask : int
        The signals named, one bit each (1 Utx, 2 Uty, 4 Ux, 8 Uy; 0 physical, unknown):
        two bits for a pair (``code`` :data:`SEVERAL_CODE`).
    """

    code: int
    name: str
    fault_type: int
    signal: int
    axis: int
    distance: float
    size: float = math.nan
    rate: float = math.nan
    ratio: float = math.nan
    runner_up: str = ""
    margin: float = math.nan
    signal_mask: int = 0


def signal_bit(signal: str) -> int:
    """Bit of a signal in :attr:`PatternResult.signal_mask`."""
    return 1 << SIGNALS.index(signal)


def scored_response(lib: PatternLibrary, i: int) -> NDArray[np.float64]:
    """Level response used for class i's signal (the step class's where there is one)."""
    c = lib.classes[i]
    for other in lib.classes:
        if other.type == "step" and other.signal == c.signal:
            return other.response
    return c.response


UNKNOWN_RESULT = PatternResult(UNKNOWN_CODE, "unknown", -1, -1, -1, math.nan)


def physical_class(library: PatternLibrary | None, kind: str, ratio: float) -> PatternResult:
    """The library's class of physical fault type ``kind`` (e.g. "spin") with its
    parameter ratio; unknown where the library has none."""
    for i, c in enumerate(library.classes if library is not None else ()):
        if c.type == kind:
            return PatternResult(code=i + 1, name=c.name,
                                 fault_type=FAULT_TYPES.index(kind) + 1, signal=0,
                                 axis=c.axis, distance=0.0, ratio=ratio)
    return UNKNOWN_RESULT


class PatternClassifier:
    """Fits every class of a :class:`PatternLibrary` to :class:`ClassificationStatistics`.

    Parameters
    ----------
    library : PatternLibrary
        The learned classes.
    """

    def __init__(self, library: PatternLibrary) -> None:
        self.library = library
        classes = library.classes
        self._step = {c.signal: i for i, c in enumerate(classes) if c.type == "step"}
        self._drift = {c.signal: i for i, c in enumerate(classes) if c.type == "drift"}
        # one level fit per signal, with the step response where there is one (a drift
        # has the same spatial response); noise and loss classes are fitted each
        level = {**self._drift, **self._step}
        self._signal = sorted([(i, classes[i]) for i in level.values()]
                              + [(i, c) for i, c in enumerate(classes)
                                 if c.type in ("noise", "loss")], key=lambda ic: ic[0])
        self._physical = [(i, c) for i, c in enumerate(library.classes)
                          if c.type in PHYSICAL_TYPES]

    @property
    def has_physical(self) -> bool:
        """The library has physical classes."""
        return bool(self._physical)

    # -- signal faults ---------------------------------------------------------------
    def classify_signal_fault(self, stats: ClassificationStatistics) -> PatternResult:
        """Best signal-fault class (step, drift, noise, loss) for the statistics."""
        if not self._signal:
            return UNKNOWN_RESULT
        lib = self.library
        f = lib.noise.scale(stats.window_blocks)
        s_level = lib.noise.level_std * f
        s_lv2 = (lib.noise.log_variance_std * f) ** 2 + lib.log_variance_model_error ** 2
        if not stats.raw_signals:
            # the voltages carry the manoeuvre (a case-rate channel): only the residuals'
            # levels and variances are compared (an infinite spread weighs a channel 0;
            # the distance stays per library component, so that it compares with the
            # physical classes' as in level flight: measured, docs/dtg_case_rate.md)
            s_level = np.where(_RAW_CHANNELS, np.inf, s_level)
            s_lv2 = np.where(_RAW_CHANNELS, np.inf, s_lv2)
        lv = np.clip(stats.log_variance, LOG_VAR_MIN, LOG_VAR_MAX)
        ratio_obs = 10.0 ** lv
        cap = lib.component_cap
        scored: list[tuple[float, int, float]] = []
        for i, c in self._signal:
            if c.type in ("step", "drift"):
                chi2, a = self._fit_level(c.response, stats.level, lv, ratio_obs, s_level,
                                          s_lv2)
            else:
                chi2, a = self._fit_variance(c, stats.level, lv, s_level, s_lv2, cap)
            scored.append((chi2, i, a))
        scored.sort()
        chi2, i, a = scored[0]
        best = lib.classes[i]
        if best.type == "loss":
            for c2, j, a2 in scored:
                other = lib.classes[j]
                if other.type == "noise" and other.signal == best.signal:
                    if c2 - chi2 < lib.loss_margin:
                        chi2, i, a, best = c2, j, a2, other
                    break
        n = 2 * N_CHANNELS
        distance = chi2 / n
        runner = next(((c2, j) for c2, j, _ in scored if j != i), (math.nan, -1))
        runner_name = lib.classes[runner[1]].name if runner[1] >= 0 else ""
        if lib.max_distance is not None and distance > lib.max_distance:
            return PatternResult(UNKNOWN_CODE, "unknown", -1, -1, -1, distance,
                                 runner_up=best.name, margin=math.nan)
        size = rate = math.nan
        if best.type in ("step", "drift"):
            size = a
            drifting = stats.growth > lib.growth_threshold
            table = self._drift if drifting else self._step
            if best.signal in table:
                i = table[best.signal]
                best = lib.classes[i]
            if best.type == "drift":
                rate = self._rate(scored_response(lib, i), stats, ratio_obs, s_level)
        elif best.type in ("noise", "loss"):
            size = math.sqrt(a)
        return PatternResult(
            code=i + 1, name=best.name, fault_type=FAULT_TYPES.index(best.type) + 1,
            signal=SIGNALS.index(best.signal) + 1, axis=best.axis, distance=distance,
            size=size, rate=rate, runner_up=runner_name,
            signal_mask=signal_bit(best.signal),
            margin=(runner[0] - chi2) / n if runner[1] >= 0 else math.nan)

    def classify_pair(self, stats: ClassificationStatistics, single: PatternResult
                      ) -> PatternResult | None:
        """Two level faults on different signals, where they explain the window's
        levels better than any one level class by :data:`PAIR_MARGIN`; else None.

        ``single`` is the one-class result (a level class, or unknown); none while the
        voltages carry a manoeuvre (``stats.raw_signals`` False). The result has
        ``code`` :data:`SEVERAL_CODE`, ``signal`` −1, both signals in ``signal_mask``,
        and the name ``"<larger>+<smaller>"``."""
        # in a manoeuvre only the two residual levels are compared: two sizes fit any
        if (single.fault_type not in (-1, 1, 4) or len(self._step) < 2
                or not stats.raw_signals):
            return None
        # a single class whose whole χ² is under half the margin leaves no pair a chance
        # (its level χ² bounds every one-signal fit's): skip the ten fits (docs/notes.md)
        if single.fault_type > 0 and single.distance * 2 * N_CHANNELS < 0.5 * PAIR_MARGIN:
            return None
        lib = self.library
        s_level = lib.noise.level_std * lib.noise.scale(stats.window_blocks)
        lv = np.clip(stats.log_variance, LOG_VAR_MIN, LOG_VAR_MAX)
        s2 = (s_level * np.sqrt(np.maximum(10.0 ** lv, 1.0))) ** 2
        responses = {sig: scored_response(lib, i) for sig, i in self._step.items()}
        alone = min(self._fit_levels([p], stats.level, s2)[0] for p in responses.values())
        best: tuple[float, str, str, NDArray[np.float64]] | None = None
        signals = sorted(responses, key=SIGNALS.index)
        for u, first in enumerate(signals):
            for second in signals[u + 1:]:
                chi2, a = self._fit_levels([responses[first], responses[second]],
                                           stats.level, s2)
                if best is None or chi2 < best[0]:
                    best = (chi2, first, second, a)
        if best is None or best[0] + PAIR_MARGIN > alone:
            return None
        chi2, first, second, a = best
        names = [lib.classes[self._step[first]].name, lib.classes[self._step[second]].name]
        if abs(a[1]) > abs(a[0]):
            names.reverse()
        axes = {AXIS_CODES[first], AXIS_CODES[second]}
        return PatternResult(
            code=SEVERAL_CODE, name="+".join(names),
            fault_type=single.fault_type if single.fault_type > 0 else 1, signal=-1,
            axis=axes.pop() if len(axes) == 1 else 3, distance=chi2 / (2 * N_CHANNELS),
            runner_up=single.name, signal_mask=signal_bit(first) | signal_bit(second))

    def _fit_levels(self, responses: list[NDArray[np.float64]], level: NDArray[np.float64],
                    s2: NDArray[np.float64]) -> tuple[float, NDArray[np.float64]]:
        """Level χ² and sizes of a sum of level responses (weighted LS with the
        library's relative model error, as :meth:`_fit_level`)."""
        lib = self.library
        rho2 = lib.level_model_error ** 2
        p = np.array(responses)
        a = np.zeros(p.shape[0])
        pred = np.zeros_like(level)
        for _ in range(4):
            w = 1.0 / (s2 + rho2 * pred * pred)
            normal = (p * w) @ p.T
            a = np.linalg.lstsq(normal, (p * w) @ level, rcond=None)[0]
            pred = a @ p
        w = 1.0 / (s2 + rho2 * pred * pred)
        return float(np.sum(np.minimum(w * (level - pred) ** 2, lib.component_cap))), a

    def as_drift(self, result: PatternResult, stats: ClassificationStatistics
                 ) -> PatternResult | None:
        """``result`` (a level class) read as its signal's drift class, with the rate
        from the window's slopes; None where the library has no drift for it."""
        if result.fault_type not in (1, 4) or not 1 <= result.signal <= len(SIGNALS):
            return None
        i = self._drift.get(SIGNALS[result.signal - 1])
        if i is None:
            return None
        lib = self.library
        s_level = lib.noise.level_std * lib.noise.scale(stats.window_blocks)
        ratio_obs = 10.0 ** np.clip(stats.log_variance, LOG_VAR_MIN, LOG_VAR_MAX)
        rate = self._rate(scored_response(lib, i), stats, ratio_obs, s_level)
        return replace(result, code=i + 1, name=lib.classes[i].name,
                       fault_type=FAULT_TYPES.index("drift") + 1, rate=rate)

    def _fit_level(self, p: NDArray[np.float64], level: NDArray[np.float64],
                   lv: NDArray[np.float64], ratio_obs: NDArray[np.float64],
                   s_level: NDArray[np.float64], s_lv2: NDArray[np.float64]
                   ) -> tuple[float, float]:
        lib = self.library
        rho2 = lib.level_model_error ** 2
        s2 = (s_level * np.sqrt(np.maximum(ratio_obs, 1.0))) ** 2
        pp = float(p @ p)
        a = 0.0
        pred = np.zeros_like(level)
        for _ in range(3):
            w = 1.0 / (s2 + rho2 * pred * pred)
            a = float(np.sum(w * p * level) / max(np.sum(w * p * p), 1e-300 * pp))
            pred = a * p
        w = 1.0 / (s2 + rho2 * pred * pred)
        cap = lib.component_cap
        chi2 = float(np.sum(np.minimum(w * (level - pred) ** 2, cap))
                     + np.sum(np.minimum(lv * lv / s_lv2, cap)))
        return chi2, a

    def _fit_variance(self, c: PatternClass, level: NDArray[np.float64],
                      lv: NDArray[np.float64], s_level: NDArray[np.float64],
                      s_lv2: NDArray[np.float64], cap: float) -> tuple[float, float]:
        if c.base is None:
            base = np.ones(N_CHANNELS)
        else:
            base = np.where(np.isnan(c.base), 0.0, 1.0 + np.nan_to_num(c.base))
        def score(grid: NDArray[np.float64]) -> tuple[NDArray[np.float64],
                                                       NDArray[np.float64]]:
            pred = base[None, :] + grid[:, None] * c.response[None, :]
            lv_pred = np.clip(np.log10(np.maximum(pred, 1e-300)), LOG_VAR_MIN, LOG_VAR_MAX)
            return (np.minimum((lv[None, :] - lv_pred) ** 2 / s_lv2[None, :], cap).sum(axis=1),
                    lv_pred)

        chi_v, _ = score(_AMPLITUDE_GRID)
        g = int(np.argmin(chi_v))
        # refine between the neighbours of the coarse optimum (1 % in amplitude)
        lo = _AMPLITUDE_GRID[max(g - 1, 0)]
        hi = _AMPLITUDE_GRID[min(g + 1, _AMPLITUDE_GRID.size - 1)]
        fine = np.geomspace(lo, hi, 41)
        chi_f, lv_pred = score(fine)
        f = int(np.argmin(chi_f))
        # the level of a noisy channel wanders more than nominal: a loose spread (×3)
        ratio = np.maximum(10.0 ** lv_pred[f], 1.0)
        chi_l = np.minimum((level / (3.0 * s_level * np.sqrt(ratio))) ** 2, cap).sum()
        return float(chi_f[f] + chi_l), float(fine[f])

    def _rate(self, p: NDArray[np.float64], stats: ClassificationStatistics,
              ratio_obs: NDArray[np.float64], s_level: NDArray[np.float64]) -> float:
        w = 1.0 / (s_level * s_level * np.maximum(ratio_obs, 1.0))
        den = float(np.sum(w * p * p))
        return float(np.sum(w * p * stats.slope) / den) if den > 0 else math.nan

    # -- physical faults -------------------------------------------------------------
    def classify_physical(self, stats: ClassificationStatistics) -> PatternResult:
        """Best physical class for the log η statistics (unknown without any)."""
        if not self._physical:
            return UNKNOWN_RESULT
        lib = self.library
        s = lib.noise.log_eta_std * lib.noise.scale(stats.window_blocks)
        y = stats.log_eta
        rho2 = lib.log_eta_model_error ** 2
        cap = lib.component_cap
        scored = []
        for i, c in self._physical:
            p = c.response
            a = 0.0
            pred = np.zeros(N_ETA)
            for _ in range(3):
                w = 1.0 / (s * s + rho2 * pred * pred)
                a = float(np.sum(w * p * y) / np.sum(w * p * p))
                pred = a * p
            w = 1.0 / (s * s + rho2 * pred * pred)
            scored.append((float(np.sum(np.minimum(w * (y - pred) ** 2, cap))), i, a))
        scored.sort()
        chi2, i, a = scored[0]
        distance = chi2 / N_ETA
        limit = lib.physical_max_distance
        if limit is not None and distance > limit:
            return PatternResult(UNKNOWN_CODE, "unknown", -1, -1, -1, distance)
        best = lib.classes[i]
        runner = scored[1] if len(scored) > 1 else None
        return PatternResult(
            code=i + 1, name=best.name, fault_type=FAULT_TYPES.index(best.type) + 1,
            signal=0, axis=best.axis, distance=distance, ratio=10.0 ** a,
            runner_up="" if runner is None else lib.classes[runner[1]].name,
            margin=math.nan if runner is None else (runner[0] - chi2) / N_ETA)


def default_library(path: Path | None = None) -> PatternLibrary:
    """The shipped pattern library, used when no ``dtg.signature_file`` is given: from
    ``path`` (an FMU's own copy) or :data:`DEFAULT_LIBRARY_FILE`."""
    data = json.loads((path or DEFAULT_LIBRARY_FILE).read_text(encoding="utf-8"))
    return PatternLibrary.from_dict(data["patterns"])
