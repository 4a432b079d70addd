"""Learning the DTG pattern library from training runs (numpy only).

A training run (:class:`PatternRun`) is what a Diagnoser reported during one training
scenario: the harness reads it (:mod:`gyrodiag_harness.campaigns.pattern_learning`), this module
learns from it.

What is learned (:func:`learn_patterns`), from the Diagnoser's own outputs so that what
is classified is what was learned:

1. **Noise model**: the spread of ``dtg.level[i]`` and ``dtg.log_var_ratio[i]`` over the
   fault-free part of every run after learning (RMS about 0), and of log10 of the
   short-window mean η. The window of those statistics (``dtg.stat_window_s``) is the
   reference window of :class:`gyrodiag.dtg.patterns.NoiseModel`.
2. **Responses** at each run's last sample (the classification window, up to the long
   window): step level/size, drift level/(rate·age at the window centre), noise
   (ratio − 1)/size², loss: the other channels' ratio − 1 (``base``) plus the noise
   response of the same signal, physical log10 η/log10 size. A class's response is the
   element-wise median over its runs; entries within 3 standard errors of 0 are set to
   0 (one seed's noise must not become a signature), noise responses are clipped at 0.
3. **Growth threshold** between step and drift: the threshold on ``dtg.level_growth``
   with the fewest errors over all alarm samples of the step and drift runs, counted as
   fractions of each class.
4. **Prior**: median reference of the runs whose reference was valid, θ0 spread.
5. **max_distance**: 4 × the largest distance of a training run to its own class (signal
   faults and physical faults apart), so that a fault unlike every class is "unknown".
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:
    from .patterns import NoiseModel, PatternClass, PatternLibrary
    from .reference import NominalPrior

__all__ = [
    "PatternRun",
    "learn_patterns",
]

N_CH = 6
N_THETA = 5
SIGNAL_FAULT_TYPES = ("step", "drift", "noise", "loss")
PHYSICAL_TYPES = ("spin", "torquer")
TRAINING_TYPES = (*SIGNAL_FAULT_TYPES, *PHYSICAL_TYPES, "nominal")
_SIGNALS = ("Utx", "Uty", "Ux", "Uy")


@dataclass
class PatternRun:
    """The data of one pattern training run.

    Attributes
    ----------
    scenario, name, type : str
        Scenario, class name, training type.
    signal : str or None
        Faulty signal (signal faults).
    size : float
        Fault size (V, V/s, V std or ratio); NaN for nominal runs.
    onset_s : float or None
        Fault onset (None: nominal).
    learn_end_s : float
        End of the channel's learning window.
    time : ndarray (n,)
    alarm, residual_alarm : ndarray of bool (n,)
    level, log_var : ndarray (n, 6)
    growth, window_s : ndarray (n,)
    eta : ndarray (n, 10)
    reference : dict of str to ndarray
        ``theta0`` (5) and ``mean``, ``block_std``, ``var_short``, ``var_long`` (6) at the
        last sample; ``status`` the reference status there.
    """

    scenario: str
    name: str
    type: str
    signal: str | None
    size: float
    onset_s: float | None
    learn_end_s: float
    time: NDArray[np.float64]
    alarm: NDArray[np.bool_]
    residual_alarm: NDArray[np.bool_]
    level: NDArray[np.float64]
    log_var: NDArray[np.float64]
    growth: NDArray[np.float64]
    window_s: NDArray[np.float64]
    eta: NDArray[np.float64]
    reference: dict[str, Any]


# --------------------------------------------------------------------------- learning
def _nominal_mask(run: PatternRun, long_window_s: float) -> NDArray[np.bool_]:
    t = run.time
    end = run.onset_s if run.onset_s is not None else math.inf
    return (t >= run.learn_end_s + long_window_s) & (t < end) & ~run.residual_alarm


def _rolling_log_eta(eta: NDArray[np.float64], n: int, step: int) -> NDArray[np.float64]:
    """log10 of the mean η over windows of n samples, every ``step`` samples."""
    if eta.shape[0] < n:
        return np.zeros((0, eta.shape[1]))
    c = np.cumsum(np.vstack([np.zeros((1, eta.shape[1])), eta]), axis=0)
    ends = np.arange(n, eta.shape[0] + 1, max(step, 1))
    return np.log10(np.maximum((c[ends] - c[ends - n]) / n, 1e-300))


def _end_stats(r: PatternRun) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
    """Level, log variance ratio and window length at the run's last sample."""
    return r.level[-1], r.log_var[-1], float(r.window_s[-1])


def _noise_model(runs: Sequence[PatternRun], *, sample_period_s: float, block_s: float,
                 short_window_s: float, long_window_s: float) -> tuple[NoiseModel, int]:
    """Phase 1: the noise model from the fault-free rows, and how many rows fed it."""
    from .patterns import NoiseModel

    lev, lvr, leta = [], [], []
    n_eta = max(1, round(short_window_s / sample_period_s))
    step = max(1, round(block_s / sample_period_s))
    for r in runs:
        m = _nominal_mask(r, long_window_s)
        m &= np.isclose(r.window_s, short_window_s, rtol=0.05)
        if m.any():
            lev.append(r.level[m][::step])
            lvr.append(r.log_var[m][::step])
            idx = np.flatnonzero(m)
            seg = r.eta[idx[0]:idx[-1] + 1]
            leta.append(_rolling_log_eta(seg, n_eta, step))
    if not lev:
        raise ValueError("no fault-free data after learning in any training run: start the "
                         "faults at least a long window after the end of learning")
    L, V, E = np.vstack(lev), np.vstack(lvr), np.vstack(leta)
    rms = lambda a: np.sqrt(np.mean(a * a, axis=0))  # noqa: E731
    ref_blocks = max(1, round(short_window_s / block_s))
    noise = NoiseModel(np.maximum(rms(L), 1e-9), np.maximum(rms(V), 1e-6),
                       np.maximum(rms(E) if E.size else np.full(10, 1e-3), 1e-6), ref_blocks)
    return noise, int(L.shape[0])


def _by_class(runs: Sequence[PatternRun], codes: dict[str, int]) -> dict[str, list[PatternRun]]:
    """The fault runs by class; every class of ``codes`` must have one."""
    by_class: dict[str, list[PatternRun]] = {}
    for r in runs:
        if r.type != "nominal":
            by_class.setdefault(r.name, []).append(r)
    for name in codes:
        if name not in by_class:
            raise ValueError(f"class {name!r} has no training run")
    return by_class


def _check_class(name: str, rs: list[PatternRun]) -> tuple[str, str | None]:
    """Type and signal of a class, checked consistent and usable for learning."""
    types = {r.type for r in rs}
    signals = {r.signal for r in rs}
    if len(types) != 1 or len(signals) != 1:
        raise ValueError(f"class {name!r}: its runs disagree on type/signal "
                         f"({sorted(types)}, {sorted(map(str, signals))})")
    typ, signal = rs[0].type, rs[0].signal
    if typ in SIGNAL_FAULT_TYPES:
        if signal not in _SIGNALS:
            raise ValueError(f"class {name!r}: training.signal must be one of {_SIGNALS}")
        for r in rs:
            if not r.residual_alarm[-1]:
                raise ValueError(
                    f"training run {r.scenario!r} (class {name!r}) does not end in "
                    "residual alarm (dtg.residual_alarm = 0 at its last sample): its "
                    "statistics would be nominal; make the fault larger or the run "
                    "longer")
    elif typ not in PHYSICAL_TYPES:
        raise ValueError(f"class {name!r}: unknown training.type {typ!r}")
    return typ, signal


def _run_responses(name: str, rs: list[PatternRun], typ: str, noise: NoiseModel, *,
                   block_s: float, sample_period_s: float,
                   record_runs: list[dict[str, Any]]) -> tuple[list[Any], list[Any]]:
    """Response and its standard deviation of each run of a class (phase 2).

    Appends each run's entry to ``record_runs``.
    """
    samples, sds = [], []
    for r in rs:
        level, log_var, win = _end_stats(r)
        f = noise.scale(max(1, round(win / block_s)))
        t_end = r.time[-1]
        if typ == "step":
            samples.append(level / r.size)
            sds.append(noise.level_std * f / abs(r.size))
        elif typ == "drift":
            age = max(t_end - 0.5 * win - float(r.onset_s), 1e-3)
            samples.append(level / (r.size * age))
            sds.append(noise.level_std * f / abs(r.size * age))
        elif typ == "noise":
            ratio = 10.0 ** log_var
            samples.append((ratio - 1.0) / r.size ** 2)
            sds.append(ratio * math.log(10) * noise.log_variance_std * f / r.size ** 2)
        elif typ == "loss":
            ratio = 10.0 ** log_var
            samples.append(ratio - 1.0)
            sds.append(ratio * math.log(10) * noise.log_variance_std * f)
        else:
            n_long = max(1, round(win / sample_period_s))
            le = np.log10(np.maximum(r.eta[-n_long:].mean(axis=0), 1e-300))
            samples.append(le / math.log10(r.size))
            sds.append(noise.log_eta_std * noise.scale(max(1, round(win / block_s)))
                       / abs(math.log10(r.size)))
        record_runs.append({"scenario": r.scenario, "class": name,
                            "size": r.size, "window_s": win,
                            "response": [float(v) for v in samples[-1]]})
    return samples, sds


def _responses(by_class: dict[str, list[PatternRun]], codes: dict[str, int],
               noise: NoiseModel, *, block_s: float, sample_period_s: float,
               ) -> tuple[dict[str, NDArray[np.float64]], dict[str, NDArray[np.float64]],
                          list[dict[str, Any]], list[str]]:
    """Phase 2: each class's response (losses last: they take their noise class's).

    Returns the responses, the loss bases, the per-run record and the class order.
    """
    record_runs: list[dict[str, Any]] = []
    responses: dict[str, NDArray[np.float64]] = {}
    bases: dict[str, NDArray[np.float64]] = {}
    order = sorted(codes, key=lambda n: (by_class[n][0].type == "loss", codes[n]))
    for name in order:
        rs = by_class[name]
        typ, signal = _check_class(name, rs)
        samples, sds = _run_responses(name, rs, typ, noise, block_s=block_s,
                                      sample_period_s=sample_period_s,
                                      record_runs=record_runs)
        S, D = np.array(samples), np.array(sds)
        med = np.median(S, axis=0)
        se = 1.2533 * np.median(D, axis=0) / math.sqrt(len(rs))
        med = np.where(np.abs(med) > 3.0 * se, med, 0.0)
        if typ == "noise":
            med = np.maximum(med, 0.0)
        if typ == "loss":
            lost = _SIGNALS.index(signal)
            noise_cls = [n for n in by_class if by_class[n][0].type == "noise"
                         and by_class[n][0].signal == signal]
            if not noise_cls:
                raise ValueError(f"class {name!r} (loss of {signal}) needs a noise class on "
                                 f"{signal} in the training set: a loss with noise left is "
                                 "fitted with that class's response")
            base = np.maximum(med, -1.0)
            base[lost] = math.nan
            bases[name] = base
            responses[name] = responses[noise_cls[0]]
        else:
            responses[name] = med
    return responses, bases, record_runs, order


def _pattern_classes(codes: dict[str, int], by_class: dict[str, list[PatternRun]],
                     responses: dict[str, NDArray[np.float64]],
                     bases: dict[str, NDArray[np.float64]]) -> list[PatternClass]:
    """The classes in library (code) order."""
    from .patterns import PatternClass

    classes = []
    for name in sorted(codes, key=codes.get):  # type: ignore[arg-type]
        r0 = by_class[name][0]
        classes.append(PatternClass(name, r0.type,
                                    None if r0.type in PHYSICAL_TYPES else r0.signal,
                                    responses[name], bases.get(name)))
    return classes


def _growth_threshold(by_class: dict[str, list[PatternRun]], short_window_s: float,
                      block_s: float) -> tuple[float, list[Any], list[Any]]:
    """Phase 3: the step/drift growth threshold, and the growths of each class."""
    gs, gd = [], []
    for rs in by_class.values():
        for r in rs:
            # the classification windows: a short window (and the two skipped blocks)
            # after the alarm rose, as the channel classifies
            sel = r.residual_alarm & (r.window_s >= short_window_s * 0.95)
            if r.onset_s is not None:
                sel &= r.time >= r.onset_s
            rose = np.flatnonzero(sel)
            if rose.size:
                sel &= r.time >= r.time[rose[0]] + short_window_s + 2.0 * block_s
            if r.type == "step":
                gs.append(r.growth[sel])
            elif r.type == "drift":
                gd.append(r.growth[sel])
    threshold = 0.15
    if gs and gd:
        g_step, g_drift = np.concatenate(gs), np.concatenate(gd)
        cands = np.linspace(0.0, 1.0, 201)
        err = [np.mean(g_step > c) + np.mean(g_drift <= c) for c in cands]
        best = float(np.min(err))
        # the middle of the best plateau: as far from both classes as the data allow
        good = cands[np.asarray(err) <= best + 1e-12]
        threshold = float(0.5 * (good[0] + good[-1]))
    return threshold, gs, gd


def _prior(runs: Sequence[PatternRun]) -> NominalPrior | None:
    """Phase 4: the nominal prior from the runs whose reference was valid."""
    from .reference import NominalPrior

    ok = [r for r in runs if r.reference["status"] == 1]
    prior = None
    if ok:
        th = np.array([r.reference["theta0"] for r in ok])
        prior = NominalPrior(
            theta0=np.median(th, axis=0), theta0_std=th.std(axis=0),
            mean=np.median([r.reference["mean"] for r in ok], axis=0),
            block_std=np.median([r.reference["block_std"] for r in ok], axis=0),
            var_short=np.median([r.reference["var_short"] for r in ok], axis=0),
            var_long=np.median([r.reference["var_long"] for r in ok], axis=0))
    return prior


def _training_distances(lib: PatternLibrary, by_class: dict[str, list[PatternRun]],
                        order: list[str], record_runs: list[dict[str, Any]], *,
                        block_s: float, sample_period_s: float,
                        ) -> tuple[list[float], list[float]]:
    """Phase 5: classify each training run; distances to its own class.

    Writes the classification into ``record_runs``; returns the distances of the
    signal-fault runs and of the physical runs classified as their class.
    """
    from .patterns import PatternClassifier
    from .reference import ClassificationStatistics

    clf = PatternClassifier(lib)
    distances: list[float] = []
    physical: list[float] = []
    for entry, r in zip(record_runs, [r for n in order for r in by_class[n]], strict=True):
        level, log_var, win = _end_stats(r)
        k = max(1, round(win / block_s))
        n_long = max(1, round(win / sample_period_s))
        stats = ClassificationStatistics(
            level=level, log_variance=log_var, slope=np.zeros(N_CH),
            growth=float(r.growth[-1]),
            log_eta=np.log10(np.maximum(r.eta[-n_long:].mean(axis=0), 1e-300)),
            window_blocks=k, window_s=win)
        res = (clf.classify_physical(stats) if r.type in PHYSICAL_TYPES
               else clf.classify_signal_fault(stats))
        entry["classified"] = res.name
        entry["distance"] = float(res.distance)
        if res.name == r.name:
            (physical if r.type in PHYSICAL_TYPES else distances).append(res.distance)
    return distances, physical


def learn_patterns(runs: Sequence[PatternRun], codes: dict[str, int], *,
                   sample_period_s: float, block_s: float, short_window_s: float,
                   long_window_s: float) -> tuple[Any, dict[str, Any]]:
    """Learn a :class:`gyrodiag.dtg.patterns.PatternLibrary` (module docstring).

    Parameters
    ----------
    runs : sequence of PatternRun
        Training runs.
    codes : dict
        Class name → code (1..n), the library order.
    sample_period_s, block_s, short_window_s, long_window_s : float
        The channel's sampling, block and window lengths (s).

    Returns
    -------
    library : PatternLibrary
    record : dict
        Per-run responses, distances and the training classification, for the file.

    Raises
    ------
    ValueError
        A class without runs, inconsistent runs of a class, a signal-fault run that does
        not end in residual alarm, no fault-free data for the noise model.
    """
    from .patterns import PatternLibrary

    noise, nominal_samples = _noise_model(
        runs, sample_period_s=sample_period_s, block_s=block_s,
        short_window_s=short_window_s, long_window_s=long_window_s)
    by_class = _by_class(runs, codes)
    responses, bases, record_runs, order = _responses(
        by_class, codes, noise, block_s=block_s, sample_period_s=sample_period_s)
    classes = _pattern_classes(codes, by_class, responses, bases)
    threshold, gs, gd = _growth_threshold(by_class, short_window_s, block_s)
    prior = _prior(runs)
    lib = PatternLibrary(classes=tuple(classes), noise=noise, sample_period_s=sample_period_s,
                         block_s=block_s, growth_threshold=threshold, prior=prior)
    distances, physical = _training_distances(
        lib, by_class, order, record_runs, block_s=block_s,
        sample_period_s=sample_period_s)
    lib = PatternLibrary(classes=tuple(classes), noise=noise, sample_period_s=sample_period_s,
                         block_s=block_s, growth_threshold=threshold, prior=prior,
                         max_distance=4.0 * max(distances) if distances else None,
                         physical_max_distance=4.0 * max(physical) if physical else None)
    record = {"runs": record_runs,
              "nominal_samples": nominal_samples,
              "growth": {"threshold": threshold,
                         "step_max": float(np.max(np.concatenate(gs))) if gs else None,
                         "drift_min": float(np.min(np.concatenate(gd))) if gd else None}}
    return lib, record
