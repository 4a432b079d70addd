"""The interface of the DTG channel's fault classifiers (strategies).

:class:`~gyrodiag.dtg.channel.DTGChannel` identifies θ on both axes, learns the nominal
reference and runs the ratio band; what an alarm is and how it is classified is left to
one classifier object:

* :class:`~gyrodiag.dtg.paper_rule.PaperRule` (``classifier="paper"``): the paper's
  ratio band, alarms classified by the nearest decade signature;
* :class:`~gyrodiag.dtg.pattern_rule.PatternRule` (``classifier="pattern"``): residual
  tests against the frozen reference and the learned pattern library.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from .outputs import DTGDiagnosis

if TYPE_CHECKING:
    from .channel import DTGChannel
    from .reference import NominalReference, ReferenceLearner

__all__ = ["ChannelClassifier"]

#: A ratio decision's confirm hook: True when the out-of-band ratios ``eta`` of one axis
#: count as a violation.
Confirm = Callable[[list[float]], bool] | None


class ChannelClassifier(ABC):
    """Alarm and classification rule of a :class:`~gyrodiag.dtg.channel.DTGChannel`.

    Parameters
    ----------
    host : DTGChannel
        The channel it classifies for: read for its θ, θ0, reference, block sizes and
        block buffers (the pattern rule also rolls its estimators back and refines its
        θ0).
    """

    #: The ``DTGChannelConfig.classifier`` value it implements.
    kind: str = ""
    #: Reference status reported when the learning window gave no usable reference.
    failed_status: int = 0

    def __init__(self, host: DTGChannel) -> None:
        self.host = host

    @abstractmethod
    def reset(self) -> None:
        """Return to the state right after construction."""

    def learn(self, t: float, theta: NDArray[np.float64]) -> NDArray[np.float64] | None:
        """Learn θ0 from θ (shape (2, 5)) at time ``t`` (s) while none is known; the θ0
        learned once the window has ended, else None."""
        return None

    @abstractmethod
    def reference_failed(self) -> bool:
        """True once learning has ended without a usable θ0."""

    def holds_physical_test(self) -> bool:
        """The physical-parameter test must pause (another test in alarm, a
        manoeuvre); none by default."""
        return False

    def confirm_hooks(self) -> tuple[Confirm, Confirm]:
        """The x and y ratio decisions' confirm hooks for this sample (None: the band
        alone)."""
        return None, None

    def on_reference(self, reference: NominalReference, learner: ReferenceLearner) -> None:
        """Take the reference checked at the end of the learning window (nothing by
        default)."""
        return None

    def end_block(self, theta: tuple[float, ...]) -> bool:
        """A runtime reference block of the host has been collected (its buffers still
        hold it; ``theta`` the estimate of both axes, (10,)); True when the block-rate
        outputs are due."""
        return False

    @abstractmethod
    def decide(self, t: float, eta: Sequence[list[float]], band_alarm: bool,
               block_done: bool) -> tuple[bool, int, NDArray[np.int64], DTGDiagnosis]:
        """Alarm, fault code, feature vector and diagnosis of a sample at time ``t`` (s)
        from the ratios ``eta`` of both axes and the band's alarm."""

    @abstractmethod
    def class_name(self, code: int) -> str:
        """Name of a ``fault_code``: "" for 0, "unknown" for no class."""

    @abstractmethod
    def get_state(self) -> dict[str, Any]:
        """Internal state (the ``"classifier"`` part of the channel's state)."""

    @abstractmethod
    def set_state(self, state: dict[str, Any],
                  reference: NominalReference | None) -> None:
        """Restore :meth:`get_state`; ``reference`` is the host's restored reference."""


def names_class(names: Sequence[str], code: int) -> str:
    """Name of ``code`` in the 1-based class list ``names`` ("" for 0, else "unknown")."""
    if code == 0:
        return ""
    return names[code - 1] if 0 < code <= len(names) else "unknown"
