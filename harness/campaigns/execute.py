"""Running a campaign: the pending runs (resume, ``--retry-failed``, ``--max-runs``) on a
process pool or Dask, the DTG libraries learned first, a preflight of every class,
interruption (Ctrl-C, SIGTERM) with the finished runs kept (:func:`run_campaign`)."""

from __future__ import annotations

import logging
import os
import signal
import subprocess
import sys
import threading
import time
import tomllib
from collections.abc import Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from gyrodiag_harness.campaigns.expand import build_scenario, campaign_fmu_dir, expand_runs, select
from gyrodiag_harness.campaigns.records import load_records, remove_stale_temporaries, write_plan
from gyrodiag_harness.campaigns.spec import DEFAULT_RUNNER, CampaignSpec, RunSpec
from gyrodiag_harness.campaigns.supervise import (
    REPO_ROOT,
    _child_env,
    _worker_init,
    execute_run,
)
from gyrodiag_harness.cosim.scenario import ScenarioError

log = logging.getLogger(__name__)


class CampaignInterrupted(KeyboardInterrupt):
    """A campaign stopped by Ctrl-C or SIGTERM; finished runs are saved (the message
    says where), runs in flight were killed."""


@dataclass
class CampaignOutcome:
    """What :func:`run_campaign` did: records of every finished run (old and new)."""

    records: list[dict[str, Any]]
    n_total: int
    n_skipped: int
    n_executed: int
    wall_s: float
    out_dir: Path
    failed: list[str] = field(default_factory=list)


def _iter_pool(runs: Sequence[RunSpec], runner: str, timeout_s: float, records_dir: Path,
               workers: int) -> Iterator[dict[str, Any]]:
    import multiprocessing

    ctx = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=workers, mp_context=ctx,
                             initializer=_worker_init, initargs=(os.getpid(),)) as pool:
        futures: list[Any] = []
        try:
            # submitting is inside the try: an interrupt here must stop the pool too
            futures += [pool.submit(execute_run, r.model_dump(), runner, timeout_s,
                                    str(records_dir)) for r in runs]
            for f in as_completed(futures):
                yield f.result()
        except BaseException:
            # without this, leaving the with-block would wait for the runs in flight;
            # take the workers first: shutdown() forgets them (Python 3.11)
            procs = list((getattr(pool, "_processes", None) or {}).values())
            pool.shutdown(wait=False, cancel_futures=True)
            for proc in procs:
                proc.terminate()
            raise
        finally:
            for f in futures:
                f.cancel()


def _raise_interrupt(signum: int, frame: Any) -> None:
    raise KeyboardInterrupt(f"signal {signum}")


def _iter_dask(runs: Sequence[RunSpec], runner: str, timeout_s: float, records_dir: Path,
               workers: int, address: str) -> Iterator[dict[str, Any]]:
    from distributed import Client, LocalCluster
    from distributed import as_completed as dask_as_completed

    cluster = None
    if address == "local":
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                               dashboard_address=None)
        client = Client(cluster)
    else:
        client = Client(address)
    try:
        futures = [client.submit(execute_run, r.model_dump(), runner, timeout_s,
                                 str(records_dir), key=f"run-{r.run_id}", pure=False,
                                 retries=0) for r in runs]
        try:
            for f in dask_as_completed(futures):
                yield f.result()
        finally:
            client.cancel(futures)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def prepare(spec: CampaignSpec, base_dir: Path, out_dir: Path,
            fmu_dir: Path | str | None = None) -> None:
    """Learn the DTG signatures first when the spec asks for them and they are missing
    (``signatures_training``, then every entry of ``libraries``), with the FMUs of
    :func:`campaign_fmu_dir`."""
    learned = ([(spec.signatures_file, spec.signatures_training)]
               if spec.signatures_training is not None else [])
    for name, training in [*learned, *spec.libraries.items()]:
        _learn_library(spec, base_dir, out_dir, name, training,
                       campaign_fmu_dir(spec, base_dir, fmu_dir))


def preflight_runs(runs: Sequence[RunSpec]) -> None:
    """Check one run of every class as a run process would before its first FMU call
    (``files`` parameters such as a library the spec does not learn, FMU files,
    variable names), so that a campaign whose chain cannot start stops at once
    instead of recording every run as failed.

    Raises
    ------
    ScenarioError, FileNotFoundError
        Naming the class's base scenario and what is missing.
    """
    from gyrodiag_harness.cosim.master import preflight

    seen: set[str] = set()
    for run in runs:
        if run.cls in seen:
            continue
        seen.add(run.cls)
        try:
            scenario = build_scenario(run)
        except ScenarioError:
            raise
        except (ValueError, tomllib.TOMLDecodeError) as exc:  # the spec's or the base's
            raise ScenarioError(run.scenario, [(f"class {run.cls}", str(exc))]) from None
        preflight(scenario, fmu_dir=run.fmu_dir, results_dir=run.results_dir)


def _learn_library(spec: CampaignSpec, base_dir: Path, out_dir: Path, name: str,
                   training_set: str, fmu_dir: str | None) -> None:
    results = (base_dir / spec.results_dir).resolve() if spec.results_dir else out_dir
    target = results / name
    if target.is_file():
        return
    training = (base_dir / training_set).resolve()
    log.info("learning the DTG signatures from %s -> %s", training, target)
    cmd = [sys.executable, "-m", "gyrodiag_harness", "learn-signatures", str(training), "--out",
           str(target)]
    if fmu_dir:
        cmd += ["--fmu-dir", fmu_dir]
    proc = subprocess.run(cmd, env=_child_env(), cwd=str(REPO_ROOT),
                          timeout=7200)
    if proc.returncode != 0 or not target.is_file():
        raise RuntimeError(f"learning the DTG signatures failed (exit {proc.returncode})")


def run_campaign(spec: CampaignSpec, base_dir: Path, out_dir: Path, *, workers: int = 2,
                 dask: str | None = None, runner: str | None = None,
                 timeout_s: float | None = None, max_runs: int | None = None,
                 retry_failed: bool = False, fraction: float = 1.0,
                 progress: bool = True, fmu_dir: Path | str | None = None,
                 groups: Sequence[str] | None = None,
                 conditions: Sequence[str] | None = None) -> CampaignOutcome:
    """Run (or resume) a campaign; every finished run is written as it finishes.

    Parameters
    ----------
    spec, base_dir : CampaignSpec, Path
        The spec and the folder its relative paths start from (:func:`load_campaign`).
    out_dir : Path
        Output folder: ``runs/<run_id>.json`` per run, ``campaign.json`` (the run list).
    workers : int
        Parallel runs (pool processes or LocalCluster workers).
    dask : str, optional
        None: local process pool; ``"local"``: a dask LocalCluster; else a scheduler
        address (``tcp://host:8786``).
    runner : str, optional
        ``"module:function"`` computing a run's record fields (default: the spec's,
        :func:`simulate_run`); it must be importable in the run process.
    timeout_s : float, optional
        Per-run wall time limit, s (default: the spec's).
    max_runs : int, optional
        Stop after starting this many pending runs (an interruption on purpose).
    retry_failed : bool
        Re-run runs whose record says error/timeout.
    fraction : float
        Run only a deterministic subset (run ids hashed below ``fraction``), in (0, 1].
    progress : bool
        tqdm progress bar with ETA on stderr.
    fmu_dir : path, optional
        Folder of the FMUs, before ``$GYRODIAG_FMU_DIR`` and the spec's
        (:func:`campaign_fmu_dir`); the run ids do not depend on it.
    groups, conditions : sequence of str, optional
        Run only these condition groups / flight conditions (:func:`select`).
    """
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    if not 0.0 < fraction <= 1.0:
        raise ValueError(f"fraction must be in (0, 1], got {fraction}")
    t0 = time.perf_counter()
    out_dir = Path(out_dir).resolve()
    records_dir = out_dir / "runs"
    if fmu_dir is not None and not Path(fmu_dir).is_dir():
        raise FileNotFoundError(f"fmu_dir {str(fmu_dir)!r} is not a folder")
    # selected before anything is written: a bad selection leaves no folder behind
    runs = select(expand_runs(spec, base_dir, out_dir, fmu_dir), fraction, groups=groups,
                  conditions=conditions)
    records_dir.mkdir(parents=True, exist_ok=True)
    prepare(spec, base_dir, out_dir, fmu_dir)
    runner = runner or spec.runner
    if runner == DEFAULT_RUNNER:  # another runner need not read the scenarios
        preflight_runs(runs)
    write_plan(out_dir, spec.model_dump(by_alias=True), base_dir, fraction, groups,
               conditions, [r.run_id for r in runs])
    remove_stale_temporaries(records_dir)
    pending, n_skipped = _pending(runs, records_dir, retry_failed, max_runs)
    timeout = float(timeout_s if timeout_s is not None else spec.timeout_s)
    new: list[dict[str, Any]] = []
    if pending:
        it = (_iter_pool(pending, runner, timeout, records_dir, workers) if dask is None
              else _iter_dask(pending, runner, timeout, records_dir, workers, dask))
        bar = _bar(len(pending), n_skipped, progress)
        interrupted = _consume(it, bar, new)
        if interrupted is not None:
            raise _interruption(spec, runs, records_dir, dask) from interrupted
    ids = {r.run_id for r in runs}
    records = [rec for rid, rec in load_records(records_dir).items() if rid in ids]
    return CampaignOutcome(records=records, n_total=len(runs), n_skipped=n_skipped,
                           n_executed=len(new), wall_s=time.perf_counter() - t0,
                           out_dir=out_dir,
                           failed=[r["run"]["run_id"] for r in records
                                   if r.get("status") != "ok"])


def _pending(runs: Sequence[RunSpec], records_dir: Path, retry_failed: bool,
             max_runs: int | None) -> tuple[list[RunSpec], int]:
    """The runs to start (resume: those without a record; ``retry_failed``: also the
    failed ones; at most ``max_runs``) and how many are skipped as done."""
    done = load_records(records_dir)
    keep = {rid for rid, rec in done.items()
            if not (retry_failed and rec.get("status") != "ok")}
    pending = [r for r in runs if r.run_id not in keep]
    n_skipped = len(runs) - len(pending)
    if max_runs is not None:
        pending = pending[:max(0, max_runs)]
    return pending, n_skipped


def _consume(it: Iterator[dict[str, Any]], bar: Any, new: list[dict[str, Any]]
             ) -> KeyboardInterrupt | None:
    """Collect the records of ``it`` into ``new`` as the runs finish; returns the
    interrupt (Ctrl-C, or SIGTERM in the main thread) that stopped it, if any."""
    # a batch system's kill (SIGTERM) stops the campaign as cleanly as Ctrl-C
    main = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGTERM, _raise_interrupt) if main else None
    interrupted: KeyboardInterrupt | None = None
    try:
        try:
            for rec in it:
                new.append(rec)
                if bar is not None:
                    bar.update(1)
                    if rec.get("status") != "ok":
                        bar.write(f"{rec['run']['run_id']}: {rec['status']}: "
                                  f"{str(rec.get('error')).strip().splitlines()[0][:150]}")
        except KeyboardInterrupt as exc:
            interrupted = exc
        finally:
            try:
                # the interrupt may land outside the generator: close it here, or
                # its pool would wait for the runs in flight at interpreter exit
                it.close()
            except KeyboardInterrupt as exc:  # a second interrupt while stopping
                interrupted = interrupted or exc
    finally:
        if main:
            signal.signal(signal.SIGTERM,
                          previous if previous is not None else signal.SIG_DFL)
        if bar is not None:
            bar.close()
    return interrupted


def _interruption(spec: CampaignSpec, runs: Sequence[RunSpec], records_dir: Path,
                  dask: str | None) -> CampaignInterrupted:
    """What an interrupted campaign says: the runs saved, the fate of those in flight."""
    ids = {r.run_id for r in runs}
    saved = sum(1 for rid, rec in load_records(records_dir).items() if rid in ids)
    fate = ("were stopped and will be redone" if dask in (None, "local") else
            "were cancelled (on a remote cluster a run already started may still "
            "finish and be saved)")
    return CampaignInterrupted(
        f"campaign {spec.name!r} interrupted: {saved} of {len(runs)} runs are saved "
        f"in {records_dir}; the runs in flight {fate}; run the same command again "
        "to resume")


def _bar(total: int, initial: int, enabled: bool) -> Any:
    if not enabled:
        return None
    from tqdm import tqdm

    return tqdm(total=total + initial, initial=initial, unit="run", desc="campaign",
                file=sys.stderr, dynamic_ncols=True, smoothing=0.1)

