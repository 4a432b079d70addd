"""Reading the DTG pattern training runs for the library learning (``learn-signatures``).

Training scenarios of the pattern classifier carry a ``[training]`` table with
``classifier = "pattern"``::

    [training]
    classifier = "pattern"
    signature = "uty_step"   # class name; classes are numbered by `code`
    code = 2
    type = "step"            # step | drift | noise | loss | spin | torquer | nominal
    signal = "Uty"           # Utx | Uty | Ux | Uy (signal faults only)
    fault = "uty_step"       # the [[faults]] entry giving the size and the onset
    diagnoser = "diag"

The fault's size is its ``magnitude`` (step V, ramp V/s), ``noise_std`` (noise, and the
noise left by a signal loss, V; a ``failure`` is a loss with 0 V) or the physical
parameter's ``value`` (spin, torquer: a ratio). ``nominal`` runs only feed the noise
model and the prior.

The learning itself (numpy only) is :func:`gyrodiag.dtg.learning.learn_patterns`;
this module reads the training runs for it.
"""

from __future__ import annotations

import math

import numpy as np

from gyrodiag.dtg.learning import N_CH, N_THETA, PatternRun
from gyrodiag_harness.cosim.results import RunResult
from gyrodiag_harness.cosim.scenario import InjectorFault, PhysicalFault, Scenario, ScenarioError

__all__ = [
    "pattern_run",
    "pattern_signal_names",
]


def pattern_signal_names(diagnoser: str) -> list[str]:
    """Outputs a pattern training run must record."""
    d = f"{diagnoser}.dtg"
    names = [f"{d}.alarm", f"{d}.residual_alarm", f"{d}.level_growth", f"{d}.stat_window_s",
             f"{d}.reference_status"]
    names += [f"{d}.level[{i}]" for i in range(1, N_CH + 1)]
    names += [f"{d}.log_var_ratio[{i}]" for i in range(1, N_CH + 1)]
    names += [f"{d}.eta_{a}[{i}]" for a in "xy" for i in range(1, N_THETA + 1)]
    names += [f"{d}.ref_theta0[{i}]" for i in range(1, N_THETA + 1)]
    for key in ("ref_mean", "ref_block_std", "ref_var_short", "ref_var_long"):
        names += [f"{d}.{key}[{i}]" for i in range(1, N_CH + 1)]
    return names


def _fault_size(scenario: Scenario, fault_name: str | None, typ: str
                ) -> tuple[float, float | None]:
    """(size, onset) of the training fault."""
    if typ == "nominal":
        return math.nan, None
    faults = scenario.faults
    if fault_name is None:
        if len(faults) != 1:
            raise ScenarioError(scenario.source, [(
                "training.fault", f"name the fault that gives the size ({len(faults)} "
                                  "faults in the scenario)")])
        fault = faults[0]
    else:
        match = [f for f in faults if f.name == fault_name]
        if not match:
            raise ScenarioError(scenario.source, [(
                "training.fault", f"no [[faults]] entry named {fault_name!r}")])
        fault = match[0]
    if isinstance(fault, InjectorFault):
        if fault.type in ("step", "ramp"):
            size = float(fault.magnitude)  # type: ignore[arg-type]
        elif fault.type in ("noise", "signal_loss"):
            size = float(fault.noise_std)  # type: ignore[arg-type]
        elif fault.type == "failure":
            size = 0.0
        else:
            raise ScenarioError(scenario.source, [(
                "training.fault", f"fault type {fault.type!r} has no size the pattern "
                                  "learning knows (step, ramp, noise, signal_loss, failure)")])
    elif isinstance(fault, PhysicalFault):
        size = float(fault.value)
        if not size > 0:
            raise ScenarioError(scenario.source, [(
                "training.fault", f"a physical fault's value is a ratio > 0, got {size}")])
    else:  # pragma: no cover - the scenario model has no other fault kinds
        raise ScenarioError(scenario.source, [("training.fault", "unsupported fault kind")])
    return size, float(fault.start_s)


def pattern_run(scenario: Scenario, result: RunResult) -> PatternRun:
    """Read one training run (its scenario's ``[training]`` table and recorded outputs).

    Raises
    ------
    ValueError
        If the run failed or recorded nothing.
    KeyError
        If a needed output was not recorded.
    ScenarioError
        If the training table does not fit the scenario.
    """
    tr = scenario.training
    assert tr is not None
    if result.error is not None:
        raise ValueError(f"training run {result.scenario!r} did not complete: "
                         f"{result.error.strip().splitlines()[0]}")
    if len(result.time) == 0:
        raise ValueError(f"training run {result.scenario!r} recorded no samples")
    d = f"{tr.diagnoser}.dtg"
    typ = tr.type or ""
    size, onset = _fault_size(scenario, tr.fault, typ)
    sig = result.signal
    params = scenario.fmus[tr.diagnoser].parameters
    learn_end = float(params.get("dtg.learn_end_s", 5.0))  # the FMU's default
    ref = {
        "theta0": np.array([sig(f"{d}.ref_theta0[{i}]")[-1] for i in range(1, N_THETA + 1)]),
        "status": int(np.rint(sig(f"{d}.reference_status")[-1])),
    }
    for key, out in (("mean", "ref_mean"), ("block_std", "ref_block_std"),
                     ("var_short", "ref_var_short"), ("var_long", "ref_var_long")):
        ref[key] = np.array([sig(f"{d}.{out}[{i}]")[-1] for i in range(1, N_CH + 1)])
    return PatternRun(
        scenario=scenario.name, name=tr.signature, type=typ, signal=tr.signal, size=size,
        onset_s=onset, learn_end_s=learn_end, time=np.asarray(result.time, dtype=float),
        alarm=sig(f"{d}.alarm") > 0.5, residual_alarm=sig(f"{d}.residual_alarm") > 0.5,
        level=np.column_stack([sig(f"{d}.level[{i}]") for i in range(1, N_CH + 1)]),
        log_var=np.column_stack([sig(f"{d}.log_var_ratio[{i}]") for i in range(1, N_CH + 1)]),
        growth=np.asarray(sig(f"{d}.level_growth"), dtype=float),
        window_s=np.asarray(sig(f"{d}.stat_window_s"), dtype=float),
        eta=np.column_stack([sig(f"{d}.eta_{a}[{i}]") for a in "xy"
                             for i in range(1, N_THETA + 1)]),
        reference=ref,
    )
