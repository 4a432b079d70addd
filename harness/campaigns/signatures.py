"""DTG fault-signature library learned from training runs (``learn-signatures``).

::

    python -m gyrodiag_harness learn-signatures scenarios/training --out results/dtg_signatures.json
    python -m gyrodiag_harness verify scenarios/dtg_fault_*.toml --out results

A training scenario is an ordinary scenario with a ``[training]`` table
(:class:`gyrodiag_harness.cosim.scenario.Training`)::

    [training]
    signature = "utx_step"   # fault class (identifier)
    code = 1                 # its fault code = position in the library (dtg.fault_code)
    diagnoser = "diag"       # Diagnoser instance whose dtg.eta_x / dtg.eta_y are read

Learning
--------
1. Every training scenario is run (or, with ``--saved``, its saved run is loaded).  A
   run must complete and end in DTG alarm (``dtg.alarm`` = 1 at the last sample):
   otherwise its feature would be the nominal one and the command fails.
2. Feature of a run: at each sample, C = round(log10 η) per axis
   (:func:`gyrodiag.dtg.decision.feature_vector`) and the axis with the larger Σ|C_i|
   (x on ties) — the rule by which ``gyrodiag.dtg.channel`` picks the vector it
   classifies.  The run's feature is the element-wise median of these vectors over the
   alarm samples of the final ``window_s`` seconds (``window_s`` = 0: the last sample
   only), rounded half away from zero.  A window rather than one sample, because the
   forgetting estimator's η jitters by a decade from sample to sample in a fault.
3. Signature of a class: element-wise median of its runs' features (rounded the same
   way), so one unusual training seed cannot move it.
4. Classes are written in code order; codes must be 1..n without gaps, one code per
   class.  The JSON file holds ``{"signatures": {name: [C1..C5]}}`` (what the
   Diagnoser's ``dtg.signature_file`` reads) plus ``codes``, the per-run features and
   the pairwise eq. 7 distances, for the record.

A verification scenario names the file through a file parameter of its Diagnoser
instance: ``files = { "dtg.signature_file" = "${out}/dtg_signatures.json" }`` (see
:class:`gyrodiag_harness.cosim.scenario.FmuInstance`).
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from gyrodiag_harness.campaigns.pattern_learning import pattern_signal_names
from gyrodiag_harness.cosim.results import RunResult
from gyrodiag_harness.cosim.scenario import Scenario, ScenarioError

__all__ = [
    "N_THETA",
    "RunFeature",
    "SignatureLibrary",
    "check_training_scenarios",
    "learn_signatures",
    "run_feature",
    "signal_names",
]

#: Number of identified DTG parameters θ1..θ5 (per axis).
N_THETA = 5
#: Default length of the final window whose median feature describes a run, s.
DEFAULT_WINDOW_S = 0.5
_AXES = ("x", "y")


def signal_names(diagnoser: str) -> list[str]:
    """Recorded signals a training run needs: ``dtg.eta_x[1..5]``, ``dtg.eta_y[1..5]``
    and ``dtg.alarm`` of the Diagnoser instance ``diagnoser``."""
    names = [f"{diagnoser}.dtg.eta_{a}[{i}]" for a in _AXES for i in range(1, N_THETA + 1)]
    return [*names, f"{diagnoser}.dtg.alarm"]


@dataclass(frozen=True)
class RunFeature:
    """Feature vector of one training run.

    Attributes
    ----------
    scenario : str
        Scenario name.
    signature : str
        Its fault class.
    feature : ndarray of int, shape (5,)
        Median feature vector C over the final window.
    axes : str
        Axes picked at the window's samples, e.g. ``"y"`` or ``"x,y"``.
    eta_end : ndarray, shape (2, 5)
        η of both axes at the last sample (1).
    n_samples : int
        Alarm samples in the final window.
    """

    scenario: str
    signature: str
    feature: NDArray[np.int64]
    axes: str
    eta_end: NDArray[np.float64]
    n_samples: int


def run_feature(result: RunResult, diagnoser: str, signature: str,
                window_s: float = DEFAULT_WINDOW_S) -> RunFeature:
    """Feature vector C of a training run (module docstring, step 2).

    Parameters
    ----------
    result : RunResult
        A completed run that recorded :func:`signal_names`.
    diagnoser : str
        Diagnoser instance name.
    signature : str
        Fault class of the run (kept in the result).
    window_s : float
        Final window, s (>= 0; 0: the last sample).

    Raises
    ------
    ValueError
        If the run failed, has no samples, or does not end in DTG alarm.
    KeyError
        If a needed signal was not recorded (names it).
    """
    from gyrodiag.dtg.decision import feature_vector, median_feature

    if not (isinstance(window_s, (int, float)) and math.isfinite(window_s) and window_s >= 0):
        raise ValueError(f"window_s must be a finite number >= 0 s, got {window_s!r}")
    if result.error is not None:
        raise ValueError(f"training run {result.scenario!r} did not complete: "
                         f"{result.error.strip().splitlines()[0]}")
    if len(result.time) == 0:
        raise ValueError(f"training run {result.scenario!r} recorded no samples")
    eta = np.stack([np.stack([result.signal(f"{diagnoser}.dtg.eta_{a}[{i}]")
                              for i in range(1, N_THETA + 1)], axis=1) for a in _AXES],
                   axis=1)  # (n, axis, θ)
    alarm = result.signal(f"{diagnoser}.dtg.alarm") > 0.5
    if not alarm[-1]:
        raise ValueError(
            f"training run {result.scenario!r} does not end in DTG alarm "
            f"({diagnoser}.dtg.alarm = 0 at t = {result.time[-1]:g} s): its feature would "
            "be the nominal one; make the fault larger or the run longer")
    t_end = result.time[-1]
    rows = np.flatnonzero((result.time >= t_end - window_s - 1e-9) & alarm)
    features, axes = [], set()
    for k in rows:
        per_axis = [feature_vector(eta[k, a]) for a in range(len(_AXES))]
        worst = int(np.argmax([np.abs(f).sum() for f in per_axis]))
        features.append(per_axis[worst])
        axes.add(_AXES[worst])
    feature = median_feature(features)
    return RunFeature(result.scenario, signature, feature, ",".join(sorted(axes)),
                      eta[-1].copy(), len(rows))


@dataclass
class SignatureLibrary:
    """Learned signatures, in code order, with the runs they came from."""

    signatures: dict[str, NDArray[np.int64]]
    codes: dict[str, int]
    runs: list[RunFeature] = field(default_factory=list)
    window_s: float = DEFAULT_WINDOW_S

    def distances(self) -> NDArray[np.float64]:
        """Eq. 7 distances between the signatures, (n, n), library order."""
        lib = np.array(list(self.signatures.values()), dtype=float)
        return np.mean(np.abs(lib[:, None, :] - lib[None, :, :]), axis=2)

    def classify(self, feature: NDArray[np.int64]) -> tuple[str, dict[str, float]]:
        """Nearest signature of ``feature`` (ties: the lower code) and all distances."""
        d = {n: float(np.mean(np.abs(np.asarray(c, float) - feature)))
             for n, c in self.signatures.items()}
        return min(d, key=lambda n: (d[n], self.codes[n])), d

    def to_json(self) -> dict[str, Any]:
        """The file content: ``signatures`` first (read by the Diagnoser), then the record."""
        names = list(self.signatures)
        dist = self.distances()
        return {
            "signatures": {n: [int(v) for v in c] for n, c in self.signatures.items()},
            "codes": dict(self.codes),
            "method": {
                "feature": "C = round(log10 eta) of the axis with the larger sum |C_i|, "
                           "median over the alarm samples of the final window of each run",
                "window_s": self.window_s,
                "combine": "element-wise median over the runs of a class, rounded half away "
                           "from zero",
            },
            "distances": {a: {b: round(float(dist[i, j]), 6) for j, b in enumerate(names)}
                          for i, a in enumerate(names)},
            "runs": [
                {"scenario": r.scenario, "signature": r.signature,
                 "feature": [int(v) for v in r.feature], "axes": r.axes,
                 "samples": r.n_samples,
                 "eta_end": {a: [float(v) for v in r.eta_end[i]] for i, a in enumerate(_AXES)}}
                for r in self.runs
            ],
        }

    def write(self, path: Path) -> None:
        """Write :meth:`to_json` to ``path`` (folders created)."""
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(self.to_json(), indent=2) + "\n", encoding="utf-8")


def check_training_scenarios(scenarios: Sequence[Scenario]) -> dict[str, int]:
    """Check the ``[training]`` tables of a training set; returns class → code.

    Raises
    ------
    ScenarioError
        A scenario without ``[training]``, one that does not record the signals the
        learning reads, a class with two codes, a code used by two classes, or codes
        that are not 1..n.
    """
    if not scenarios:
        raise ValueError("no training scenarios given")
    codes: dict[str, int] = {}
    owner: dict[int, str] = {}
    kinds = set()
    for s in scenarios:
        tr = s.training
        if tr is None:
            raise ScenarioError(s.source, [("training", "missing [training] table: "
                                                        "learn-signatures needs the fault class "
                                                        "(signature) and its code")])
        kinds.add(tr.classifier)
        if len(kinds) > 1:
            raise ScenarioError(s.source, [("training.classifier",
                                            "a training set is either 'paper' or 'pattern', "
                                            "not both")])
        if tr.diagnoser not in s.fmus:
            raise ScenarioError(s.source, [("training.diagnoser",
                                            f"unknown instance {tr.diagnoser!r}")])
        needed = (signal_names(tr.diagnoser) if tr.classifier == "paper"
                  else pattern_signal_names(tr.diagnoser))
        if tr.classifier == "pattern":
            cls = s.fmus[tr.diagnoser].parameters.get("dtg.classifier", "pattern")
            if cls != "pattern":
                raise ScenarioError(s.source, [(
                    f"fmus.{tr.diagnoser}.parameters.dtg.classifier",
                    "pattern training needs the Diagnoser's pattern classifier (its "
                    "statistics are what is learned)")])
            if tr.type == "nominal":
                if s.record.variables is not None:
                    missing = [n for n in needed if n not in s.record.variables]
                    if missing:
                        raise ScenarioError(s.source, [(
                            "record.variables", f"must include {', '.join(missing)}")])
                continue
        if s.record.variables is not None:
            missing = [n for n in needed if n not in s.record.variables]
            if missing:
                raise ScenarioError(s.source, [("record.variables",
                                                f"must include {', '.join(missing)} (the "
                                                "learning reads them)")])
        if codes.get(tr.signature, tr.code) != tr.code:
            raise ScenarioError(s.source, [("training.code",
                                            f"class {tr.signature!r} has code {tr.code} here "
                                            f"but {codes[tr.signature]} in another scenario")])
        if owner.get(tr.code, tr.signature) != tr.signature:
            raise ScenarioError(s.source, [("training.code",
                                            f"code {tr.code} is also used by class "
                                            f"{owner[tr.code]!r}")])
        codes[tr.signature] = tr.code
        owner[tr.code] = tr.signature
    expected = list(range(1, len(codes) + 1))
    if sorted(codes.values()) != expected:
        raise ScenarioError(scenarios[0].source, [
            ("training.code", f"codes of the classes must be 1..{len(codes)} without gaps "
                              f"(the Diagnoser numbers signatures by position), got "
                              f"{dict(sorted(codes.items(), key=lambda kv: kv[1]))}")])
    return dict(sorted(codes.items(), key=lambda kv: kv[1]))


def learn_signatures(scenarios: Sequence[Scenario], results: Sequence[RunResult],
                     window_s: float = DEFAULT_WINDOW_S) -> SignatureLibrary:
    """Learn the library from training scenarios and their runs (same order).

    Raises
    ------
    ScenarioError, ValueError, KeyError
        See :func:`check_training_scenarios` and :func:`run_feature`.
    """
    from gyrodiag.dtg.decision import median_feature

    if len(scenarios) != len(results):
        raise ValueError(f"{len(scenarios)} scenarios but {len(results)} runs")
    codes = check_training_scenarios(scenarios)
    runs = []
    for s, r in zip(scenarios, results, strict=True):
        assert s.training is not None
        runs.append(run_feature(r, s.training.diagnoser, s.training.signature, window_s))
    signatures = {}
    for name in codes:
        signatures[name] = median_feature([r.feature for r in runs if r.signature == name])
    return SignatureLibrary(signatures, codes, runs, window_s)


def is_pattern_training(scenarios: Sequence[Scenario]) -> bool:
    """The training set is for the pattern classifier (checked to be uniform by
    :func:`check_training_scenarios`)."""
    return bool(scenarios) and all(s.training is not None
                                   and s.training.classifier == "pattern" for s in scenarios)


def learn_pattern_library(scenarios: Sequence[Scenario], results: Sequence[RunResult]
                          ) -> tuple[Any, dict[str, Any]]:
    """Learn the pattern library of a pattern training set (same order as ``results``).

    The channel's sampling and window settings are read from the training Diagnosers'
    parameters (they must agree). Returns the library and the file content
    ``{"patterns": ..., "codes": ..., "training": ...}``.

    Raises
    ------
    ScenarioError, ValueError, KeyError
        See :func:`check_training_scenarios` and
        :func:`gyrodiag.dtg.learning.learn_patterns`.
    """
    from gyrodiag.dtg.learning import learn_patterns
    from gyrodiag_harness.campaigns.pattern_learning import pattern_run

    if len(scenarios) != len(results):
        raise ValueError(f"{len(scenarios)} scenarios but {len(results)} runs")
    codes = check_training_scenarios(scenarios)
    settings = set()
    for s in scenarios:
        assert s.training is not None
        p = s.fmus[s.training.diagnoser].parameters
        settings.add((float(p.get("sample_period_s", 1e-3)), float(p.get("dtg.window_s", 0.5)),
                      float(p.get("dtg.long_window_s", 2.0))))
    if len(settings) != 1:
        raise ValueError("the training Diagnosers differ in sample_period_s / dtg.window_s / "
                         f"dtg.long_window_s: {sorted(settings)}; learn one library per "
                         "setting")
    period, short_s, long_s = settings.pop()
    block_s = max(1, round(0.025 / period)) * period  # gyrodiag.dtg.channel.BLOCK_S
    runs = [pattern_run(s, r) for s, r in zip(scenarios, results, strict=True)]
    lib, record = learn_patterns(runs, codes, sample_period_s=period, block_s=block_s,
                                 short_window_s=short_s, long_window_s=long_s)
    content = {"patterns": lib.to_dict(), "codes": codes, "training": record}
    return lib, content
