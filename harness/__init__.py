"""fmpy co-simulation harness for gyrodiag: master, scenarios, metrics, report, CLI.

The harness knows FMUs only through fmpy. Python API mirrored by the CLI
(``python -m harness run | verify | report | list``)::

    from harness import load_scenario, run_scenario
    result = run_scenario("scenarios/aircraft_q_bias.toml", out_dir="results/aircraft_q_bias")
"""

from harness.master import run_scenario
from harness.results import FaultWindow, RunResult
from harness.scenario import Scenario, ScenarioError, load_scenario

__all__ = ["FaultWindow", "RunResult", "Scenario", "ScenarioError", "load_scenario", "run_scenario"]
