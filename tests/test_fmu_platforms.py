"""What is shipped runs where it is claimed to, and a host's Python that lacks a package is
told so (issue 37 item 3; docs/fmu.md "Platforms").

* Only Linux x86-64 binaries are shipped (with the status shim); pythonfmu's win64 DLL,
  which has no shim and was never run, is not.
* A host whose Python lacks numpy or SciPy gets a NULL instance and a message naming
  the missing package and GYRODIAG_PYTHON: the C host (tests/host/gd_fmi2_host.c) with
  GYRODIAG_PYTHON set to a bare virtual environment of this Python (no numpy, no SciPy),
  and to the same with numpy alone on PYTHONPATH.
"""

from __future__ import annotations

import os
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

HERE = Path(__file__).resolve().parent
HOST_SOURCE = HERE / "host" / "gd_fmi2_host.c"


@pytest.fixture(scope="module")
def host(c_host) -> Path:
    return c_host
FMUS = ("Aircraft", "DTG", "Diagnoser", "FaultInjector", "HRG", "PitchController")


@pytest.mark.parametrize("name", FMUS)
def test_only_linux_binaries_with_the_shim_are_shipped(fmu_dir, name):
    with zipfile.ZipFile(fmu_dir / f"{name}.fmu") as zf:
        binaries = sorted(n for n in zf.namelist() if n.startswith("binaries/"))
        docs = zf.read("documentation/index.html").decode()
    assert binaries == [f"binaries/linux64/{name}.so", "binaries/linux64/pythonfmu-export.so"]
    assert "Linux x86-64 only" in docs


@pytest.fixture(scope="module")
def bare_python(tmp_path_factory) -> Path:
    """A virtual environment of this Python without pip, numpy or SciPy."""
    target = tmp_path_factory.mktemp("bare") / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(target)], check=True,
                   capture_output=True, timeout=300)
    python = target / "bin" / "python"
    for module in ("numpy", "scipy"):
        probe = subprocess.run([str(python), "-c", f"import {module}"], capture_output=True,
                               timeout=120)
        assert probe.returncode != 0, f"the bare environment has {module}"
    return python


@pytest.fixture(scope="module")
def numpy_only(tmp_path_factory) -> Path:
    """A folder for PYTHONPATH with this environment's numpy and nothing else."""
    folder = tmp_path_factory.mktemp("numpy_only")
    package = Path(np.__file__).resolve().parent
    for path in (package, package.with_name("numpy.libs")):
        if path.exists():
            (folder / path.name).symlink_to(path)
    return folder


def _run(host: Path, fmu: Path, work: Path, **env: str) -> subprocess.CompletedProcess:
    target = work / fmu.stem
    with zipfile.ZipFile(fmu) as zf:
        zf.extractall(target)
    clean = {k: v for k, v in os.environ.items()
             if k not in ("PYTHONPATH", "PYTHONHOME", "LD_PRELOAD", "VIRTUAL_ENV",
                          "GYRODIAG_PYTHON")}
    return subprocess.run([str(host), "--stop", "0.02", "--step", "0.01", str(target)],
                          env={**clean, **env}, capture_output=True, text=True, timeout=300)


def test_a_python_without_numpy_gets_a_null_instance_naming_the_packages(
        host, bare_python, fmu_dir, tmp_path):
    proc = _run(host, fmu_dir / "Aircraft.fmu", tmp_path, GYRODIAG_PYTHON=str(bare_python))
    assert proc.returncode == 1, proc.stderr
    assert "Aircraft: fmi2Instantiate failed" in proc.stderr
    assert "numpy, scipy missing" in proc.stderr
    assert f"the Python of {bare_python}" in proc.stderr
    assert "GYRODIAG_PYTHON" in proc.stderr and "[FATAL]" not in proc.stderr


def test_a_python_without_scipy_names_scipy_and_runs_the_fmus_that_need_numpy_only(
        host, bare_python, numpy_only, fmu_dir, tmp_path):
    env = {"GYRODIAG_PYTHON": str(bare_python), "PYTHONPATH": str(numpy_only)}
    # the Diagnoser starts on numpy alone (SciPy is optional at start-up: test_lean_host)
    proc = _run(host, fmu_dir / "Aircraft.fmu", tmp_path, **env)
    assert proc.returncode == 1, proc.stderr
    assert "scipy missing" in proc.stderr and "numpy, scipy missing" not in proc.stderr
    assert "GYRODIAG_PYTHON" in proc.stderr and "[FATAL]" not in proc.stderr
    proc = _run(host, fmu_dir / "FaultInjector.fmu", tmp_path, **env)  # numpy alone
    assert proc.returncode == 0, proc.stderr
    assert " OK" in proc.stdout
