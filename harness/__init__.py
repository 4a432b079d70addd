"""fmpy co-simulation harness for gyrodiag: master, scenarios, metrics, report, CLI.

The harness knows FMUs only through fmpy. Python API mirrored by the CLI
(``python -m harness run | verify | report | list``)::

    from harness import load_scenario, run_scenario
    result = run_scenario("scenarios/aircraft_q_bias.toml", out_dir="results/aircraft_q_bias")

Subpackages, by role (each imports only the ones listed before it; a test checks it):

``harness.verification``
    metrics on recorded signals, the ``[[expect]]`` kinds and their evaluation, the
    isolability analysis of the seed aircraft;
``harness.cosim``
    the scenario format, the fmpy co-simulation master, run records, batches of runs;
``harness.reporting``
    JUnit XML, the HTML report and its plots;
``harness.campaigns``
    Monte Carlo campaigns and their summary, DTG fault-signature learning;
``harness.cli``
    the command line (``python -m harness``) on top of them all.
"""

from harness.cosim.master import run_scenario
from harness.cosim.results import FaultWindow, RunResult
from harness.cosim.scenario import Scenario, ScenarioError, load_scenario

__all__ = ["FaultWindow", "RunResult", "Scenario", "ScenarioError", "load_scenario", "run_scenario"]
