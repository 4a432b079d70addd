"""Isolation of the sequential diagnosis: the bank of hypothesis generators and the
decision among the hypotheses they leave consistent.

Hypothesis S ("the faulty sensors are S", one sensor or two) has generator ``¬S``, which
does not use the sensors of S and so cannot see their faults
(:mod:`gyrodiag.df.generators`). S is consistent while no CUSUM chart of ``¬S`` has
alarmed since the bank started; the diagnosis is the only consistent single sensor,
else the only consistent pair, else "multiple" — never a guess among several
consistent hypotheses.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..common._validation import check_finite_array
from ..common.cusum import CusumBank
from .generators import ObserverStack, ResidualGenerator

__all__ = ["HypothesisBank", "hypotheses_of"]

_FloatArray = NDArray[np.float64]


def hypotheses_of(n_sensors: int, max_faults: int) -> list[tuple[int, ...]]:
    """Every single sensor, then (``max_faults`` 2) every pair, in this order."""
    hyps: list[tuple[int, ...]] = [(i,) for i in range(n_sensors)]
    if max_faults >= 2:
        hyps += list(itertools.combinations(range(n_sensors), 2))
    return hyps


class HypothesisBank:
    """The hypothesis generators run as one system, their CUSUM charts, and which
    hypotheses they have rejected (module notes).

    Parameters
    ----------
    generators : list of ResidualGenerator
        Generator ``¬S`` of each hypothesis S, in the order of :func:`hypotheses_of`.
    n_inputs, n_sensors : int
        p and m of the plant.
    new_cusum : callable
        ``new_cusum(n_channels)``: a CUSUM bank with the diagnoser's thresholds.

    Attributes
    ----------
    stack : ObserverStack
    cusum : CusumBank
    inconsistent : ndarray of bool
        Per hypothesis: a chart of its generator has alarmed since :meth:`start`.
    gen_of_channel : ndarray of int
        Hypothesis of each output channel of ``stack``.
    """

    def __init__(self, generators: list[ResidualGenerator], n_inputs: int, n_sensors: int,
                 new_cusum: Callable[[int], CusumBank]) -> None:
        self.m = n_sensors
        self.stack = ObserverStack(generators, n_inputs, n_sensors)
        self._new_cusum = new_cusum
        self.cusum = new_cusum(self.stack.n_out)
        self.gen_of_channel = np.concatenate([
            np.full(g.n_channels, k) for k, g in enumerate(generators)])
        self.inconsistent = np.zeros(len(generators), dtype=bool)
        self._verdict: tuple[int, str] | None = None

    def reset(self) -> None:
        """States zero, charts cleared, every hypothesis consistent."""
        self.stack.reset()
        self.cusum.reset()
        self.inconsistent = np.zeros(len(self.stack.generators), dtype=bool)
        self._verdict = None

    def start(self, xhat: _FloatArray, disturbance: _FloatArray, sample: int) -> None:
        """Every observer from the main filter's estimate ``xhat`` (and its whitening
        state ``disturbance``, see :meth:`ObserverStack.set_observer_state`) before
        ``sample``; charts cleared from it, every hypothesis consistent."""
        self.stack.reset()
        for g in range(len(self.stack.generators)):
            self.stack.set_observer_state(g, xhat, disturbance)
        self.cusum.reset(sample)
        self.inconsistent[:] = False
        self._verdict = None

    def step(self, w: _FloatArray) -> None:
        """Run the generators and their charts on ``w = [u; y]``."""
        zb, _ = self.stack.update(w)
        cusum = self.cusum
        # a channel alarming now that did not before raised a chart now: without a
        # newly raised chart every alarm is one already marked
        if cusum.update(zb) and cusum.newly_raised.any():
            self.inconsistent[self.gen_of_channel[cusum.alarms]] = True
            self._verdict = None

    def verdict(self) -> tuple[int, str]:
        """(the hypothesis isolated or −1, status): "single", "pair", "multiple" (no
        hypothesis left) or "not isolated" (several left)."""
        if self._verdict is None:  # else: no hypothesis went inconsistent since
            self._verdict = self._judge()
        return self._verdict

    def _judge(self) -> tuple[int, str]:
        consistent = ~self.inconsistent
        singles = np.flatnonzero(consistent[:self.m])
        gen = -1
        if singles.size == 1:
            gen, status = int(singles[0]), "single"
        elif singles.size == 0:
            pairs = np.flatnonzero(consistent[self.m:]) + self.m
            if pairs.size == 1:
                gen, status = int(pairs[0]), "pair"
            else:
                status = "multiple"
        else:
            status = "not isolated"
        return gen, status

    # ------------------------------------------------------------------------ state

    def get_state(self) -> dict[str, Any]:
        """The bank's part of the diagnoser's state (deep copies)."""
        return {
            "bank_x": self.stack.x.copy(),
            "bank_scale": [s.copy() for s in self.stack.channel_scale],
            "bank_cusum": self.cusum.get_state(),
            "inconsistent": self.inconsistent.astype(float),
        }

    def check_state(self, state: dict[str, Any]) -> dict[str, Any]:
        """The bank's part of a saved state, checked (ValueError; KeyError for a missing
        key)."""
        n_gen = len(self.stack.generators)
        got: dict[str, Any] = {
            "bank_scale": [check_finite_array("state['bank_scale']", s, shape=(g.n_channels,))
                           for s, g in zip(state["bank_scale"], self.stack.generators,
                                           strict=True)],
            "bank_x": check_finite_array("state['bank_x']", state["bank_x"],
                                         shape=(self.stack.n_state,)),
            "inconsistent": check_finite_array("state['inconsistent']", state["inconsistent"],
                                               shape=(n_gen,)) != 0.0,
        }
        got["bank_cusum"] = self._new_cusum(self.stack.n_out)
        got["bank_cusum"].set_state(state["bank_cusum"])
        return got

    def set_state(self, got: dict[str, Any]) -> None:
        """Install a state :meth:`check_state` returned."""
        self.stack.set_channel_scale(got["bank_scale"])
        self.stack.x = got["bank_x"]
        self.cusum = got["bank_cusum"]
        self.inconsistent = got["inconsistent"]
        self._verdict = None
