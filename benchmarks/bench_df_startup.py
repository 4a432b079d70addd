"""Start-up cost of the detection-filter channel: import, build, and the calibration
window's last step (where the decision engine is designed and calibrated).

Usage::

    .venv/bin/python benchmarks/bench_df_startup.py [--window-s 10] [--repeat 3]

For each decision rule (paper, sequential) and sample period (1 ms as the system chain,
10 ms as the aircraft seeds), in a fresh process each (imports are part of the cost),
with and without the table of default observer designs that build_fmu.py ships in the
Diagnoser (:mod:`gyrodiag.df.gains`; written to a temporary file here): process CPU
seconds for ``import gyrodiag.df.channel``, the channel's construction, the step that
ends the calibration window, and everything (200 monitoring steps included), and
whether ``scipy.signal`` was imported.  Prints medians over ``--repeat`` processes; no
assertions (timings depend on the machine and its load).
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

_CHILD = r"""
import json, sys, time
t0 = time.process_time()
sys.path.insert(0, {src!r})
from pathlib import Path
from gyrodiag.df import gains
gains.TABLE_FILE = Path({table!r})
import numpy as np
from gyrodiag.df.channel import DFChannel, DFChannelConfig
t1 = time.process_time()
ch = DFChannel(DFChannelConfig(sample_period_s={period!r}, decision={rule!r},
                               calibrate_s={window!r}, align_auto=False))
t2 = time.process_time()
n = round({window!r} / {period!r})
rng = np.random.default_rng(1)
u = rng.normal(0, 0.01, (n + 200, ch.p))
y = rng.normal(0, 1e-3, (n + 200, ch.m))
last = 0.0
for k in range(n + 200):
    a = time.process_time()
    ch.update(u[k], y[k])
    if k == n - 1:
        last = time.process_time() - a
print(json.dumps({{"import": t1 - t0, "build": t2 - t1, "window_end": last,
                  "total": time.process_time() - t0,
                  "scipy_signal": "scipy.signal" in sys.modules}}))
"""


def _run(rule: str, period: float, window: float, table: Path) -> dict:
    code = _CHILD.format(src=str(ROOT / "fmu_src"), table=str(table), period=period,
                         rule=rule, window=window)
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          check=True, timeout=3600)
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--window-s", type=float, default=10.0,
                        help="calibration window, s (default 10, as the system scenarios)")
    parser.add_argument("--repeat", type=int, default=3, help="processes per figure")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="gyrodiag-bench-") as tmp:
        table = Path(tmp) / "observer_gains.npz"
        subprocess.run([sys.executable, str(ROOT / "fmu_src" / "tools" / "observer_gains.py"),
                        "--out", str(table)], check=True, capture_output=True, timeout=3600)
        absent = Path(tmp) / "absent.npz"
        print(f"detection-filter start-up, {args.window_s:g} s window, CPU s "
              f"(median of {args.repeat} processes)")
        print(f"{'rule':<11}{'period':>8}  {'table':<6}{'import':>8}{'build':>8}"
              f"{'window end':>12}{'total':>8}  scipy.signal")
        for rule in ("paper", "sequential"):
            for period in (0.001, 0.01):
                for label, path in (("no", absent), ("yes", table)):
                    runs = [_run(rule, period, args.window_s, path)
                            for _ in range(args.repeat)]
                    med = {k: statistics.median(r[k] for r in runs)
                           for k in ("import", "build", "window_end", "total")}
                    imported = "imported" if any(r["scipy_signal"] for r in runs) else "-"
                    print(f"{rule:<11}{period * 1e3:>6g}ms  {label:<6}{med['import']:>8.2f}"
                          f"{med['build']:>8.2f}{med['window_end']:>12.2f}"
                          f"{med['total']:>8.2f}  {imported}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
