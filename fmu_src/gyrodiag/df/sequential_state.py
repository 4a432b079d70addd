"""Saved state of :class:`~gyrodiag.df.sequential_diagnosis.SequentialDiagnoser`: its
assembly from the diagnoser and its parts, and the checked restore.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from ..common._validation import check_finite_array

if TYPE_CHECKING:
    from .sequential_diagnosis import SequentialDiagnoser

__all__ = ["diagnoser_state", "restore_diagnoser_state"]

_FloatArray = NDArray[np.float64]

#: Status codes kept in the saved state.
_STATUS = ("none", "not isolated", "single", "pair", "multiple")
#: Keys of the saved state, in the order :meth:`SequentialDiagnoser.get_state` has
#: always given them (its parts own some of them).
_STATE_KEYS = (
    "main_x", "main_scale", "bank_x", "bank_scale", "main_cusum", "bank_cusum", "presence",
    "count", "hist_w", "hist_x", "hist_z", "hist_d", "in_episode", "episodes", "wait_clear",
    "bank_active", "last_end", "change", "record_episodes", "inconsistent", "sig", "gram_c",
    "gz_c", "zz_c", "n_rec", "n_after", "g_last", "z_last", "y_prev", "status", "isolated",
    "iso_gen", "model_cols", "theta", "previous_isolated", "previous_types",
    "previous_mags", "presence_mode", "presence_zero", "presence_start", "hist_c", "hist_p",
    "presence_grew", "types", "mags", "mag_valid",
)
#: Integer entries of the saved state the diagnoser itself owns.
_INT_KEYS = ("count", "in_episode", "episodes", "bank_active", "last_end", "change",
             "record_episodes", "wait_clear")


def diagnoser_state(d: SequentialDiagnoser) -> dict[str, Any]:
    """Every piece of dynamic state (deep copies)."""
    own = {
        "main_x": d.main.x.copy(),
        "main_scale": [s.copy() for s in d.main.channel_scale],
        "main_cusum": d.main_cusum.get_state(),
        "count": int(d._count),
        "hist_w": d._hist_w.copy(), "hist_x": d._hist_x.copy(),
        "hist_z": d._hist_z.copy(), "hist_d": d._hist_d.copy(),
        "in_episode": int(d._in_episode), "episodes": int(d._episodes),
        "wait_clear": int(d._wait_clear),
        "bank_active": int(d._bank_active), "last_end": int(d._last_end),
        "change": int(d._change), "record_episodes": int(d._record_episodes),
        "status": _STATUS.index(d._status), "isolated": list(d._isolated),
        "iso_gen": int(d._iso_gen),
        **d.hypothesis_bank.get_state(), **d.signatures.get_state(),
        **d.typer.get_state(), **d.presence.get_state(),
    }
    return {key: own[key] for key in _STATE_KEYS}


def restore_diagnoser_state(d: SequentialDiagnoser, state: dict[str, Any]) -> None:
    """Restore :func:`diagnoser_state` output of an identically built diagnoser; checked
    first, so a bad state leaves it untouched."""
    try:
        got = _check_state(d, state)
        parts = [(part, part.check_state(state)) for part in (
            d.hypothesis_bank, d.typer, d.presence)]
        signatures = d.signatures.check_state(state, d.main.n_state)
    except KeyError as exc:
        raise ValueError(f"state is missing key {exc}") from None
    d.main.set_channel_scale(got["main_scale"])
    d.main.x = got["main_x"]
    d.main_cusum = got["main_cusum"]
    for part, checked in parts:
        part.set_state(checked)
    d._install_signature_matrices()
    d.signatures.set_state(signatures)
    d._hist_w, d._hist_x, d._hist_z = got["hist_w"], got["hist_x"], got["hist_z"]
    d._hist_d = got["hist_d"]
    d._out_types = d.typer.types.copy()
    d._out_mags = d.typer.mags.copy()
    d._out_valid = d.typer.mag_valid.copy()
    d._status, d._isolated = _STATUS[got["status"]], got["isolated"]
    d._iso_gen = got["iso_gen"]
    ints = got["ints"]
    d._count = ints["count"]
    d._in_episode = bool(ints["in_episode"])
    d._wait_clear = bool(ints["wait_clear"])
    d._episodes = ints["episodes"]
    d._bank_active = bool(ints["bank_active"])
    d._last_end, d._change = ints["last_end"], ints["change"]
    d._record_episodes = ints["record_episodes"]


def _check_state(d: SequentialDiagnoser, state: dict[str, Any]) -> dict[str, Any]:
    """The diagnoser's own part of a saved state, checked (ValueError; KeyError for
    a missing key)."""
    n_gen = len(d.bank_generators)

    def arr(key: str, shape: tuple[int, ...]) -> _FloatArray:
        return check_finite_array(f"state[{key!r}]", state[key], shape=shape)

    got: dict[str, Any] = {
        "main_scale": [check_finite_array("state['main_scale']", s, shape=(g.n_channels,))
                       for s, g in zip(state["main_scale"], d.main.generators,
                                       strict=True)],
        "main_x": arr("main_x", (d.main.n_state,)),
        "hist_w": arr("hist_w", d._hist_w.shape),
        "hist_x": arr("hist_x", d._hist_x.shape),
        "hist_z": arr("hist_z", d._hist_z.shape),
        "hist_d": (arr("hist_d", d._hist_d.shape) if "hist_d" in state
                   else np.zeros(d._hist_d.shape)),
    }
    got["status"] = int(state["status"])
    if not 0 <= got["status"] < len(_STATUS):
        raise ValueError(f"state['status'] must be in [0, {len(_STATUS)})")
    got["iso_gen"] = int(state["iso_gen"])
    if not -1 <= got["iso_gen"] < n_gen:
        raise ValueError(f"state['iso_gen'] must be in [-1, {n_gen})")
    got["isolated"] = tuple(int(i) for i in state["isolated"])
    got["main_cusum"] = d._new_cusum(d.m)
    got["main_cusum"].set_state(state["main_cusum"])
    got["ints"] = {key: int(state[key]) for key in _INT_KEYS}
    return got
