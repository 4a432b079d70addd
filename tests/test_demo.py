"""``python -m gyrodiag.demo`` prints what it measured beside what the model says it
should be, and the two agree."""

from __future__ import annotations

import re

import numpy as np

from gyrodiag import demo


def _rows(text: str, label: str) -> list[np.ndarray]:
    return [np.array([float(v) for v in line.split()[-5:]])
            for line in text.splitlines() if line.strip().startswith(label)]


def test_demo_prints_expected_values_beside_results(capsys) -> None:
    assert demo.main(["--seconds", "5"]) == 0
    text = capsys.readouterr().out
    expected, measured = _rows(text, "expected (model)"), _rows(text, "identified")
    assert len(expected) == 3 and len(measured) == 1      # θ, then η of the two faults
    # θ identified within 10 % of the model's (the prefilter and noise bias it)
    np.testing.assert_allclose(measured[0], expected[0], rtol=0.1)
    eta_measured = _rows(text, "measured")
    for exp, got in zip(expected[1:], eta_measured, strict=True):
        np.testing.assert_allclose(got, exp, atol=0.02)
    # the fault judgements state their expected outcome, and meet it
    verdicts = re.findall(r"alarm = (True|False) \(expected (True|False)\)", text)
    assert verdicts == [("False", "False"), ("True", "True")]
    codes = re.findall(r"C = (\[.*?\]) \(expected (\[.*?\])\)", text)
    assert len(codes) == 2 and all(a == b for a, b in codes)
    assert "c/J = " in text and "(40.00)" in text
