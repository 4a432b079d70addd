"""The diagnoser's quantiles (gyrodiag.common._distributions) are scipy.stats' to the bit, and
the Diagnoser's run-time import chain no longer loads scipy.stats (1.5 s per process)."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.stats

from gyrodiag.common._distributions import chi2_ppf, normal_isf

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("dof", [1, 2, 7, 99, 1000, 2.5])
@pytest.mark.parametrize("q", [0.0, 1e-9, 0.025, 0.05, 0.5, 0.95, 0.975, 1.0])
def test_chi2_ppf_is_scipy_stats(q, dof):
    assert chi2_ppf(q, dof) == scipy.stats.chi2.ppf(q, dof)


@pytest.mark.parametrize("p", [0.0, 1e-12, 5e-7, 1e-3, 0.025, 0.5, 0.9, 1.0])
def test_normal_isf_is_scipy_stats(p):
    assert normal_isf(p) == scipy.stats.norm.isf(p)


def test_known_values_and_bad_input():
    assert normal_isf(0.025) == pytest.approx(1.959963984540054, rel=1e-15)
    assert chi2_ppf(0.95, 1) == pytest.approx(1.959963984540054**2, rel=1e-14)
    assert np.isinf(normal_isf(0.0))
    with pytest.raises(ValueError, match="q must be"):
        chi2_ppf(1.5, 3)
    with pytest.raises(ValueError, match="dof must be"):
        chi2_ppf(0.5, 0)
    with pytest.raises(ValueError, match="p must be"):
        normal_isf(float("nan"))


def test_the_diagnosers_channels_do_not_import_scipy_stats():
    code = ("import sys; import gd_diagnoser_fmu, gyrodiag.df.channel, gyrodiag.grey, "
            "gyrodiag.dtg.channel, gyrodiag.df.sequential_diagnosis; "
            "print('scipy.stats' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], cwd=str(ROOT / "fmu_src"),
                         capture_output=True, text=True, check=True, timeout=600).stdout
    assert out.strip() == "False"
