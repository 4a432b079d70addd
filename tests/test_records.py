"""gyrodiag.common._records.fast_init: the per-sample output records keep the dataclass
contract (signature, defaults, factories, frozen, equality, replace)."""

from __future__ import annotations

import dataclasses
import inspect

import numpy as np
import pytest

from gyrodiag.common._records import fast_init
from gyrodiag.df.channel import DFChannelOutput
from gyrodiag.df.sequential_diagnosis import DiagnosisOutput
from gyrodiag.dtg.channel import DTGChannelOutput
from gyrodiag.grey import GreyDetectorOutput


@dataclasses.dataclass(frozen=True)
class _Plain:
    a: int
    b: list = dataclasses.field(default_factory=list)
    c: float = 2.5


_Fast = fast_init(dataclasses.make_dataclass(
    "_Fast", [("a", int), ("b", list, dataclasses.field(default_factory=list)),
              ("c", float, dataclasses.field(default=2.5))], frozen=True))


@pytest.mark.parametrize("cls", [DTGChannelOutput, DFChannelOutput, DiagnosisOutput,
                                 GreyDetectorOutput])
def test_output_records_keep_their_signature_and_stay_frozen(cls):
    names = [f.name for f in dataclasses.fields(cls)]
    assert list(inspect.signature(cls).parameters) == names
    first = next(iter(names))
    # plain values (arrays would make == ambiguous); defaults where a field has one
    values = {f.name: (f.default if f.default is not dataclasses.MISSING else k)
              for k, f in enumerate(dataclasses.fields(cls))}
    record = cls(**values)
    with pytest.raises(dataclasses.FrozenInstanceError):
        setattr(record, first, 1)
    assert dataclasses.replace(record, **{first: "x"}) == cls(**{**values, first: "x"})
    assert record == cls(**values) and record != dataclasses.replace(record, **{first: -9})


def test_defaults_factories_and_errors_as_the_generated_init():
    assert _Fast(1) == _Fast(1, [], 2.5)
    assert _Fast(1).b is not _Fast(1).b  # a fresh list per instance, as the factory says
    assert repr(_Fast(3, [1], 0.5)) == "_Fast(a=3, b=[1], c=0.5)"
    with pytest.raises(TypeError):
        _Fast()  # the required argument is still required
    with pytest.raises(TypeError, match="frozen"):
        fast_init(dataclasses.make_dataclass("Open", [("a", int)]))
    d = DTGChannelOutput(True, False, np.zeros((2, 5)), np.ones((2, 5)), np.zeros(5),
                         False, 0, np.zeros(5, dtype=int), float("nan"))
    assert d.diagnosis.block == 0 and _Plain(1) == _Plain(1, [], 2.5)
