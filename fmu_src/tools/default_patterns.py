"""Writer and checker of the Diagnoser's shipped DTG pattern library.

The library is learned from the pattern training scenarios (the paper DTG bench at
1 kHz) and committed as ``gyrodiag/dtg/default_patterns.json``, because learning it
takes 54 co-simulation runs. To regenerate it::

    python -m gyrodiag_harness learn-signatures scenarios/training/patterns --out learned.json
    python fmu_src/tools/default_patterns.py learned.json          # rewrites the file
    python fmu_src/tools/default_patterns.py learned.json --check  # exit 1 if it differs

The shipped file keeps the classes, the noise model, the decision constants and the
bench's nominal prior, marked ``levels_only``: the prior replaces a learned reference
only when θ0 and the noise match the training bench and the levels do not (an offset
fault present before learning). Another gyro, dither or noise level is its own nominal.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from gyrodiag.dtg.patterns import DEFAULT_LIBRARY_FILE, PatternLibrary

#: Where the training scenarios live, recorded in the shipped file.
TRAINING = "scenarios/training/patterns"


def shipped_content(learned: dict[str, Any]) -> dict[str, Any]:
    """The shipped library from a ``learn-signatures`` pattern file: patterns with the
    nominal prior marked ``levels_only``, and the class codes."""
    if "patterns" not in learned or "codes" not in learned:
        raise ValueError("not a pattern library from learn-signatures: it needs "
                         "'patterns' and 'codes'")
    patterns = dict(learned["patterns"])
    if "nominal" not in patterns:
        raise ValueError("the learned library has no nominal prior (learn it with the "
                         "fault-free training runs)")
    patterns["nominal"] = {**patterns["nominal"], "levels_only": True}
    PatternLibrary.from_dict(patterns)  # readable by the channel, or a clear error
    return {"patterns": patterns, "codes": learned["codes"], "learned_from": TRAINING}


def differences(a: Any, b: Any, path: str = "", rtol: float = 1e-9) -> list[str]:
    """Where two JSON values differ (numbers within ``rtol``), as key paths."""
    if isinstance(a, dict) and isinstance(b, dict):
        out = [f"{path}.{k}: only in one" for k in sorted(set(a) ^ set(b))]
        for k in sorted(set(a) & set(b)):
            out += differences(a[k], b[k], f"{path}.{k}", rtol)
        return out
    if isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            return [f"{path}: length {len(a)} != {len(b)}"]
        return [d for i, (x, y) in enumerate(zip(a, b, strict=True))
                for d in differences(x, y, f"{path}[{i}]", rtol)]
    numbers = (int, float)
    if isinstance(a, numbers) and isinstance(b, numbers) and not isinstance(a, bool):
        if math.isclose(a, b, rel_tol=rtol, abs_tol=1e-300):
            return []
    elif a == b:
        return []
    return [f"{path}: {a!r} != {b!r}"]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description="Write (or check) the Diagnoser's shipped DTG pattern library.")
    parser.add_argument("learned", type=Path,
                        help="pattern library written by harness learn-signatures")
    parser.add_argument("--out", type=Path, default=DEFAULT_LIBRARY_FILE,
                        help="file to write or check (default: %(default)s)")
    parser.add_argument("--check", action="store_true",
                        help="compare with --out instead of writing it; exit 1 if differs")
    args = parser.parse_args(argv)
    content = shipped_content(json.loads(args.learned.read_text(encoding="utf-8")))
    if args.check:
        diff = differences(content, json.loads(args.out.read_text(encoding="utf-8")))
        for line in diff[:20]:
            print(line)
        print(f"{args.out}: {'differs' if diff else 'matches'} ({len(diff)} differences)")
        return 1 if diff else 0
    args.out.write_text(json.dumps(content, indent=1) + "\n", encoding="utf-8")
    print(f"{len(content['patterns']['classes'])} classes -> {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
