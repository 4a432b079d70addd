"""``python -m gyrodiag_harness export-ssp``: write a scenario as an SSP package.

See :mod:`gyrodiag_harness.cosim.ssp` for what is carried and what is not.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from gyrodiag_harness.cli.common import EXIT_OK, EXIT_USAGE
from gyrodiag_harness.cosim.ssp import export_ssp


def add_parser(sub: Any) -> None:
    """Register ``export-ssp`` on the CLI's sub-parsers."""
    p = sub.add_parser(
        "export-ssp",
        help="write a scenario as an SSP package (SystemStructure.ssd, the FMUs, parameter "
             "values) for SSP tools such as libcosim and Ecos")
    p.add_argument("scenario", type=Path, metavar="SCENARIO", help="scenario .toml file")
    p.add_argument("--out", type=Path, required=True, metavar="FILE.ssp", help="SSP to write")
    p.add_argument("--fmu-dir", type=Path, default=None, help="folder of the .fmu files")
    p.add_argument("--results", type=Path, default=Path("results"), metavar="DIR",
                   help="what ${out}/ stands for in the scenario's files (default results/)")
    p.set_defaults(func=cmd_export_ssp)


def cmd_export_ssp(args: argparse.Namespace) -> int:
    """``export-ssp``: exit 0 written (what SSP cannot carry is printed), 2 usage."""
    try:
        done = export_ssp(args.scenario, args.out, args.fmu_dir, args.results)
    except ImportError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    print(f"{done.path}: {len(done.components)} components ({', '.join(done.components)}), "
          f"{done.parameters} parameter values")
    for note in done.not_carried:
        print(f"  not carried: {note}")
    return EXIT_OK
