"""Build hook for the optional compiled kernels (everything else is in pyproject.toml).

``gyrodiag.common._ckernels`` (fmu_src/gyrodiag/common/_ckernels.c) is compiled against the CPython
stable ABI (one ``.abi3.so`` for every CPython >= 3.11). It is optional: without a C
compiler the install goes on and gyrodiag uses its plain-Python kernels
(``gyrodiag.common._accel``).
"""

from setuptools import Extension, setup

setup(
    ext_modules=[
        Extension(
            "gyrodiag.common._ckernels",
            ["fmu_src/gyrodiag/common/_ckernels.c"],
            py_limited_api=True,
            # no fused multiply-add: same rounding as the plain-Python kernels
            extra_compile_args=["-O2", "-ffp-contract=off"],
            optional=True,
        )
    ]
)
