"""Shared building blocks of every method: signal conditioning, estimators, tables.

Modules
-------
prefilter
    Streaming Butterworth low-pass (second-order sections with carried state).
estimators
    Sliding-window batch least squares, RLS, RLS with forgetting factor.
cusum
    CUSUM tests and their thresholds for a stated false-alarm rate (the detection
    filter's sequential rule, the grey detector's sequential decision).
cusum_table
    Shipped CUSUM thresholds (data; written by ``fmu_src/tools/cusum_table.py``).
_distributions
    Normal and χ² quantiles without importing ``scipy.stats``.
_validation
    Argument checks with named, ranged error messages.
_records
    Fast ``__init__`` of frozen record dataclasses.
_accel, _pykernels, _ckernels
    Per-sample kernels: the compiled C extension (``_ckernels.c``) when it loads, else
    the same kernels in plain Python; ``_accel`` picks one.

Every public name of these modules is importable from the package too
(``from gyrodiag.common import ...``); it is imported from its module at first use,
so that importing one module of the package imports none of its siblings.
"""

from __future__ import annotations

from ._lazy import lazy_exports

#: Public name -> the module of this package that defines it.
_EXPORTS = {
    "ButterworthPrefilter": "prefilter",
    "butterworth_sos": "prefilter",
    "ringing_samples": "prefilter",
    "RLS": "estimators",
    "ForgettingRLS": "estimators",
    "SlidingWindowLS": "estimators",
    "batch_ls": "estimators",
    "CusumBank": "cusum",
    "arl_for_rate": "cusum",
    "mean_cusum_arl": "cusum",
    "mean_cusum_threshold": "cusum",
    "variance_cusum_arl": "cusum",
    "variance_cusum_increment": "cusum",
    "variance_cusum_threshold": "cusum",
}

__all__ = sorted(_EXPORTS)

__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
