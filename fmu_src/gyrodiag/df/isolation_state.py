"""Saved state of :class:`~gyrodiag.df.isolation.SensorFaultIsolator`: a flat dict of its
observers, evaluators and decision sums, and the restore that rolls back on a bad state.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from gyrodiag.common._validation import check_finite_array
from gyrodiag.df.filter import as_state_int

if TYPE_CHECKING:
    from gyrodiag.df.isolation import SensorFaultIsolator

__all__ = ["isolator_state", "restore_isolator_state"]


def isolator_state(iso: SensorFaultIsolator) -> dict[str, Any]:
    """Flat dict of numpy arrays / ints with every dynamic state (deep copies)."""
    state: dict[str, Any] = {}
    for key, val in iso._main.get_state().items():
        state[f"main.{key}"] = val
    for j, b in enumerate(iso._bank):
        for key, val in b.observer.get_state().items():
            state[f"bank{j}.{key}"] = val
    if iso._main_eval is not None and iso._bank_eval is not None:
        for key, val in iso._main_eval.get_state().items():
            state[f"main_eval.{key}"] = val
        for j, ev in enumerate(iso._bank_eval):
            for key, val in ev.get_state().items():
                state[f"bank_eval{j}.{key}"] = val
    state.update(
        detected=int(iso._detected),
        isolated=int(iso._isolated),
        onset=int(iso._onset),
        candidate=int(iso._candidate),
        candidate_count=int(iso._candidate_count),
        sums=iso._sums.copy(),
        ref=iso._ref.copy(),
        energy=iso._energy.copy(),
        energy_n=int(iso._energy_n),
        energy_baseline=iso._baseline.copy(),
    )
    return state


def restore_isolator_state(iso: SensorFaultIsolator, state: dict[str, Any]) -> None:
    """Restore a state produced by :func:`isolator_state` of an identically built isolator."""
    if not isinstance(state, dict):
        raise TypeError(f"state must be a dict, got {type(state).__name__}")

    snapshot = isolator_state(iso)
    try:
        _apply_state(iso, state)
    except Exception:
        # Leave the object as it was rather than half restored.
        _apply_state(iso, snapshot)
        raise


def _apply_state(iso: SensorFaultIsolator, state: dict[str, Any]) -> None:
    def sub(prefix: str) -> dict[str, Any]:
        return {k[len(prefix):]: v for k, v in state.items() if k.startswith(prefix)}

    try:
        iso._main.set_state(sub("main."))
        for j, b in enumerate(iso._bank):
            b.observer.set_state(sub(f"bank{j}."))
        if iso._main_eval is not None and iso._bank_eval is not None:
            iso._main_eval.set_state(sub("main_eval."))
            for j, ev in enumerate(iso._bank_eval):
                ev.set_state(sub(f"bank_eval{j}."))
        sums = check_finite_array("state['sums']", state["sums"], shape=(iso._m, 6))
        ref = check_finite_array("state['ref']", state["ref"], shape=(iso._m, 2))
        iso._detected = bool(as_state_int("state['detected']", state["detected"]))
        iso._isolated = as_state_int("state['isolated']", state["isolated"], minimum=-2)
        iso._onset = as_state_int("state['onset']", state["onset"], minimum=-1)
        iso._candidate = as_state_int("state['candidate']", state["candidate"], minimum=-1)
        iso._candidate_count = as_state_int("state['candidate_count']",
                                          state["candidate_count"])
        if "energy" in state or "energy_n" in state:
            energy = check_finite_array("state['energy']", state["energy"],
                                        shape=(iso._m,))
            energy_n = as_state_int("state['energy_n']", state["energy_n"])
        else:  # a state of a version before the energy isolation: nothing summed yet
            energy, energy_n = np.zeros(iso._m), 0
        if "energy_baseline" in state:
            baseline = check_finite_array("state['energy_baseline']",
                                          state["energy_baseline"], shape=(iso._m,))
        else:  # a state of a version before the baseline: the calibration's
            baseline = np.ones(iso._m)
    except KeyError as exc:
        raise ValueError(f"state is missing key {exc}") from None
    iso._sums = sums.copy()
    iso._ref = ref.copy()
    iso._energy, iso._energy_n = energy.copy(), energy_n
    iso._baseline = baseline.copy()
