"""Build-time generator of the Diagnoser's table of default observer designs.

``python fmu_src/tools/observer_gains.py --out FILE [--periods S ...]`` (build_fmu.py
runs it into ``resources/gyrodiag/df/observer_gains.npz``). The Diagnoser only loads
and looks the table up (:mod:`gyrodiag.df.gains`); designing it needs the whole
detection-filter channel, which is why the generator lives here, outside the runtime
package.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np
from numpy.typing import NDArray

from gyrodiag.df import gains
from gyrodiag.df.channel import DFChannel, DFChannelConfig

#: Sample periods (s) whose default designs the shipped table holds: the seed aircraft
#: scenarios run the Diagnoser at 10 ms, the system chain at 1 ms.
DEFAULT_PERIODS_S = (0.001, 0.002, 0.005, 0.01, 0.02)


def default_designs(periods_s: Sequence[float] = DEFAULT_PERIODS_S
                    ) -> dict[str, NDArray[np.float64]]:
    """The gains a Diagnoser with the default detection-filter model and eigenvalues
    designs at each sample period, with either decision rule.

    Each channel is built and calibrated on a short window of synthetic noise, the
    path a Diagnoser takes, and its designs are collected from the memo.
    """
    gains.start_empty()  # computed here, not read from an existing table
    rng = np.random.default_rng(0)
    for period in periods_s:
        window_s = max(0.5, 50 * period)
        for rule in ("paper", "sequential"):
            channel = DFChannel(DFChannelConfig(
                sample_period_s=period, decision=rule, calibrate_s=window_s,
                burn_in_s=0.1 * window_s, align_auto=False))
            n = round(window_s / period) + 1
            u = rng.normal(0.0, 0.01, (n, channel.p))
            y = rng.normal(0.0, 1e-3, (n, channel.m))
            for k in range(n):
                channel.update(u[k], y[k])
            if channel.engine is None:
                raise RuntimeError(f"{rule} channel at {period} s did not calibrate")
    out = gains.designs()
    gains.forget()  # the process goes on with its table file, if any
    return out


def save(path: Path | str, designs: dict[str, NDArray[np.float64]]) -> Path:
    """Write a table of designs (key -> gain) as .npz, with the runtime's
    :data:`gyrodiag.df.gains.FORMAT`."""
    path = Path(path)
    if gains.FORMAT_KEY in designs:
        raise ValueError(f"gains must not hold the key {gains.FORMAT_KEY!r}")
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("wb") as fh:
        np.savez(fh, **{gains.FORMAT_KEY: np.array(gains.FORMAT)}, **designs)
    return path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description="Write the Diagnoser's table of default observer designs (.npz).")
    parser.add_argument("--out", type=Path, required=True, help="table file to write")
    parser.add_argument("--periods", type=float, nargs="+", default=DEFAULT_PERIODS_S,
                        metavar="S", help="sample periods, s (default: %(default)s)")
    args = parser.parse_args(argv)
    if any(not (p > 0.0) for p in args.periods):
        parser.error(f"--periods must all be > 0, got {args.periods}")
    designs = default_designs(args.periods)
    save(args.out, designs)
    print(f"{len(designs)} observer designs -> {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
