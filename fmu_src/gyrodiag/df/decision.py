"""The interface of the detection-filter channel's decision rules.

A rule turns the channel's aligned samples into its outputs. :class:`DFChannel
<gyrodiag.df.channel.DFChannel>` streams, aligns, equalises and keeps the calibration
window; it installs the rule its config names when the window
ends and hands it every sample after. Rules: :class:`~gyrodiag.df.paper_rule.PaperRule`,
:class:`~gyrodiag.df.sequential_rule.SequentialRule`.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from .calibration import CalibrationWindow, DFDesign
from .channel_config import DFChannelConfig
from .channel_output import DFChannelOutput

__all__ = ["DFDecision"]

#: Keys of :meth:`DFChannel.get_state <gyrodiag.df.channel.DFChannel.get_state>` that a
#: rule's :meth:`DFDecision.get_state` fills, in the state's order.
RULE_STATE_KEYS = ("noise_std", "gust_note", "noise_var", "engine", "thresholds",
                   "threshold_stats")


class DFDecision(ABC):
    """A decision rule of the channel: installed from the calibration window (or from
    the configured thresholds / noise), then fed one aligned sample at a time."""

    #: The rule's name in :data:`~gyrodiag.df.channel_config.DECISIONS`.
    name: ClassVar[str]
    #: :meth:`decide_stacked` is available (the channel's plain-float fast path).
    stacked: ClassVar[bool] = False

    def __init__(self, design: DFDesign, config: DFChannelConfig) -> None:
        self.design = design
        self.config = config
        self._noise_std: NDArray[np.float64] | None = None
        self.reset()

    def reset(self) -> None:
        """Back to not installed."""
        self.uninstall()

    @abstractmethod
    def uninstall(self) -> None:
        """Drop the engine, noise and thresholds (a state saved while calibrating)."""

    @abstractmethod
    def install(self, window: CalibrationWindow | None) -> None:
        """Build the engine from the aligned window, or with ``None`` from the given
        thresholds / noise (``calibrate_s`` = 0)."""

    @abstractmethod
    def decide(self, u: NDArray[np.float64], y: NDArray[np.float64], delay: int
               ) -> DFChannelOutput:
        """Outputs for one aligned sample; ``delay`` is the alignment in use."""

    def decide_stacked(self, w: NDArray[np.float64], delay: int) -> DFChannelOutput:
        """:meth:`decide` for the sample stacked as (u, y) (when :attr:`stacked`)."""
        p = self.design.p
        return self.decide(w[:p], w[p:], delay)

    @abstractmethod
    def get_state(self) -> dict[str, Any]:
        """The rule's part of the channel state (:data:`RULE_STATE_KEYS`), installed."""

    @abstractmethod
    def set_state(self, state: dict[str, Any], has_window: bool) -> None:
        """Rebuild the engine from a (migrated) channel state saved after calibration
        and restore it; ``has_window``: the channel calibrates on a window."""

    @property
    @abstractmethod
    def engine(self) -> Any:
        """The decision object (None until installed)."""

    @property
    def noise_std(self) -> NDArray[np.float64] | None:
        """Sensor noise standard deviations in use (None until installed)."""
        return self._noise_std

    @property
    def thresholds(self) -> list[NDArray[np.float64]] | None:
        """Residual thresholds (the paper rule's; None otherwise)."""
        return None

    @property
    def cusum_thresholds(self) -> tuple[float, float] | None:
        """(mean-CUSUM, variance-CUSUM) thresholds (the sequential rule's; else None)."""
        return None

    @property
    def gust_note(self) -> str:
        """Why the gust model is not in use ("" when it is or none is configured)."""
        return ""

    @property
    def gust_in_use(self) -> bool:
        """The engine models the turbulence."""
        return False

