"""Never fatal, never a crash: wrong calls from a host are fmi2Error with a message.

Issue 32 item 3, docs/fmu.md "Errors": wrong-typed or unknown value references, NULL
arguments and calls in the wrong state; what they did before the fix: docs/notes.md
(wrong calls from a host).

Each FMU runs in its own process (tests/_never_fatal_runner.py, a raw ctypes host on the
FMU's binary, no fmpy wrapper in between): a segfault or abort is a test failure naming
the call, not a dead pytest worker.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import zipfile
from pathlib import Path
from typing import Any

import pytest

HERE = Path(__file__).resolve().parent
RUNNER = HERE / "_never_fatal_runner.py"
FMUS = ("Aircraft", "DTG", "Diagnoser", "FaultInjector", "HRG", "PitchController")
TYPES = ("Real", "Integer", "Boolean", "String")
ERROR, FATAL = 3, 4


def _run(fmu: Path, work: Path, mode: str) -> list[dict[str, Any]]:
    """Run the runner; its records (the process must end normally)."""
    proc = subprocess.run([sys.executable, str(RUNNER), str(fmu), str(work), mode],
                          capture_output=True, text=True, timeout=600)
    records = [json.loads(line) for line in proc.stdout.splitlines() if line.startswith("{")]
    begun = [r["begin"] for r in records if "begin" in r]
    if proc.returncode != 0 or not records or records[-1] != {"end": True}:
        how = (f"killed by {signal.Signals(-proc.returncode).name}" if proc.returncode < 0
               else f"exit status {proc.returncode}")
        pytest.fail(f"{fmu.stem} ({mode}): the host process died ({how}) in the call "
                    f"{begun[-1] if begun else '(none)'!r}\n{proc.stderr[-3000:]}")
    return [r for r in records if "call" in r]


def _by_label(records: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    return {r["call"]: r for r in records}


def _errors(record: dict[str, Any]) -> str:
    return "\n".join(m for s, m in record["log"] if s == ERROR)


def _assert_never_fatal(records: list[dict[str, Any]]) -> None:
    for r in records:
        assert r["status"] != FATAL, r
        assert all(s != FATAL for s, _ in r["log"]), r


def _md_variables(fmu: Path) -> dict[str, list[dict[str, Any]]]:
    import xml.etree.ElementTree as ET

    with zipfile.ZipFile(fmu) as zf:
        root = ET.fromstring(zf.read("modelDescription.xml"))
    out: dict[str, list[dict[str, Any]]] = {}
    for sv in root.iter("ScalarVariable"):
        out.setdefault(sv[0].tag, []).append({"vr": int(sv.get("valueReference")),
                                              "name": sv.get("name")})
    return out


def _check_types(name: str, records: list[dict[str, Any]], fmu: Path,
                 python_side: bool = False) -> int:
    """The assertions of the ``types`` mode; the number of wrong calls checked."""
    _assert_never_fatal(records)
    calls = _by_label(records)
    kinds = [k for k in TYPES if k in _md_variables(fmu)]
    wrong = [r for r in records if r["call"].startswith("wrong ")]
    assert len(wrong) == 2 * 3 * len(kinds), [r["call"] for r in wrong]
    for r in wrong:
        _, what, acc, kind, vr = r["call"].split()
        assert r["status"] == ERROR, r
        text = _errors(r)
        assert f"value reference {vr} " in text and f"is the {kind} variable" in text, r
        assert f"not {'an' if acc == 'Integer' else 'a'} {acc}" in text, r
        assert f"fmi2{what.capitalize()}{acc}" in text, r
    unknown = [r for r in records if r["call"].startswith(("unknown ", "mixed "))]
    assert len(unknown) == 2 * len(TYPES) + 1
    for r in unknown:
        vr = r["call"].split()[-1]
        assert r["status"] == ERROR, r
        assert f"unknown value reference {vr} " in _errors(r), r
    # the instance goes on: right calls, steps, terminate and free
    for r in records:
        if r["call"].startswith("right ") or r["call"].startswith("fmi2"):
            assert r["status"] == 0, r
    assert {"fmi2DoStep after", "fmi2DoStep after 2", "fmi2Terminate",
            "fmi2FreeInstance"} <= set(calls)
    # the shim's messages name causality and variability, the facades' do not
    mark = "', not " if python_side else "), not "
    assert all(mark in _errors(r) for r in wrong), wrong[0]
    return len(wrong) + len(unknown)


@pytest.mark.parametrize("name", FMUS)
def test_wrong_typed_and_unknown_value_references_are_errors_not_fatal(fmu_dir, tmp_path,
                                                                        name):
    """For every variable type of the FMU, a get and a set through each other accessor,
    and get/set of an unknown value reference: fmi2Error with a message naming the value
    reference and its real type; then the right calls, two doSteps, terminate and free
    work."""
    fmu = fmu_dir / f"{name}.fmu"
    records = _run(fmu, tmp_path, "types")
    assert _check_types(name, records, fmu) >= 2 * 3 * 2 + 9


@pytest.mark.parametrize("name", ["Diagnoser", "HRG", "DTG"])
def test_without_a_model_description_the_facades_refuse_wrong_types(fmu_dir, tmp_path, name):
    """The shim reads its table from modelDescription.xml next to the resources; a host
    that extracted the binary and resources only gets the same errors from the Python
    facades (gd_fmu_base.GuardedSlave), never pythonfmu's fatal."""
    fmu = fmu_dir / f"{name}.fmu"
    records = _run(fmu, tmp_path, "types-no-md")
    _check_types(name, records, fmu, python_side=True)


# the expected status of each call of the ``states`` mode (labels up to a variable part)
STATES = {
    "fmi2Instantiate": (0, None),
    "doStep before initialisation": (ERROR, "fmi2DoStep: refused in instantiated"),
    "exit before enter": (ERROR, "fmi2ExitInitializationMode: refused in instantiated"),
    "fmi2SetupExperiment": (0, None),
    "fmi2EnterInitializationMode": (0, None),
    "setupExperiment in initialisation mode": (ERROR, "fmi2SetupExperiment: refused in "
                                                      "initialisation mode"),
    "doStep in initialisation mode": (ERROR, "fmi2DoStep: refused in initialisation mode"),
    "enter twice": (ERROR, "fmi2EnterInitializationMode: refused in initialisation mode"),
    "set String NULL string": (ERROR, "is a NULL string"),
    "set String invalid UTF-8": (ERROR, "is not valid UTF-8"),
    "fmi2ExitInitializationMode": (0, None),
    "exit twice": (ERROR, "fmi2ExitInitializationMode: refused in step mode"),
    "set fixed parameter": (ERROR, "only inputs and tunable parameters can be set"),
    "set output": (ERROR, "only inputs and tunable parameters can be set"),
    "get Real vr NULL": (ERROR, "the value reference array is NULL with nvr = 1"),
    "set Real vr NULL": (ERROR, "the value reference array is NULL with nvr = 1"),
    "get Real values NULL": (ERROR, "the value array is NULL with nvr = 1"),
    "set Real values NULL": (ERROR, "the value array is NULL with nvr = 1"),
    "get Real n 0 NULL": (0, None),
    "fmi2DoStep after": (0, None),
    "fmi2GetFMUstate": (0, None),
    "state size NULL": (ERROR, "the size pointer is NULL"),
    "serialize NULL bytes": (ERROR, "the byte array is NULL"),
    "fmi2FreeFMUstate": (0, None),
    "fmi2Terminate": (0, None),
    "doStep after terminate": (ERROR, "fmi2DoStep: refused in terminated"),
    "terminate twice": (ERROR, "fmi2Terminate: refused in terminated"),
    "get after terminate": (0, None),
    "fmi2FreeInstance": (0, None),
    "null component doStep": (ERROR, None),
}


@pytest.mark.parametrize("name", FMUS)
def test_calls_in_the_wrong_state_and_null_arrays_are_errors(fmu_dir, tmp_path, name):
    records = _run(fmu_dir / f"{name}.fmu", tmp_path, "states")
    _assert_never_fatal(records)
    seen = set()
    for r in records:
        key = next(k for k in sorted(STATES, key=len, reverse=True) if r["call"].startswith(k))
        seen.add(key)
        status, text = STATES[key]
        assert r["status"] == status, r
        if text:
            assert text in _errors(r), r
    expected = set(STATES)
    if "String" not in _md_variables(fmu_dir / f"{name}.fmu"):
        expected -= {"set String NULL string", "set String invalid UTF-8"}
    assert seen == expected


@pytest.mark.parametrize("name", FMUS)
def test_bad_instantiate_arguments_give_null_and_a_message(fmu_dir, tmp_path, name):
    records = _run(fmu_dir / f"{name}.fmu", tmp_path, "instantiate")
    _assert_never_fatal(records)
    calls = _by_label(records)
    for label, text in {"instantiate NULL GUID": "fmuGUID is NULL",
                        "instantiate wrong GUID": "fmuGUID {not-this-fmu} is not this FMU's",
                        "instantiate NULL name": "instance name is NULL or empty",
                        "instantiate NULL resources": "fmuResourceLocation is NULL",
                        "instantiate model exchange": "co-simulation only"}.items():
        assert calls[label]["status"] is None, calls[label]
        assert text in _errors(calls[label]), calls[label]
    # and a right instance runs afterwards
    for label in ("fmi2Instantiate", "fmi2ExitInitializationMode", "fmi2DoStep",
                  "fmi2Terminate", "fmi2FreeInstance"):
        assert calls[label]["status"] == 0, calls[label]
