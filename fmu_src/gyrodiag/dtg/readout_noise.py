"""Which read-out a noise class names: the residual tests confuse a torquer read-out's
noise with the pick-off of the same axis (Ux with Utx, Uy with Uty), but the noise
attenuates θ of a different axis in each (Ux, Uty: x; Uy, Utx: y), and the physical
test's fit over the alarm shows which (docs/methods.md §2). The same fit tells a
read-out's noise from a spin or torquer change, which moves both axes alike."""

from __future__ import annotations

from dataclasses import replace

from .patterns import FAULT_TYPES, SIGNALS, PatternLibrary, PatternResult, signal_bit

__all__ = ["AXIS_Z", "OTHER_AXIS_SHARE", "attenuated_axis", "renamed_noise"]

#: The attenuated axis must stand out by this many standard errors ...
AXIS_Z = 5.0
#: ... and the other axis stay under this share of it.
OTHER_AXIS_SHARE = 0.25

_NOISE_TYPE = FAULT_TYPES.index("noise") + 1
_PARTNER = {"Utx": "Ux", "Ux": "Utx", "Uty": "Uy", "Uy": "Uty"}
#: θ axis (0: x, 1: y) that noise on each signal attenuates.
_ATTENUATED = {"Ux": 0, "Uty": 0, "Uy": 1, "Utx": 1}


def attenuated_axis(evidence: tuple[float, float] | None) -> int | None:
    """0 (x) or 1 (y) where one axis's θ shift stands out of ``evidence`` (largest |z|
    on the x and y axes), None where neither does or both do (a spin or torquer change
    moves both axes alike)."""
    if evidence is None:
        return None
    zx, zy = evidence
    if zx >= AXIS_Z and zy <= OTHER_AXIS_SHARE * zx:
        return 0
    if zy >= AXIS_Z and zx <= OTHER_AXIS_SHARE * zy:
        return 1
    return None


def renamed_noise(library: PatternLibrary | None, result: PatternResult | None,
                  evidence: tuple[float, float] | None) -> PatternResult | None:
    """``result``, or its same-axis partner's noise class where ``evidence`` (largest
    |z| of the θ shift on the x and y axes) points clearly at the partner's axis."""
    if (library is None or result is None or evidence is None
            or result.fault_type != _NOISE_TYPE or not 1 <= result.signal <= len(SIGNALS)):
        return result
    axis = attenuated_axis(evidence)
    if axis is None:
        return result
    signal = SIGNALS[result.signal - 1]
    if _ATTENUATED[signal] == axis:
        return result
    want = _PARTNER[signal]
    for i, c in enumerate(library.classes):
        if c.type == "noise" and c.signal == want:
            return replace(result, code=i + 1, name=c.name, signal=SIGNALS.index(want) + 1,
                           axis=c.axis, signal_mask=signal_bit(want))
    return result
