"""``python -m gyrodiag_harness compare-results A B``: are two results folders the same?

For "no change of behaviour" checks (issue 31): run the same job before and after a
change, then compare the two output folders.  Two kinds of folder are understood:

* a **runs folder**, written by ``all``, ``verify`` or ``run`` (one sub-folder with
  ``run.json`` per scenario, ``junit.xml``): the same set of runs (scenarios, and the
  training runs under ``training/``); every run's ``run.json`` (fault windows, samples,
  storage, error ...); every recorded signal, bit for bit (same names in the same order,
  same lengths, same values, NaN equal to NaN), with the first differing sample and the
  largest absolute difference; every expectation's verdict as ``junit.xml`` holds it
  (pass / fail / skipped / error and its message, which carries the measured value);
  the other files (the learned libraries ``dtg_*.json`` as JSON, text files line by
  line);
* a **campaign folder** (``campaign`` or ``campaign-summary`` output: ``campaign.json``
  and ``runs/``, or only ``summary.json``): ``campaign.json`` (the planned run ids), every
  run record (verdicts, detections, delays, threshold sweeps) and ``summary.json`` (the
  pooled figures).

Fields that legitimately differ from one run to the next (wall times, absolute paths,
timestamps, ...) and files rendered for people (``report.html``, plots) are left out;
:data:`IGNORED` is the complete list and the command prints it.  ``--rtol``/``--atol``
(default 0: exact) loosen the comparison of signal samples and JSON numbers to
``|a - b| <= atol + rtol * |b|``.

Exit status: 0 identical, 1 different (a capped list of differences), 2 bad input (a
folder missing or not a results folder, or two folders of different kinds).

From Python: :func:`compare_results` returns a :class:`Comparison`.
"""

from __future__ import annotations

import argparse
import fnmatch
import json
import logging
import math
import re
import xml.etree.ElementTree as ET
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from gyrodiag_harness.cli.common import EXIT_FAILED, EXIT_OK, EXIT_USAGE
from gyrodiag_harness.cosim.results import CSV_FILE, META_FILE, SIGNALS_FILE, RunResult

__all__ = ["ANYWHERE_KEYS", "IGNORED", "Comparison", "Ignored", "ResultsFolderError",
           "add_parser", "compare_results"]

log = logging.getLogger("gyrodiag_harness.cli")

JUNIT_FILE = "junit.xml"
CAMPAIGN_FILE = "campaign.json"
SUMMARY_FILE = "summary.json"
RUNS_DIR = "runs"
#: Differences listed by the command unless ``--max-diffs`` says otherwise.
DEFAULT_MAX_DIFFS = 50


@dataclass(frozen=True)
class Ignored:
    """What the comparison leaves out: in files matching ``files`` (a glob on the path
    relative to the folder, ``/``-separated), the JSON key path ``key`` (dotted, ``*``
    for any one key or list index; ``None``: the whole file), and why."""

    files: str
    key: str | None
    reason: str

    def describe(self) -> str:
        what = "whole file" if self.key is None else self.key
        return f"{self.files}: {what}: {self.reason}"


#: Everything :func:`compare_results` does not compare (printed by the command).
IGNORED: tuple[Ignored, ...] = (
    Ignored("**/run.json", "wall_time_s", "wall-clock time of the run"),
    Ignored(JUNIT_FILE, "@time", "testsuite/testcase wall times"),
    Ignored("**/*.html", None, "rendered for people: timestamp, wall times, plots; verdicts "
                            "and figures are compared in junit.xml / summary.json"),
    Ignored("**/*.png", None, "plots (matplotlib output, version-dependent bytes)"),
    Ignored("summary.md", None, "rendered from summary.json (compared); campaign-summary's "
                                "table shows wall-time run hours"),
    Ignored(CAMPAIGN_FILE, "base_dir", "absolute path of the spec's folder"),
    Ignored(f"{RUNS_DIR}/*.json", "wall_s", "wall-clock time of the run"),
    Ignored(f"{RUNS_DIR}/*.json", "sim_wall_s", "wall-clock time of the co-simulation"),
    Ignored(f"{RUNS_DIR}/*.json", "run.scenario", "absolute path of the base scenario "
                                                  "(the run id holds its relative path)"),
    Ignored(f"{RUNS_DIR}/*.json", "run.fmu_dir", "absolute path of the FMU folder"),
    Ignored(f"{RUNS_DIR}/*.json", "run.results_dir", "absolute path of the output folder"),
    Ignored(SUMMARY_FILE, "campaigns.*.run_hours", "the runs' wall times summed"),
    Ignored(SUMMARY_FILE, "campaigns.*.folder", "campaign-summary: path of each campaign "
                                                "folder as given"),
    Ignored("**/.*", None, "hidden files and folders (temporary files of atomic writes)"),
)

#: JSON keys left out at any depth of any file: no writer of this version writes them,
#: they are here so that adding one (a host name, a commit id, an FMU hash, a time
#: stamp) does not read as a change of behaviour.
ANYWHERE_KEYS: frozenset[str] = frozenset({
    "timestamp", "time_stamp", "written_at", "started_at", "finished_at", "hostname",
    "git_commit", "git_describe", "commit_id", "fmu_hash", "fmu_hashes", "fmu_sha256",
})

#: With a tolerance, how signals are stored may differ too (e.g. float32 vs float64).
_STORAGE_KEYS = ("signal_storage", "rounded_signals", "signals_precision")


_KIND_NAMES = {"runs": "runs (all / verify / run)", "campaign": "campaign output",
               "campaign-summary": "campaign-summary output"}


class ResultsFolderError(ValueError):
    """A path given to :func:`compare_results` is no results folder (exit status 2)."""

    def __init__(self, path: Path, message: str) -> None:
        super().__init__(f"{path}: {message}")
        self.path = path


@dataclass
class Comparison:
    """Outcome of :func:`compare_results`.

    ``differences`` holds one human-readable line per difference (empty: identical),
    ``ignored`` the lines of what was left out, ``counts`` what was compared.
    """

    a: Path
    b: Path
    kind: str
    rtol: float = 0.0
    atol: float = 0.0
    differences: list[str] = field(default_factory=list)
    ignored: list[str] = field(default_factory=list)
    counts: dict[str, int] = field(default_factory=dict)

    @property
    def identical(self) -> bool:
        return not self.differences

    def count(self, what: str, n: int = 1) -> None:
        self.counts[what] = self.counts.get(what, 0) + n

    def render(self, max_diffs: int = DEFAULT_MAX_DIFFS) -> str:
        """The report the command prints: folders, what was ignored, what was compared,
        the verdict and at most ``max_diffs`` differences."""
        tol = ("exact (bit for bit, NaN == NaN)" if self.rtol == 0 and self.atol == 0
               else f"|a - b| <= {self.atol:g} + {self.rtol:g} * |b|")
        kind = _KIND_NAMES.get(self.kind, self.kind)
        lines = [f"comparing two {kind} folders, numbers {tol}",
                 f"  A: {self.a}", f"  B: {self.b}",
                 "not compared (legitimately different):"]
        lines += [f"  - {text}" for text in self.ignored]
        lines.append("  - JSON keys anywhere: " + ", ".join(sorted(ANYWHERE_KEYS)))
        lines.append("compared: " + (", ".join(f"{n} {what}" for what, n in self.counts.items())
                                     or "nothing"))
        if self.identical:
            lines.append("IDENTICAL")
            return "\n".join(lines)
        n = len(self.differences)
        lines.append(f"DIFFERENT: {n} difference{'s' if n != 1 else ''}"
                     + (f" (the first {max_diffs} listed)" if n > max_diffs else ""))
        lines += [f"  {d}" for d in self.differences[:max_diffs]]
        if n > max_diffs:
            lines.append(f"  ... and {n - max_diffs} more (--max-diffs)")
        return "\n".join(lines)


# ---------------------------------------------------------------------------- the entry
def compare_results(a: Path | str, b: Path | str, *, rtol: float = 0.0,
                    atol: float = 0.0) -> Comparison:
    """Compare two results folders (module doc); never modifies them.

    Raises
    ------
    ResultsFolderError
        ``a`` or ``b`` is missing, not a folder, not a results folder, or the two are
        of different kinds; the message names the path.
    """
    if rtol < 0 or atol < 0 or math.isnan(rtol) or math.isnan(atol):
        raise ValueError(f"rtol and atol must be >= 0, got {rtol}, {atol}")
    a, b = Path(a), Path(b)
    kind_a, kind_b = _kind(a), _kind(b)
    if kind_a != kind_b:
        raise ResultsFolderError(b, f"a {kind_b} folder, but {a} is a {kind_a} folder: "
                                    "compare folders of the same kind")
    cmp = Comparison(a, b, kind_a, rtol, atol)
    ignored = list(IGNORED)
    if rtol or atol:
        ignored += [Ignored("**/run.json", k, "how signals are stored (a tolerance is given)")
                    for k in _STORAGE_KEYS]
    cmp.ignored = [i.describe() for i in ignored]
    _Comparer(cmp, ignored).run()
    return cmp


def _kind(folder: Path) -> str:
    if not folder.exists():
        raise ResultsFolderError(folder, "no such folder")
    if not folder.is_dir():
        raise ResultsFolderError(folder, "not a folder")
    if (folder / CAMPAIGN_FILE).is_file():
        return "campaign"
    if (folder / SUMMARY_FILE).is_file():
        return "campaign-summary"
    if (folder / JUNIT_FILE).is_file() or any(
            (d / META_FILE).is_file() for d in folder.iterdir() if d.is_dir()):
        return "runs"
    raise ResultsFolderError(folder, f"not a results folder (no {JUNIT_FILE}, no "
                                     f"<scenario>/{META_FILE}, no {CAMPAIGN_FILE} or "
                                     f"{SUMMARY_FILE})")


def _visible(path: Path, root: Path) -> bool:
    return not any(part.startswith(".") for part in path.relative_to(root).parts)


def _run_dirs(folder: Path) -> Iterator[Path]:
    for meta in sorted(folder.rglob(META_FILE)):
        if _visible(meta, folder) and meta.parent != folder:
            yield meta.parent


# ------------------------------------------------------------------------ the comparer
class _Comparer:
    def __init__(self, cmp: Comparison, ignored: list[Ignored]) -> None:
        self.cmp = cmp
        self.ignored = ignored
        self.exact = cmp.rtol == 0 and cmp.atol == 0

    def diff(self, text: str) -> None:
        self.cmp.differences.append(text)

    def file_ignored(self, rel: str) -> bool:
        return any(i.key is None and _match(rel, i.files) for i in self.ignored)

    def key_patterns(self, rel: str) -> list[list[str]]:
        return [i.key.split(".") for i in self.ignored
                if i.key is not None and _match(rel, i.files)]

    # -------------------------------------------------------------------------- kinds
    def run(self) -> None:
        a, b = self.cmp.a, self.cmp.b
        handled: set[str] = set()
        if self.cmp.kind == "runs":
            handled = self.runs_folder(a, b)
        elif self.cmp.kind == "campaign":
            handled = self.campaign_folder(a, b)
        self.other_files(a, b, handled)

    def runs_folder(self, a: Path, b: Path) -> set[str]:
        runs_a = {d.relative_to(a).as_posix(): d for d in _run_dirs(a)}
        runs_b = {d.relative_to(b).as_posix(): d for d in _run_dirs(b)}
        self.only("run", runs_a, runs_b)
        handled: set[str] = set()
        for name in sorted(set(runs_a) & set(runs_b)):
            self.cmp.count("runs")
            self.one_run(name, runs_a[name], runs_b[name])
        for name in set(runs_a) | set(runs_b):
            handled.update(f"{name}/{f}" for f in (META_FILE, SIGNALS_FILE, CSV_FILE))
        self.junit(a / JUNIT_FILE, b / JUNIT_FILE)
        handled.add(JUNIT_FILE)
        return handled

    def campaign_folder(self, a: Path, b: Path) -> set[str]:
        self.json_file(CAMPAIGN_FILE, a / CAMPAIGN_FILE, b / CAMPAIGN_FILE)
        recs_a = {p.stem: p for p in sorted((a / RUNS_DIR).glob("*.json"))
                  if _visible(p, a)}
        recs_b = {p.stem: p for p in sorted((b / RUNS_DIR).glob("*.json"))
                  if _visible(p, b)}
        self.only("run record", recs_a, recs_b)
        for rid in sorted(set(recs_a) & set(recs_b)):
            self.cmp.count("run records")
            self.json_file(f"{RUNS_DIR}/{rid}.json", recs_a[rid], recs_b[rid], count=False)
        handled = {CAMPAIGN_FILE} | {f"{RUNS_DIR}/{r}.json" for r in set(recs_a) | set(recs_b)}
        return handled

    def only(self, what: str, a: dict[str, Any], b: dict[str, Any]) -> None:
        for name in sorted(set(a) - set(b)):
            self.diff(f"{name}: {what} only in A")
        for name in sorted(set(b) - set(a)):
            self.diff(f"{name}: {what} only in B")

    # --------------------------------------------------------------------------- runs
    def one_run(self, name: str, a: Path, b: Path) -> None:
        meta_a = self.read_json(a / META_FILE, name)
        meta_b = self.read_json(b / META_FILE, name)
        if meta_a is None or meta_b is None:
            return
        self.json_values(f"{name}/{META_FILE}", meta_a, meta_b)
        dropped_a, dropped_b = meta_a.get("signals_dropped"), meta_b.get("signals_dropped")
        if dropped_a or dropped_b:
            if bool(dropped_a) != bool(dropped_b):  # said by the run.json comparison too
                self.diff(f"{name}: signals kept in {'B' if dropped_a else 'A'} only")
            return
        try:
            run_a = RunResult.load(a)
        except (OSError, ValueError) as exc:
            self.diff(f"{name}: signals of A unreadable: {exc}")
            return
        try:
            run_b = RunResult.load(b)
        except (OSError, ValueError) as exc:
            self.diff(f"{name}: signals of B unreadable: {exc}")
            return
        self.signals(name, run_a, run_b)

    def signals(self, name: str, a: RunResult, b: RunResult) -> None:
        names_a, names_b = list(a.signals), list(b.signals)
        for s in [n for n in names_a if n not in b.signals]:
            self.diff(f"{name}: signal {s} only in A")
        for s in [n for n in names_b if n not in a.signals]:
            self.diff(f"{name}: signal {s} only in B")
        common = [n for n in names_a if n in b.signals]
        if common != [n for n in names_b if n in a.signals]:
            self.diff(f"{name}: signals recorded in another order")
        time_a = np.asarray(a.time, dtype=float)
        for s, col_a, col_b in [("time", a.time, b.time),
                                *((n, a.signals[n], b.signals[n]) for n in common)]:
            self.cmp.count("signals")
            text = self.arrays(np.asarray(col_a, dtype=float), np.asarray(col_b, dtype=float),
                               time_a)
            if text:
                self.diff(f"{name}: signal {s}: {text}")

    def arrays(self, a: np.ndarray, b: np.ndarray, time: np.ndarray) -> str | None:
        """None when equal, else what differs: first sample, count, largest difference."""
        if a.shape != b.shape:
            return f"{a.size} samples in A, {b.size} in B"
        self.cmp.count("samples", a.size)
        nan_a, nan_b = np.isnan(a), np.isnan(b)
        if self.exact:
            bits_a = np.ascontiguousarray(a, dtype="<f8").view("<u8")
            bits_b = np.ascontiguousarray(b, dtype="<f8").view("<u8")
            same = (bits_a == bits_b) | (nan_a & nan_b)
        else:
            with np.errstate(invalid="ignore", over="ignore"):
                same = ((a == b) | (nan_a & nan_b)
                        | (np.abs(a - b) <= self.cmp.atol + self.cmp.rtol * np.abs(b)))
        bad = np.flatnonzero(~same)
        if bad.size == 0:
            return None
        k = int(bad[0])
        at = f"t = {float(time[k])!r} s" if k < time.size else "?"
        finite = np.isfinite(a) & np.isfinite(b)
        with np.errstate(over="ignore"):
            delta = np.abs(a[finite] - b[finite])
        worst = float(delta.max()) if delta.size else 0.0
        if np.any(nan_a != nan_b) or np.any(~finite & ~nan_a & ~nan_b & (a != b)):
            worst = math.inf  # NaN on one side only, or different infinities
        return (f"{bad.size} of {a.size} samples differ, first at {at} (sample {k}): "
                f"{float(a[k])!r} in A, {float(b[k])!r} in B; max |A - B| = {worst:.6g}")

    # ------------------------------------------------------------------------- junit
    def junit(self, a: Path, b: Path) -> None:
        if not a.is_file() and not b.is_file():
            return
        if not (a.is_file() and b.is_file()):
            self.diff(f"{JUNIT_FILE}: only in {'A' if a.is_file() else 'B'}")
            return
        try:
            va, vb = _junit_verdicts(a), _junit_verdicts(b)
        except (ET.ParseError, OSError) as exc:
            self.diff(f"{JUNIT_FILE}: unreadable: {exc}")
            return
        self.only(f"scenario in {JUNIT_FILE}", va, vb)
        for scenario in [s for s in va if s in vb]:
            self.cmp.count("verdicts")
            ca, cb = va[scenario], vb[scenario]
            self.only(f"testcase in {JUNIT_FILE}", {f"{scenario}: {c!r}": 0 for c in ca},
                      {f"{scenario}: {c!r}": 0 for c in cb})
            for case in [c for c in ca if c in cb]:
                self.cmp.count("expectations" if case != "run" else "run outcomes")
                (sa, ma), (sb, mb) = ca[case], cb[case]
                if (sa, ma) == (sb, mb):
                    continue
                what = "run" if case == "run" else f"expectation {case!r}"
                verdict = f"{sa} in both" if sa == sb else f"{sa.upper()} in A, {sb.upper()} in B"
                self.diff(f"{scenario}: {what}: {verdict}; A: {_measured(ma)} | "
                          f"B: {_measured(mb)}")

    # --------------------------------------------------------------------- JSON, text
    def read_json(self, path: Path, label: str) -> Any:
        try:
            return json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            self.diff(f"{label}: unreadable {path.name}: {exc}")
            return None

    def json_file(self, rel: str, a: Path, b: Path, count: bool = True) -> None:
        if not (a.is_file() and b.is_file()):
            if a.is_file() or b.is_file():
                self.diff(f"{rel}: only in {'A' if a.is_file() else 'B'}")
            return
        if count:
            self.cmp.count("files")
        va, vb = self.read_json(a, f"{rel} (A)"), self.read_json(b, f"{rel} (B)")
        if va is not None and vb is not None:
            self.json_values(rel, va, vb)

    def json_values(self, rel: str, a: Any, b: Any) -> None:
        patterns = self.key_patterns(rel)
        for path, text in _json_diff(a, b, [], patterns, self.cmp.rtol, self.cmp.atol):
            where = ".".join(path) or "(top level)"
            self.diff(f"{rel}: {where}: {text}")

    def other_files(self, a: Path, b: Path, handled: set[str]) -> None:
        files_a = {p.relative_to(a).as_posix(): p for p in a.rglob("*") if p.is_file()}
        files_b = {p.relative_to(b).as_posix(): p for p in b.rglob("*") if p.is_file()}
        rest = {r for r in set(files_a) | set(files_b)
                if r not in handled and not self.file_ignored(r)
                and not any(part.startswith(".") for part in r.split("/"))}
        self.only("file", {r: 0 for r in rest if r in files_a},
                  {r: 0 for r in rest if r in files_b})
        for rel in sorted(r for r in rest if r in files_a and r in files_b):
            pa, pb = files_a[rel], files_b[rel]
            if rel.endswith(".json"):
                self.json_file(rel, pa, pb)
                continue
            self.cmp.count("files")
            da, db = pa.read_bytes(), pb.read_bytes()
            if da == db:
                continue
            try:
                lines_a = da.decode("utf-8").splitlines()
                lines_b = db.decode("utf-8").splitlines()
            except UnicodeDecodeError:
                self.diff(f"{rel}: contents differ ({len(da)} bytes in A, {len(db)} in B)")
                continue
            k = next((i for i, (x, y) in enumerate(zip(lines_a, lines_b, strict=False))
                      if x != y), min(len(lines_a), len(lines_b)))
            self.diff(f"{rel}: line {k + 1} differs: {_line(lines_a, k)!r} in A, "
                      f"{_line(lines_b, k)!r} in B")


def _line(lines: list[str], k: int) -> str:
    return _clip(lines[k]) if k < len(lines) else "<end of file>"


def _clip(text: str, n: int = 160) -> str:
    text = " ".join(text.split())
    return text if len(text) <= n else text[:n - 3] + "..."


def _match(rel: str, pattern: str) -> bool:
    """``rel`` (``/``-separated) matches ``pattern``: ``**/NAME`` a file or folder name
    at any depth, else the whole path part by part (``*`` within one part)."""
    parts = rel.split("/")
    if pattern.startswith("**/"):
        return any(fnmatch.fnmatchcase(part, pattern[3:]) for part in parts)
    pat = pattern.split("/")
    return len(pat) == len(parts) and all(fnmatch.fnmatchcase(x, p)
                                          for x, p in zip(parts, pat, strict=True))


def _ignored_key(path: list[str], patterns: list[list[str]]) -> bool:
    if path and path[-1] in ANYWHERE_KEYS:
        return True
    return any(len(p) == len(path) and all(x in ("*", y) for x, y in zip(p, path, strict=True))
               for p in patterns)


def _json_diff(a: Any, b: Any, path: list[str], patterns: list[list[str]], rtol: float,
               atol: float) -> Iterator[tuple[list[str], str]]:
    if _ignored_key(path, patterns):
        return
    if isinstance(a, dict) and isinstance(b, dict):
        for k in a:
            if k not in b and not _ignored_key([*path, k], patterns):
                yield [*path, k], "only in A"
        for k in b:
            if k not in a and not _ignored_key([*path, k], patterns):
                yield [*path, k], "only in B"
        for k in a:
            if k in b:
                yield from _json_diff(a[k], b[k], [*path, k], patterns, rtol, atol)
        return
    if isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            yield path, f"{len(a)} items in A, {len(b)} in B"
        for i, (x, y) in enumerate(zip(a, b, strict=False)):
            yield from _json_diff(x, y, [*path, str(i)], patterns, rtol, atol)
        return
    if _same_json_value(a, b, rtol, atol):
        return
    yield path, f"{_clip(repr(a))} in A, {_clip(repr(b))} in B"


def _same_json_value(a: Any, b: Any, rtol: float, atol: float) -> bool:
    number = (int, float)
    if (isinstance(a, number) and isinstance(b, number)
            and not isinstance(a, bool) and not isinstance(b, bool)):
        if type(a) is not type(b) and not (rtol or atol):
            return False  # 1 and 1.0 are written differently
        if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
            return True
        return a == b or abs(a - b) <= atol + rtol * abs(b)
    return type(a) is type(b) and a == b


def _junit_verdicts(path: Path) -> dict[str, dict[str, tuple[str, str]]]:
    """Scenario → testcase name → (status, message) of a junit.xml of the harness."""
    root = ET.parse(path).getroot()
    out: dict[str, dict[str, tuple[str, str]]] = {}
    for suite in root.iter("testsuite"):
        cases = out.setdefault(suite.get("name", ""), {})
        for case in suite.iter("testcase"):
            error, failure = case.find("error"), case.find("failure")
            skipped, stdout = case.find("skipped"), case.find("system-out")
            if error is not None:
                status, message = "error", error.text or error.get("message", "")
            elif failure is not None:
                status, message = "fail", failure.get("message", "")
            elif skipped is not None:
                status, message = "skipped", skipped.get("message", "")
            else:
                status, message = "pass", ""
            if stdout is not None and stdout.text and status != "error":
                message = stdout.text
            name = case.get("name", "")
            n = 2
            while name in cases:  # an expectation named like another testcase ("run")
                name, n = f"{case.get('name', '')} #{n}", n + 1
            cases[name] = (status, message)
    return out


_MEASURED = re.compile(r"measured[: ]\s*(.*)", re.DOTALL)


def _measured(message: str) -> str:
    """The measured part of an expectation's message (all of it if it has none)."""
    m = _MEASURED.search(message)
    return _clip("measured " + m.group(1) if m else message or "(no message)")


# ---------------------------------------------------------------------------- command
def _non_negative(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not value >= 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {text}")
    return value


def add_parser(sub: Any) -> None:
    """Register ``compare-results`` on the CLI's sub-parsers."""
    p = sub.add_parser(
        "compare-results",
        help="compare two results folders (all/verify/run, or campaign): verdicts, "
             "signals bit for bit, campaign summaries; exit 0 identical, 1 different")
    p.add_argument("a", type=Path, metavar="A", help="results folder (before)")
    p.add_argument("b", type=Path, metavar="B", help="results folder (after)")
    p.add_argument("--rtol", type=_non_negative, default=0.0,
                   help="relative tolerance on signal samples and JSON numbers (default 0)")
    p.add_argument("--atol", type=_non_negative, default=0.0,
                   help="absolute tolerance on signal samples and JSON numbers (default 0)")
    p.add_argument("--max-diffs", type=int, default=DEFAULT_MAX_DIFFS, metavar="N",
                   help=f"differences listed at most (default {DEFAULT_MAX_DIFFS})")
    p.set_defaults(func=cmd_compare_results)


def cmd_compare_results(args: argparse.Namespace) -> int:
    try:
        cmp = compare_results(args.a, args.b, rtol=args.rtol, atol=args.atol)
    except ResultsFolderError as exc:
        log.error("%s", exc)
        return EXIT_USAGE
    log.info("%s", cmp.render(max(0, args.max_diffs)))
    return EXIT_OK if cmp.identical else EXIT_FAILED
