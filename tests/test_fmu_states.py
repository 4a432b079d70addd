"""Bad FMU states give fmi2Error naming the problem and leave every FMU as it was.

Issue 13 item 3 / docs/methods.md §6.14: truncated, corrupt and foreign serialized states, states
of other FMUs and freed states, for every FMU of the project. The calls run in one fresh
process (tests/_state_runner.py); see there for the cases.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from _state_runner import SETUP, fnv1a64, frame, unframe

RUNNER = Path(__file__).resolve().parent / "_state_runner.py"
FMI_ERROR = 3

#: case → (call that must fail, words its message must contain)
EXPECTED: dict[str, tuple[str, tuple[str, ...]]] = {
    "empty": ("deserialize", ("truncated serialized state", "0 bytes")),
    "truncated_header": ("deserialize", ("truncated serialized state", "10 bytes")),
    "truncated_half": ("deserialize", ("truncated serialized state", "payload bytes announced")),
    "truncated_last_byte": ("deserialize", ("truncated serialized state",)),
    "trailing_byte": ("deserialize", ("corrupt serialized state", "payload bytes announced")),
    "flipped_payload": ("deserialize", ("corrupt serialized state", "checksum mismatch")),
    "flipped_checksum": ("deserialize", ("corrupt serialized state", "checksum mismatch")),
    "flipped_guid": ("deserialize", ("foreign serialized state", "GUID")),
    "garbage": ("deserialize", ("not a serialized state of a gyrodiag FMU",)),
    "raw_json": ("deserialize", ("not a serialized state", "without the gyrodiag shim")),
    "foreign_fmu": ("deserialize", ("foreign serialized state", "GUID")),
    "forged_other_model": ("set", ("foreign FMU state: made by model",)),
    "forged_bad_json": ("set", ("truncated or corrupt", "JSONDecodeError")),
    "forged_missing_variable": ("set", ("does not fit this instance", "missing")),
    "forged_other_format": ("set", ("foreign FMU state (format 'x/9'",)),
    "forged_broken_channel_state": ("set", ("does not fit this instance", "'monitor'")),
    "pointer_of_other_fmu": ("set", ("foreign FMU state", "not a live state of this FMU")),
    "freed_pointer": ("set", ("foreign FMU state", "not a live state of this FMU")),
    "null_pointer": ("set", ("the FMU state is NULL",)),
}


@pytest.fixture(scope="module")
def states(fmu_dir, tmp_path_factory) -> dict:
    out = tmp_path_factory.mktemp("states") / "states.json"
    proc = subprocess.run([sys.executable, str(RUNNER), str(fmu_dir), str(out)],
                          capture_output=True, text=True, timeout=600)
    if proc.returncode != 0:
        pytest.fail(f"state runner failed:\n{proc.stdout[-3000:]}\n{proc.stderr[-6000:]}")
    return json.loads(out.read_text(encoding="utf-8"))


def test_frame_format_is_what_the_shim_writes(states):
    """The runner's forged frames follow the shim's layout (else the forged cases would
    test nothing): re-framing a real payload gives back the shim's bytes' header."""
    for name, res in states.items():
        assert res["size"] > 64, name
    assert fnv1a64(b"") == 0xCBF29CE484222325 and fnv1a64(b"a") == 0xAF63DC4C8601EC8C
    guid, payload = unframe(frame("g-1", b'{"x": 1}'))
    assert (guid, payload) == ("g-1", b'{"x": 1}')


@pytest.mark.parametrize("name", list(SETUP))
def test_restoring_a_saved_state_repeats_the_run(states, name):
    res = states[name]
    np.testing.assert_array_equal(res["R2"], res["R1"])
    # the run moves: a restored state that did nothing would not pass
    r1 = np.array(res["R1"])
    assert np.ptp(r1, axis=0).max() > 0, name


@pytest.mark.parametrize("name", list(SETUP))
def test_bad_states_are_fmi2error_naming_the_problem(states, name):
    calls = states[name]["calls"]
    expected = {c: e for c, e in EXPECTED.items()
                if c != "forged_broken_channel_state" or name == "Diagnoser"}
    assert set(calls) == set(expected)
    for case, (call, words) in expected.items():
        entry = calls[case]
        if call == "set":
            assert entry.get("deserialize", 0) == 0, (name, case, entry)
        assert entry[call] == FMI_ERROR, (name, case, entry)  # not fmi2Fatal
        log = entry[f"{call}_log"]
        for word in words:
            assert word in log, (name, case, log)
        if case not in ("null_pointer",):
            assert "unchanged" in log, (name, case, log)
        assert "Traceback" not in log, (name, case, log)


@pytest.mark.parametrize("name", list(SETUP))
def test_instance_keeps_its_state_after_every_bad_state(states, name):
    """After all the refused calls the instance continues exactly as without them."""
    res = states[name]
    np.testing.assert_array_equal(res["R3"], res["R1"])


def test_foreign_messages_name_both_guids(states):
    diag = states["Diagnoser"]
    log = diag["calls"]["foreign_fmu"]["deserialize_log"]
    other = next(iter(SETUP))  # the runner pairs the last FMU with the first
    assert f"made by the FMU with GUID {states[other]['guid']}" in log
    assert f"this FMU has GUID {diag['guid']}" in log
