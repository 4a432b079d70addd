"""Random legal and illegal FMI call sequences never crash an FMU nor make it fatal (issue 37).

Each FMU runs a Hypothesis rule-based state machine (tests/_fmi_fuzz_runner.py) in its own
process, on a raw ctypes host: a segfault or abort there is a test failure naming the
sequence, not a dead pytest worker. The suite runs the same sequences at every run
(``--derandomize``); ``benchmarks/bench_call_sequences.py`` runs thousands of random ones
per FMU (figures: docs/notes.md).
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent
RUNNER = HERE / "_fmi_fuzz_runner.py"
FMUS = ("Aircraft", "DTG", "Diagnoser", "FaultInjector", "HRG", "PitchController")
#: sequences per FMU in the suite (a few hundred in all)
SEQUENCES = 50


def run_fuzzer(fmu: Path, work: Path, sequences: int, *extra: str,
               timeout: float = 900) -> dict:
    """Run the fuzzer on ``fmu``; its summary (fails the test if the process died or a
    property failed, with the sequence)."""
    proc = subprocess.run([sys.executable, str(RUNNER), str(fmu), str(work), "--sequences",
                           str(sequences), *extra], capture_output=True, text=True,
                          timeout=timeout)
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("{")]
    if proc.returncode < 0 or not lines:
        trace = work / "sequence.log"
        calls = trace.read_text().splitlines()[-40:] if trace.exists() else []
        how = (f"killed by {signal.Signals(-proc.returncode).name}" if proc.returncode < 0
               else f"exit status {proc.returncode}")
        pytest.fail(f"{fmu.stem}: the host process died ({how}); the sequence, last call "
                    "last:\n" + "\n".join(calls) + f"\n{proc.stderr[-3000:]}")
    summary = json.loads(lines[-1])
    if summary["failure"]:
        pytest.fail(f"{fmu.stem}: {summary['failure']}\n{proc.stderr[-6000:]}")
    return summary


@pytest.mark.parametrize("name", FMUS)
def test_random_call_sequences_are_never_fatal(fmu_dir, tmp_path, name):
    """No crash, no fmi2Fatal, every illegal call fmi2Error with a message, terminate and
    free after any error; and the sequences reach step mode and make illegal calls."""
    summary = run_fuzzer(fmu_dir / f"{name}.fmu", tmp_path, SEQUENCES, "--derandomize")
    assert summary["sequences"] >= SEQUENCES
    assert summary.get("status 4", 0) == 0
    kinds = summary["calls_by_kind"]
    assert kinds.get("fmi2DoStep legal 0", 0) > 0, kinds
    assert summary["illegal"] > 0 and summary["illegal"] == summary.get("status 3", 0) - \
        summary.get("legal refused", 0), summary
