"""Build-time generator of the Diagnoser's table of default observer designs.

``python fmu_src/tools/observer_gains.py --out FILE [--periods S ...]`` (build_fmu.py
runs it into ``resources/gyrodiag/df/observer_gains.npz``; :mod:`gyrodiag.df.gains`).
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from gyrodiag.df.gains import main

if __name__ == "__main__":
    sys.exit(main())
