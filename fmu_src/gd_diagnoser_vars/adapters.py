"""One adapter per channel: the FMU variable values → the library's channel config.

The plain fields come from the tables (:func:`~.spec.config_fields`); what is written
here are the coded parameters (estimator, classifier, case rate, decision rules, grey
model), the files read from the FMU resources, and the rules that tie parameters
together (theta0's learn switch, the noise std's "< 0 on any sensor").
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from gyrodiag.dtg.case_rate import CASE_RATE_SCHEMES
from gyrodiag.dtg.channel import CLASSIFIERS, ESTIMATOR_KINDS, DTGChannelConfig
from gyrodiag.dtg.model import N_THETA
from gyrodiag.dtg.patterns import PatternLibrary, default_library
from gyrodiag.grey import ClassicGreyPredictor, ImprovedGreyPredictor
from gyrodiag.grey.decision import CalibratedSequential, GreyDecision, PaperThreshold

from . import df, dtg, grey
from .spec import config_fields, named_int

if TYPE_CHECKING:  # imported when the channel is built: it needs SciPy (design time)
    from gyrodiag.df.channel import DFChannelConfig

#: The shipped pattern library in the FMU's resources.
DEFAULT_LIBRARY_RESOURCE = "gyrodiag/dtg/default_patterns.json"
#: dtg.case_rate codes (0: the paper's regression, the case at rest).
DTG_CASE_RATE_CODES = (None, *CASE_RATE_SCHEMES)

Values = dict[str, Any]


def _resource_path(text: str, resources: str | None) -> Path:
    """A file parameter's path: relative paths are in the FMU's resources."""
    path = Path(text)
    if not path.is_absolute() and resources:
        path = Path(resources) / path
    return path


# ---------------------------------------------------------------------------- DTG
def dtg_config(values: Values, period: float, resources: str | None,
               unclassified: Callable[[str], None]) -> DTGChannelConfig:
    """The DTG channel's config; ``unclassified`` hears why its alarms will go
    unclassified, as soon as that is known (the shipped library's sample period)."""
    v = values
    kind = int(v["dtg.estimator"])
    if kind not in range(len(ESTIMATOR_KINDS)):
        raise ValueError(f"dtg.estimator must be 0, 1 or 2, got {kind}")
    classifier = str(v["dtg.classifier"]).strip()
    if classifier not in CLASSIFIERS:
        raise ValueError(f"dtg.classifier must be one of {', '.join(CLASSIFIERS)}, got "
                         f"{classifier!r}")
    case_rate = int(v["dtg.case_rate"])
    if case_rate not in range(len(DTG_CASE_RATE_CODES)):
        raise ValueError(f"dtg.case_rate must be 0 (none), 1 (central) or 2 (paper), got "
                         f"{case_rate}")
    signatures, patterns = _dtg_library(v, classifier, period, resources, unclassified)
    fields = config_fields(dtg.PARAMETERS, v, "config")
    if v["dtg.learn_theta0"]:
        fields["theta0"] = None  # learned from the learning window
    return DTGChannelConfig(
        sample_period_s=period, estimator=ESTIMATOR_KINDS[kind], signatures=signatures,
        classifier=classifier,  # type: ignore[arg-type]
        patterns=patterns, case_rate=DTG_CASE_RATE_CODES[case_rate], **fields)


def _dtg_library(v: Values, classifier: str, period: float, resources: str | None,
                 unclassified: Callable[[str], None]
                 ) -> tuple[dict[str, list[float]], PatternLibrary | None]:
    """(decade signatures, pattern library) from dtg.signature_file or the table."""
    path_text = str(v["dtg.signature_file"]).strip()
    n = int(v["dtg.n_signatures"])
    if not 0 <= n <= dtg.MAX_SIGNATURES:
        raise ValueError(f"dtg.n_signatures must be in [0, {dtg.MAX_SIGNATURES}], got {n}")
    if classifier == "pattern" and n > 0 and not path_text:
        raise ValueError(
            f"dtg.n_signatures = {n}: the signature table holds decade signatures of "
            "dtg.classifier = paper; the pattern classifier reads a pattern library "
            "from dtg.signature_file")
    if not path_text:
        table = {
            f"signature_{j}": [float(v[f"dtg.signature[{j},{i}]"])
                               for i in range(1, N_THETA + 1)]
            for j in range(1, n + 1)
        }
        if classifier == "paper":
            return table, None
        return {}, _shipped_patterns(period, resources, unclassified)
    path = _resource_path(path_text, resources)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as exc:
        raise ValueError(f"dtg.signature_file {str(path)!r} cannot be read: {exc}") from None
    if not isinstance(data, dict):
        raise ValueError(f"dtg.signature_file {str(path)!r} must hold a JSON object")
    if classifier == "pattern":
        if "patterns" not in data:
            raise ValueError(
                f"dtg.signature_file {str(path)!r} holds no 'patterns' library (decade "
                "signatures are for dtg.classifier = paper; learn patterns with "
                "python -m gyrodiag_harness learn-signatures on pattern training scenarios)")
        try:
            return {}, PatternLibrary.from_dict(data["patterns"])
        except (ValueError, TypeError) as exc:
            raise ValueError(f"dtg.signature_file {str(path)!r}: {exc}") from None
    sigs = data.get("signatures")
    if not isinstance(sigs, dict) or not sigs:
        raise ValueError(
            f"dtg.signature_file {str(path)!r} must hold a non-empty object "
            "'signatures': {name: [C1, ..., C5]} for dtg.classifier = paper"
            + (" (it holds a pattern library: set dtg.classifier = pattern)"
               if "patterns" in data else "")
        )
    return {str(k): list(s) for k, s in sigs.items()}, None


def _shipped_patterns(period: float, resources: str | None,
                      unclassified: Callable[[str], None]) -> PatternLibrary | None:
    """The shipped pattern library, or None at a sample period it was not learned
    for: the channel then detects and reports class unknown (``unclassified`` hears
    why; the facade warns at the first alarm)."""
    # this instance's copy: another instance's extracted module may be gone by now
    own = Path(resources) / DEFAULT_LIBRARY_RESOURCE if resources else None
    lib = default_library(own if own is not None and own.exists() else None)
    if abs(period - lib.sample_period_s) <= 1e-6 * lib.sample_period_s:
        return lib
    unclassified(
        f"dtg: the shipped pattern library was learned at "
        f"sample_period_s = {lib.sample_period_s:g} s; at {period:g} s DTG faults are "
        "detected but not classified (learn a library at this period: dtg.signature_file)")
    return None


# ---------------------------------------------------------------------------- grey
def grey_predictors(v: Values) -> tuple[Any, list[Any]]:
    """The grey predictor, and the improved model's other residual orders that
    compete on the calibration window (``grey.auto_order``; a learned rule uses
    them, the paper rule does not)."""
    model = int(v["grey.model"])
    window = named_int(v, "grey.window")
    if model == 0:
        evaluation = named_int(v, "grey.classic_evaluation")
        if evaluation not in (0, 1):
            raise ValueError("grey.classic_evaluation must be 0 (careful) or 1 (textbook), "
                             f"got {evaluation}")
        # window 0 stands for None: FMI has no "absent" Integer
        return ClassicGreyPredictor(
            None if window == 0 else window,
            evaluation="textbook" if evaluation == 1 else "careful",
        ), []
    if model != 1:
        raise ValueError(f"grey.model must be 0 (classic) or 1 (improved), got {model}")
    if window == 0:
        raise ValueError("grey.window = 0 (whole record) is only available for the "
                         "classic model (grey.model = 0); the improved model needs "
                         "a moving window >= 4")
    options = config_fields(grey.PARAMETERS, v, "improved")  # a_min, residual_order
    order = options["residual_order"]
    predictor = ImprovedGreyPredictor(window, **options)
    candidates = ([ImprovedGreyPredictor(window, **{**options, "residual_order": o})
                   for o in (1, 0) if o != order] if bool(v["grey.auto_order"]) else [])
    return predictor, candidates


def grey_decision(v: Values) -> GreyDecision:
    """The rule of ``grey.decision`` with its parameters."""
    code = named_int(v, "grey.decision")
    rule = grey.GREY_DECISIONS.get(code)
    if rule is None:
        raise ValueError(f"grey.decision must be 0 (paper), 1 (sequential) or 2 "
                         f"(k-sigma), got {code}")
    if rule is PaperThreshold:
        return PaperThreshold(**config_fields(grey.PARAMETERS, v, "paper"))
    learned = config_fields(grey.PARAMETERS, v, "learned")
    if rule is CalibratedSequential:
        learned.update(config_fields(grey.PARAMETERS, v, "sequential"))
    return rule(**learned)


# ---------------------------------------------------------------------------- detection filter
def df_config(v: Values, period: float, resources: str | None) -> DFChannelConfig:
    """The detection-filter channel's config (imports the channel: SciPy)."""
    from gyrodiag.df.channel import DFChannelConfig, decision_rule

    noise = config_fields(df.PARAMETERS, v, "noise")["noise_std"]
    decision = named_int(v, "df.decision")
    if decision not in (0, 1, df.DF_DECISION_AUTO):
        raise ValueError("df.decision must be 0 (paper), 1 (sequential) or 2 (auto), "
                         f"got {decision}")
    sensor_dynamics = _df_sensor_dynamics(v, period, resources)
    rule = decision_rule(decision, sensor_dynamics is not None)
    fields = config_fields(df.PARAMETERS, v, "config")  # checked before the gust
    return DFChannelConfig(
        sample_period_s=period, decision=rule,
        noise_std=None if np.any(noise < 0) else noise,
        sensor_dynamics=sensor_dynamics, gust=df_gust(v), **fields)


def _df_sensor_dynamics(v: Values, period: float, resources: str | None) -> Any:
    """The :class:`~gyrodiag.df.sensor_dynamics.SensorDynamics` of
    df.sensor_dynamics_file, or None when it is empty."""
    from gyrodiag.df.sensor_dynamics import SensorDynamics

    text = str(v["df.sensor_dynamics_file"]).strip()
    if not text:
        return None
    try:
        return SensorDynamics.from_json(_resource_path(text, resources), period)
    except ValueError as exc:
        raise ValueError(f"df.sensor_dynamics_file: {exc}") from None


def df_gust(v: Values) -> Any:
    """The gust model of df.gust_*, or None when df.gust_sigma_w is 0."""
    from gyrodiag.df.gust import GustModel

    gust = config_fields(df.PARAMETERS, v, "gust")
    if gust["sigma_w"] == 0.0:
        return None
    return GustModel(**gust)
