"""fmpy co-simulation harness for gyrodiag: master, scenarios, metrics, report, CLI.

The harness knows FMUs only through fmpy. Python API mirrored by the CLI
(``python -m gyrodiag_harness run | verify | report | list``)::

    from gyrodiag_harness import load_scenario, run_scenario
    result = run_scenario("scenarios/aircraft_q_bias.toml", out_dir="results/aircraft_q_bias")

Subpackages, by role (each imports only the ones listed before it; a test checks it):

``gyrodiag_harness.verification``
    metrics on recorded signals, the ``[[expect]]`` kinds and their evaluation, the
    isolability analysis of the seed aircraft;
``gyrodiag_harness.cosim``
    the scenario format, the fmpy co-simulation master, run records, batches of runs;
``gyrodiag_harness.reporting``
    JUnit XML, the HTML report and its plots;
``gyrodiag_harness.campaigns``
    Monte Carlo campaigns and their summary, DTG fault-signature learning;
``gyrodiag_harness.cli``
    the command line (``python -m gyrodiag_harness``) on top of them all.

The folder ``harness/`` installs as ``gyrodiag_harness`` (PyPI's ``harness`` is an unrelated
package; docs/harness.md).
"""

if __name__ != "gyrodiag_harness":     # imported as ``harness`` from a checkout's root
    raise ImportError(f"the gyrodiag harness is imported as {__name__!r}: install the project "
                      "(pip install -e .) and import gyrodiag_harness, or run "
                      "python -m gyrodiag_harness / gyrodiag")

from gyrodiag_harness.cosim.master import run_scenario
from gyrodiag_harness.cosim.results import FaultWindow, RunResult
from gyrodiag_harness.cosim.scenario import Scenario, ScenarioError, load_scenario

__all__ = ["FaultWindow", "RunResult", "Scenario", "ScenarioError", "load_scenario", "run_scenario"]
