"""Monte Carlo fault-injection campaigns: ``python -m gyrodiag_harness campaign SPEC.toml``.

A campaign spec (TOML, validated by :class:`CampaignSpec`) names, per *class*, a base
scenario (the chain of FMUs, e.g. ``scenarios/aircraft_q_bias.toml``) and sweeps over
fault type, magnitude, onset time, affected injector channel (sensor) and random seed,
plus nominal runs (no fault) for the false-alarm rate.  :func:`expand_runs` turns the
spec into :class:`RunSpec` entries, each with a deterministic id (hash of its content),
so that a campaign can be interrupted and resumed.

Execution
---------
Each run is simulated in **its own fresh process** (``python -m
gyrodiag_harness.campaigns.supervise --child``): pythonfmu FMUs must not be loaded twice in one
process, a crash (abort, segfault) only kills that process, and a hung run can be killed
at its timeout.  The guard that starts the process, waits for it and writes the run's record
(:func:`execute_run`) is the task that a pool runs:

* default: a ``concurrent.futures.ProcessPoolExecutor`` (``spawn`` context);
* ``--dask local``: a ``dask.distributed`` ``LocalCluster``; ``--dask ADDRESS``: the
  scheduler of a real cluster (the workers need this package and the FMUs at the same
  paths).  No home-made job system: the pools do the scheduling.

Every finished run is written at once as ``<out>/runs/<run_id>.json`` (atomically: a
temporary file renamed), also when it failed: ``status`` is ``"ok"``, ``"error"`` (the
runner raised, the process died, the FMU failed) or ``"timeout"``.  A resumed campaign
skips every id that has a record (``--retry-failed`` re-runs the failed ones).

What a run records
------------------
Not the signals: a small record (:func:`simulate_run`) with, for the channel's alarm
``A(t)`` (detection filter with the paper's rule, ``df.decision = 0``: any main-residual
alarm ``diag.df.alarm[i]``, k-of-n, unlatched; with the sequential rule (the default):
``diag.df.detected``, a fault episode; DTG: ``diag.dtg.alarm``):

* ``detected`` / ``delay_s``: ``A`` on at some sample at or after the onset, delay from
  the onset to the first such sample;
* ``false_alarms`` / ``fault_free_s``: rising edges of ``A`` in the fault-free time from
  the end of calibration (DF) or learning (DTG) to the onset (the whole run if nominal);
* ``diagnosed``: isolated sensor (``diag.df.isolated_sensor``; several isolated sensors
  joined by "+", e.g. "alpha+q", from ``diag.df.isolated_mask``) or DTG fault code at the
  end of the run, and ``injected``, what it should be (a sweep's ``also`` faults make it
  a pair); sequential DF also ``typed`` (fault type at the end), ``expected_type``,
  ``size``, ``episodes`` and ``input_delay`` (the alignment it chose);
* the threshold sweep: the alarm statistic ``s(t)`` in threshold units is rebuilt from the
  recorded outputs, so that ``A_T(t) = s(t) > T`` reproduces the alarm at any threshold
  ``T``, and detection, delay and false alarms are evaluated on the class's threshold
  grid.  DF: ``s(t) = max_i kth_largest(|r_i - mu_i| / sigma_i over the last n
  samples)``, ``|r_i - mu_i| / sigma_i`` being ``k_sigma`` times the channel's own
  ``df.statistic[i]`` (its ``mu_i``, ``sigma_i`` and the alignment it chose; without that
  output ``mu_i``, ``sigma_i`` (ddof 1) are re-estimated from the recorded main residuals
  over the calibration window after the burn-in, exact with Gauss-Seidel coupling only);
  ``T`` is in standard deviations (the FMU uses ``df.k_sigma``); sequential DF: the
  recorded ``diag.df.statistic[i]`` (CUSUM over its threshold, capped at 1), so only
  ``T <= 1`` is meaningful and the alarm ``df.detected`` (episode logic) differs from
  ``s > 1`` after the first alarm (``sweep_mismatch`` shows how much).  DTG: ``s(t) =
  max |eta - 1|`` over the monitored ratios of both axes after learning; ``T`` is the
  half-width of a band symmetric about 1 (the paper's 0.5/1.5 is ``T = 0.5``).
  ``sweep_mismatch`` is the fraction of samples where ``s > T_config`` disagrees with the
  FMU's own alarm (0 when the reconstruction is exact).

Approximated in the sweep: the detection filter's isolation bank can also raise
``df.detected``; only the main residual alarms are swept.  Isolation and DTG
classification are not re-evaluated at other thresholds.

System runs (``channel = "system"``, the DTG as the aircraft's pitch gyro): one
Diagnoser runs both channels, and each is a witness of its own: the DTG channel's
``dtg.alarm`` (judged from the end of learning) and the detection filter's
``df.detected`` (from the end of calibration).  The record keeps both under
``witnesses`` (detected, delay, false alarms, fault-free time, the DTG class and the
isolated sensor, type and size of the detection filter); the top-level fields judge
"either witness" so the usual tables still apply; ``diagnosed`` is the detection
filter's isolated sensor.  No threshold sweep.  *Conditions* (``[conditions.NAME]``)
vary the flight of any class: manoeuvres (the scenario's ``[[manoeuvres]]`` entries)
and parameter overrides (e.g. turbulence), each with a ``group`` ("level",
"manoeuvre") that the summary compares.  A run is flown with the same seed under every
condition (a paired comparison) unless its class says ``condition_seeds = "disjoint"``.

Side by side, df and dtg (issue 16): a class may list ``witnesses``, Diagnoser instances
judged in the same run, each with its own rule, e.g. ``diag`` (the project's rule) and
``paper`` (the paper's).  ``witness_copies`` adds a witness to the base scenario as a copy
of ``diagnoser`` (same FMU, parameters and files, a copy of every connection into it, so
both see the same signals) with its own ``parameters``/``files`` (a setting replaces the
original's, in either table) and its own sweep grid ``thresholds`` in its rule's units.
The campaign adds the copy rather than shipping two-Diagnoser base scenarios: one base
scenario stays the single source of the chain (and of the seed scenarios' checks), the
two rules cannot drift apart in their connections, and the paper's settings are read in
the campaign file.  Each witness is judged exactly as a single Diagnoser of its rule
would be (:func:`judge_diagnoser`): DF paper rule (``df.decision = 0``): any main-residual
alarm, isolated sensor, sweep on the k-of-n statistic in sigma; DF sequential:
``df.detected`` episodes, isolated sensor, type, size, sweep on the CUSUM; DTG paper
(``dtg.classifier = "paper"``): the ratio band, the nearest decade signature's name, sweep
on ``|eta - 1|``; DTG pattern: class and axis, sweep on the residual tests.  The record
keeps each under ``witnesses`` (with its grid), the top level is the first witness's, and
the summary splits it into one record per witness (class ``<class>/<witness>``, channel
``df/<witness>``, ``dtg/<witness>``), so every table (detection, isolation/class right,
false alarms, delays, confusion matrix, threshold sweep) has a row per rule.  The seed
does not depend on the witnesses (the same noise with or without the copy, which does
not change the first Diagnoser's record); the run id does, so records of a single-rule
campaign are never mixed with two-rule ones.  A paper DTG witness needs the decade
signatures and the pattern witness its library: ``libraries`` names further files
learned first, like ``signatures_training`` (e.g. ``{ "dtg_signatures.json" =
"../scenarios/training" }`` next to ``dtg_patterns.json``).

Grey-prediction runs (``channel = "grey"``, the HRG): the class's ``witnesses`` are
Diagnoser instances that watch the same faulty signal with different decision rules
(e.g. the paper's fixed threshold and the project's calibrated detector), each judged
on its own ``grey.alarm`` from its first ready sample (``grey.prediction_valid`` and not
``grey.calibrating``: the window is full and, if calibrated, sigma is learned).  The
record keeps each under ``witnesses`` with its own threshold sweep; the summary splits a
grey record into one record per witness (class ``<class>/<witness>``, channel
``grey/<witness>``), so every table has a row per rule.  The grey channel names no
fault kind: ``diagnosed`` is None and isolation/classification does not apply.  Sweep
``T`` in multiples of the rule's threshold.  A fixed-threshold rule (the paper's,
``grey.decision = 0``) is *replayed*: the library's detector
(:class:`gyrodiag.grey.GreyFaultDetector`, the FMU's own code) is run on the recorded
input ``grey.y`` with threshold ``T · grey.threshold``, substitutions and clearing
included, so every point is exact; ``sweep_mismatch`` is the replay at ``T = 1``
against the FMU's alarm (0 when the replay is faithful).  A calibrated rule is rebuilt
from ``s(t) = grey.statistic`` (its CUSUM over its threshold and the lagged step test's
``|z|`` over its threshold), exact only up to the first alarm: in alarm the predictor is
fed substitutes and the CUSUM holds the alarm down to half its threshold.

Modules
-------
This module is the campaigns' front: it re-exports the names of the modules that do the
work, by role: :mod:`~gyrodiag_harness.campaigns.spec` (the spec format, :func:`load_campaign`,
:class:`RunSpec`), :mod:`~gyrodiag_harness.campaigns.expand` (spec to runs, :func:`select`, a run
to its scenario), :mod:`~gyrodiag_harness.campaigns.judge` (a run's signals to its record,
:func:`simulate_run`), :mod:`~gyrodiag_harness.campaigns.supervise` (a run in a process of its
own), :mod:`~gyrodiag_harness.campaigns.execute` (pools, resume, interruption,
:func:`run_campaign`) and :mod:`~gyrodiag_harness.campaigns.records` (run records on disk).
"""

from __future__ import annotations

import sys

from gyrodiag_harness.campaigns.execute import (
    CampaignInterrupted,
    CampaignOutcome,
    preflight_runs,
    prepare,
    run_campaign,
)
from gyrodiag_harness.campaigns.expand import (
    add_witness_copies,
    build_scenario,
    campaign_fmu_dir,
    expand_runs,
    select,
)
from gyrodiag_harness.campaigns.judge import (
    DF_TYPE_NAMES,
    EXPECTED_DF_TYPE,
    GreyReplay,
    alarm_statistic,
    grey_replay,
    judge,
    judge_diagnoser,
    judge_grey_witness,
    simulate_run,
)
from gyrodiag_harness.campaigns.judge import _band_statistic as _band_statistic
from gyrodiag_harness.campaigns.judge import _df_sequential as _df_sequential
from gyrodiag_harness.campaigns.judge import _judge_system as _judge_system
from gyrodiag_harness.campaigns.judge import _kth_largest_window as _kth_largest_window
from gyrodiag_harness.campaigns.records import CampaignOutput, load_campaign_output, load_records
from gyrodiag_harness.campaigns.spec import (
    AIRCRAFT_SENSORS,
    DEFAULT_RUNNER,
    DEFAULT_THRESHOLDS,
    GREY_SIGNALS,
    MAGNITUDE_PARAMETER,
    SYSTEM_WITNESSES,
    WITNESS_CHANNELS,
    CampaignSpec,
    Channel,
    Condition,
    FaultClass,
    Nominal,
    RunSpec,
    Sweep,
    WitnessCopy,
    load_campaign,
)
from gyrodiag_harness.campaigns.supervise import (
    PARENT_PID_ENV,
    REPO_ROOT,
    RUN_TMP_PREFIX,
    execute_run,
)
from gyrodiag_harness.cosim.supervision import ORPHAN_POLL_S

__all__ = [
    "AIRCRAFT_SENSORS", "DEFAULT_RUNNER", "DEFAULT_THRESHOLDS", "DF_TYPE_NAMES",
    "EXPECTED_DF_TYPE", "GREY_SIGNALS", "MAGNITUDE_PARAMETER", "ORPHAN_POLL_S",
    "PARENT_PID_ENV", "REPO_ROOT", "RUN_TMP_PREFIX", "SYSTEM_WITNESSES", "WITNESS_CHANNELS",
    "CampaignInterrupted", "CampaignOutcome", "CampaignOutput", "CampaignSpec", "Channel",
    "Condition", "FaultClass", "GreyReplay", "Nominal", "RunSpec", "Sweep", "WitnessCopy",
    "add_witness_copies", "alarm_statistic", "build_scenario", "campaign_fmu_dir",
    "execute_run", "expand_runs", "grey_replay", "judge", "judge_diagnoser",
    "judge_grey_witness", "load_campaign", "load_campaign_output", "load_records",
    "preflight_runs", "prepare", "run_campaign", "select", "simulate_run",
]

if __name__ == "__main__":
    # the run processes' entry moved to gyrodiag_harness.campaigns.supervise
    from gyrodiag_harness.campaigns.supervise import child_entry

    child_entry(sys.argv)
