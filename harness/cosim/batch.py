"""Running many scenarios: expand folders, load them all, run them one after the other.

Used by the command line (``run``, ``verify``, ``all``, ``learn-signatures``) and by
anything else that runs a list of scenarios.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path

from harness.cosim.results import RunResult
from harness.cosim.scenario import Scenario, ScenarioError, load_scenario


def scenario_files(paths: Sequence[Path]) -> list[Path]:
    """Expand folders to their ``*.toml`` files (sorted); files are kept as given."""
    files: list[Path] = []
    for p in paths:
        if p.is_dir():
            found = sorted(p.glob("*.toml"))
            if not found:
                raise FileNotFoundError(f"{p}: no .toml scenario files in this folder")
            files += found
        else:
            files.append(p)
    return files


def load_all(paths: Sequence[Path]) -> list[Scenario]:
    """Load every scenario, reporting all invalid files at once (ScenarioError)."""
    scenarios, errors = [], []
    for f in scenario_files(paths):
        try:
            scenarios.append(load_scenario(f))
        except ScenarioError as exc:
            errors.append(exc)
    if errors:
        raise ScenarioError(errors[0].source, errors[0].problems) if len(errors) == 1 else \
            _merged(errors)
    names = [s.name for s in scenarios]
    for s in scenarios:
        if names.count(s.name) > 1:
            others = [o.source for o in scenarios if o.name == s.name and o is not s]
            raise ScenarioError(s.source, [("name", f"scenario name {s.name!r} is also used by "
                                                    f"{', '.join(others)}: results would "
                                                    "overwrite each other")])
    return scenarios


def _merged(errors: list[ScenarioError]) -> ScenarioError:
    merged = ScenarioError(errors[0].source, errors[0].problems)
    merged.args = ("\n".join(str(e) for e in errors),)
    return merged


def summary_line(result: RunResult, out_dir: Path | None) -> str:
    """One line per run: outcome, samples, simulated and wall time, where it was saved."""
    n = len(result.time)
    where = f" -> {out_dir}" if out_dir is not None else ""
    if result.error is None:
        return (f"{result.scenario}: ok, {n} samples of {len(result.signals)} signals, "
                f"{result.stop_time_s:g} s simulated in {result.wall_time_s:.1f} s{where}")
    first = result.error.strip().splitlines()[0] if result.error.strip() else "error"
    t_end = f"{result.time[-1]:g} s" if n else "nothing"
    return (f"{result.scenario}: ERROR ({t_end} recorded of {result.stop_time_s:g} s): "
            f"{first}{where}")


def run_all(scenarios: Sequence[Scenario], out: Path, fmu_dir: Path | None,
            progress: bool) -> list[RunResult]:
    """Run scenarios one after the other, saving each into ``out/<name>``."""
    from harness.cosim.master import run_scenario

    results = []
    for s in scenarios:
        target = out / s.name
        result = run_scenario(s, fmu_dir=fmu_dir, progress=progress, out_dir=target,
                              results_dir=out)
        print(summary_line(result, target), flush=True)
        if result.error is not None and "\n" in result.error.strip():
            print(_indent(result.error), file=sys.stderr, flush=True)
        results.append(result)
    return results


def _indent(text: str) -> str:
    return "\n".join("    " + line for line in text.strip().splitlines())
