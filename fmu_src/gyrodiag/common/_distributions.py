"""The few distribution quantiles the diagnoser needs, from ``scipy.special``.

``scipy.stats`` would give the same numbers (these are the formulas it evaluates, equal
to the bit: tests/test_distributions.py) but importing it costs three times as much
CPU as ``scipy.special``, which the library already needs, and every process that
instantiates the Diagnoser FMU pays it (docs/notes.md, distributions).  Imported where used:
the DTG and grey channels run on hosts without SciPy (tests/test_lean_host.py).
"""

from __future__ import annotations

__all__ = ["chi2_ppf", "normal_isf"]


def chi2_ppf(q: float, dof: float) -> float:
    """Quantile of the chi-square distribution: ``scipy.stats.chi2.ppf(q, dof)``.

    Parameters
    ----------
    q : float
        Probability, in [0, 1].
    dof : float
        Degrees of freedom, > 0.
    """
    if not 0.0 <= q <= 1.0:
        raise ValueError(f"q must be a probability in [0, 1], got {q!r}")
    if not dof > 0.0:
        raise ValueError(f"dof must be > 0, got {dof!r}")
    from scipy.special import gammaincinv

    return float(2.0 * gammaincinv(dof / 2.0, q))


def normal_isf(p: float) -> float:
    """Inverse survival function of the standard normal: ``scipy.stats.norm.isf(p)``.

    Parameters
    ----------
    p : float
        Upper-tail probability, in [0, 1].
    """
    if not 0.0 <= p <= 1.0:
        raise ValueError(f"p must be a probability in [0, 1], got {p!r}")
    from scipy.special import ndtri

    return float(-ndtri(p))
