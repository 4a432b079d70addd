"""JUnit XML, HTML report and plots of harness runs (headless)."""

from __future__ import annotations

import base64
import html
import re
import xml.etree.ElementTree as ET
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest
from matplotlib.figure import Figure

from gyrodiag_harness.cosim.results import FaultWindow, RunResult
from gyrodiag_harness.reporting import plots, report
from gyrodiag_harness.verification.expectations import verify_results

STEP_S = 0.01
THETA_NOM = (1.9951, 0.9959, -0.0288, -0.0303, 0.0002)  # docs/methods.md §2, paper's θ_nom


def _full_run() -> RunResult:
    """Every signal family the plot selection knows, 20 s at 10 ms, fault from 10 s."""
    rng = np.random.default_rng(1)
    t = np.arange(2001) * STEP_S
    sig: dict[str, np.ndarray] = {
        "diag.df.detected": (t >= 10.37).astype(float),
        "diag.df.isolated_sensor": np.where(t >= 10.5, 3.0, 0.0),
        "diag.df.residual[1]": rng.normal(0.0, 0.01, t.size),
        "diag.df.residual[2]": rng.normal(0.0, 0.01, t.size) + 0.2 * (t >= 10.0),
        "diag.df.alarm[2]": (t >= 10.37).astype(float),
        "hrg.voltage": 2.0 + np.sin(t),
        "diag.grey.alarm": np.zeros(t.size),
        "diag.dtg.first_alarm_time": np.full(t.size, -1.0),  # not a flag
    }
    sig["diag.grey.prediction"] = sig["hrg.voltage"] * (1.0 + 1e-3 * rng.normal(size=t.size))
    for i, nominal in enumerate(THETA_NOM, start=1):
        # RLS-like start-up transient, then noise about the nominal value
        sig[f"diag.dtg.theta_x[{i}]"] = nominal + 5.0 * np.exp(-20 * t) + 0.01 * rng.normal(
            size=t.size)
        sig[f"diag.dtg.theta_y[{i}]"] = nominal + 0.01 * rng.normal(size=t.size)
        sig[f"diag.dtg.theta0_used[{i}]"] = np.full(t.size, nominal)
    return RunResult("full", t, sig, [FaultWindow("q_bias", "inj.out_3", "bias", 10.0)],
                     STEP_S, None, 1.25, 20.0)


FULL_SCENARIO = {
    "name": "full",
    "description": "all plot families",
    "fmus": {"diag": {"fmu": "Diagnoser",
                      "parameters": {"df.threshold[1]": 0.05, "df.threshold[2]": 0.06,
                                     "grey.decision": 0, "grey.threshold": 0.05}}},
    "connections": [{"from": "hrg.voltage", "to": "diag.grey.y"}],
    "expect": [
        {"kind": "detected_within", "signal": "diag.df.detected", "fault": "q_bias",
         "max_delay_s": 0.5},
        {"kind": "detected_within", "signal": "diag.df.detected", "fault": "q_bias",
         "max_delay_s": 0.3, "name": "fast <detection> & more"},
        {"kind": "value_at_end", "signal": "diag.df.isolated_sensor", "equals": 3},
    ],
}


@pytest.fixture(scope="module")
def full_run() -> RunResult:
    return _full_run()


def _broken_run() -> RunResult:
    t = np.arange(3) * STEP_S
    return RunResult("broken", t, {"diag.df.detected": np.zeros(3)}, [], STEP_S,
                     "instance diag: doStep at t=0.02:\n\x1b[31mFATAL\x1b[0m <nan> & stop", 0.1)


BROKEN_SCENARIO = {"name": "broken", "expect": [
    {"kind": "no_alarm_before", "signal": "diag.df.detected"},
    {"kind": "value_at_end", "signal": "diag.df.detected", "equals": 0},
]}
MISSING_SCENARIO = {"name": "missing", "expect": [
    {"kind": "no_alarm_before", "signal": "diag.df.detected"}]}


@pytest.fixture(scope="module")
def written(full_run: RunResult, tmp_path_factory: pytest.TempPathFactory) -> dict:
    runs = [full_run, _broken_run()]
    scenarios = [FULL_SCENARIO, BROKEN_SCENARIO, MISSING_SCENARIO]
    verdicts = verify_results(runs, scenarios)
    out = tmp_path_factory.mktemp("report")
    paths = report.write_report(verdicts, runs, out, scenarios=scenarios)
    return {"verdicts": verdicts, "paths": paths, "out": out}


# ------------------------------------------------------------------- JUnit
def test_write_report_uses_default_file_names(written: dict) -> None:
    assert written["paths"].junit == written["out"] / "junit.xml"
    assert written["paths"].html == written["out"] / "report.html"
    assert written["paths"].junit.is_file() and written["paths"].html.is_file()


def test_junit_counts_failures_and_errors(written: dict) -> None:
    root = ET.parse(written["paths"].junit).getroot()
    assert root.tag == "testsuites"
    # tests: expectations + one run case per scenario = (3+1) + (2+1) + (1+1); the
    # expectations of the broken and the missing run are not evaluated (skipped): their
    # reason is said once, by the run case's error
    assert (root.get("tests"), root.get("failures"), root.get("errors"),
            root.get("skipped")) == ("9", "1", "2", "3")
    suites = {s.get("name"): s for s in root.findall("testsuite")}
    assert list(suites) == ["full", "broken", "missing"]
    full = suites["full"]
    assert (full.get("tests"), full.get("failures"), full.get("errors")) == ("4", "1", "0")
    assert full.get("time") == "1.250"
    failed = [c for c in full.findall("testcase") if c.find("failure") is not None]
    assert [c.get("name") for c in failed] == ["fast <detection> & more"]
    assert "measured delay 0.37 s" in failed[0].find("failure").get("message")
    passed_case = full.findall("testcase")[1]
    assert "measured delay 0.37 s" in passed_case.find("system-out").text


def test_junit_run_errors_survive_control_characters(written: dict) -> None:
    root = ET.parse(written["paths"].junit).getroot()
    broken = next(s for s in root.findall("testsuite") if s.get("name") == "broken")
    run_case = broken.find("testcase[@name='run']")
    error = run_case.find("error")
    assert error.get("message") == "instance diag: doStep at t=0.02:"
    assert "FATAL" in error.text and "<nan> & stop" in error.text and "\x1b" not in error.text
    assert (broken.get("failures"), broken.get("errors"), broken.get("skipped")) == (
        "0", "1", "2")
    skipped = [c.find("skipped") for c in broken.findall("testcase") if c.get("name") != "run"]
    assert [e.get("message") for e in skipped] == ["not evaluated: the run did not complete"] * 2
    assert all("FATAL" not in c.find("system-out").text for c in broken.findall("testcase")
               if c.get("name") != "run")
    missing = next(s for s in root.findall("testsuite") if s.get("name") == "missing")
    assert "no run result" in missing.find("testcase[@name='run']/error").get("message")


# -------------------------------------------------------------------- HTML
class _Collector(HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.images: list[str] = []
        self.cells: list[str] = []
        self._in_td = False

    def handle_starttag(self, tag: str, attrs: list) -> None:
        if tag == "img":
            self.images.append(dict(attrs)["src"])
        self._in_td = tag == "td" or (self._in_td and tag != "tr")
        if tag == "td":
            self.cells.append("")

    def handle_endtag(self, tag: str) -> None:
        if tag == "td":
            self._in_td = False

    def handle_data(self, data: str) -> None:
        if self._in_td and self.cells:
            self.cells[-1] += data


def test_html_has_tables_and_embedded_plots(written: dict, full_run: RunResult) -> None:
    text = written["paths"].html.read_text(encoding="utf-8")
    page = _Collector()
    page.feed(text)
    # full run: one figure per channel (DTG, detection filter, grey); the broken run: the
    # timeline of its (all-zero) detection flag
    assert len(page.images) == 4
    for src in page.images:
        assert src.startswith("data:image/png;base64,")
        assert base64.b64decode(src.split(",", 1)[1])[:8] == b"\x89PNG\r\n\x1a\n"
    cells = page.cells
    assert "fast <detection> & more" in cells  # escaped in HTML, intact after parsing
    assert "detected_within(diag.df.detected, q_bias, 0.5 s)" in cells
    # no scenario passes; 2 expectations do; the full run FAILs (summary row and one
    # expectation), the broken run is an ERROR, the missing one NOT RUN, and the
    # expectations of both are NOT EVALUATED
    assert cells.count("PASS") == 2 and cells.count("FAIL") == 2
    assert cells.count("ERROR") == 1 and cells.count("NOT RUN") == 1
    assert cells.count("NOT EVALUATED") == 3
    assert "2/3" in cells and "0/2" in cells and "0/1" in cells
    assert "0.37" in cells  # metrics table: detection delay of diag.df.detected
    assert "<nan> & stop" in html.unescape(text) and "\x1b" not in text


def test_summary_metrics_rows(full_run: RunResult) -> None:
    rows = report.summary_metrics(full_run, FULL_SCENARIO)
    delay = next(r for r in rows if r.metric == "detection delay"
                 and r.subject == "diag.df.detected")
    assert delay.value == pytest.approx(0.37, abs=1e-9) and delay.unit == "s"
    fa = next(r for r in rows if r.metric == "false alarms" and r.subject == "diag.df.detected")
    assert fa.value == 0.0
    grey = next(r for r in rows if r.metric == "prediction error mean")
    assert grey.value == pytest.approx(0.1 * np.sqrt(2 / np.pi), rel=0.15)  # E|N(0,1e-3)|·100
    theta = next(r for r in rows if r.subject == "diag.dtg.theta_y[1]")
    assert theta.value == pytest.approx(THETA_NOM[0], abs=2e-3)
    assert theta.condition == "5 ≤ t ≤ 10 s"
    assert not any(r.subject == "diag.grey.alarm" and r.metric == "detection delay"
                   and r.value is not None for r in rows)


# ------------------------------------------------------------------- plots
def _spans(ax) -> list:
    return [p for p in ax.patches if p.get_alpha() == pytest.approx(0.15)]


def test_theta_plot_has_five_panels_like_the_paper(full_run: RunResult) -> None:
    fig = plots.plot_theta(full_run, "diag.dtg", sample_period_s=0.001)
    assert isinstance(fig, Figure)
    main = [ax for ax in fig.axes if ax.get_ylabel().startswith("θ")]
    assert [ax.get_ylabel() for ax in main] == ["θ1", "θ2", "θ3", "θ4", "θ5"]
    for ax in main:
        assert len(ax.get_lines()) == 3  # x axis, y axis, nominal θ0
        assert len(_spans(ax)) == 1
    lo, hi = main[0].get_ylim()
    assert lo < THETA_NOM[0] < hi and hi < 2.5  # the start-up transient (≈7) is clipped
    plots.figure_to_png(fig)


def test_plots_are_palette_pngs_that_look_the_same_in_a_third_of_the_space(
        full_run: RunResult) -> None:
    import io

    from PIL import Image

    fig = plots.plot_theta(full_run, "diag.dtg", sample_period_s=0.001)
    full, small = plots.figure_to_png(fig, colors=None), plots.figure_to_png(fig)
    with Image.open(io.BytesIO(full)) as a, Image.open(io.BytesIO(small)) as b:
        assert (a.mode, b.mode) == ("RGBA", "P") and a.size == b.size
        diff = np.abs(np.asarray(a.convert("RGB"), float) - np.asarray(b.convert("RGB"),
                                                                      float))
    print(f"theta plot: RGBA {len(full)} B, palette {len(small)} B, mean |diff| "
          f"{diff.mean():.3f} of 255, 99.9 % <= {np.percentile(diff, 99.9):.0f}")
    assert len(full) / len(small) >= 2.0
    assert diff.mean() < 0.5 and np.percentile(diff, 99.9) <= 24
    with pytest.raises(ValueError, match=r"colors must be 2\.\.256 or None, got 1000"):
        plots.figure_to_png(fig, colors=1000)


def test_residual_plot_thresholds_and_fault_shading(full_run: RunResult) -> None:
    fig = plots.plot_signals_with_faults(
        full_run, ["diag.df.residual[1]", "diag.df.residual[2]"],
        {"diag.df.residual[2]": 0.06})
    ax1, ax2 = fig.axes
    assert len(ax1.get_lines()) == 1 and len(ax2.get_lines()) == 3
    levels = sorted(float(np.unique(line.get_ydata())[0]) for line in ax2.get_lines()[1:])
    assert levels == [-0.06, 0.06]
    span = _spans(ax1)[0]
    assert span.get_x() == pytest.approx(10.0) and span.get_width() == pytest.approx(10.0)


def test_long_records_keep_spikes(full_run: RunResult) -> None:
    n = 200_001
    t = np.arange(n) * 1e-3
    y = np.zeros(n)
    y[123_457] = 7.0
    run = RunResult("long", t, {"a.alarm": y}, [], 1e-3)
    fig = plots.plot_signals_with_faults(run, ["a.alarm"])
    line = fig.axes[0].get_lines()[0]
    assert len(line.get_ydata()) <= 2 * plots.MAX_PLOT_POINTS
    assert float(np.max(line.get_ydata())) == 7.0


def test_grey_plot_error_and_threshold(full_run: RunResult) -> None:
    fig = plots.plot_grey_prediction(full_run, "diag.grey.prediction", "hrg.voltage",
                                     threshold=0.05)
    top, bottom = fig.axes
    assert len(top.get_lines()) == 2
    err = bottom.get_lines()[0].get_ydata()
    expected = np.abs(full_run.signals["hrg.voltage"] - full_run.signals["diag.grey.prediction"])
    np.testing.assert_allclose(err, expected)
    assert bottom.get_lines()[1].get_ydata()[0] == 0.05
    with pytest.raises(ValueError, match="measured or error"):
        plots.plot_grey_prediction(full_run, "diag.grey.prediction")


def test_one_figure_per_channel_with_its_lanes(full_run: RunResult) -> None:
    titles = [title for title, _ in plots.figures_for_result(full_run, FULL_SCENARIO)]
    assert titles == ["detection-filter channel — diag", "grey-prediction channel — diag",
                      "DTG channel — diag"]
    figs = dict(plots.figures_for_result(full_run, FULL_SCENARIO))
    df = figs["detection-filter channel — diag"]
    assert [ax.get_ylabel() for ax in df.axes] == ["r1", "r2", "detected", "isolated_sensor",
                                                   "alarm[2]"]
    dtg = figs["DTG channel — diag"]
    assert [ax.get_ylabel() for ax in dtg.axes] == ["θ1", "θ2", "θ3", "θ4", "θ5"]
    grey = figs["grey-prediction channel — diag"]
    assert [ax.get_ylabel() for ax in grey.axes] == ["signal", "|error|", "alarm"]
    # without the scenario the grey measurement and the thresholds are unknown
    figs = dict(plots.figures_for_result(full_run))
    grey = figs["grey-prediction channel — diag"]
    assert [ax.get_ylabel() for ax in grey.axes] == ["alarm"]
    df = figs["detection-filter channel — diag"]
    assert all(len(ax.get_lines()) == 1 for ax in df.axes[:2])


def test_residual_thresholds_from_scenario(full_run: RunResult) -> None:
    figs = dict(plots.figures_for_result(full_run, FULL_SCENARIO))
    ax1, ax2 = figs["detection-filter channel — diag"].axes[:2]
    assert float(ax1.get_lines()[1].get_ydata()[0]) == 0.05
    assert float(ax2.get_lines()[1].get_ydata()[0]) == 0.06


def test_residual_thresholds_from_the_diagnosers_threshold_output() -> None:
    t = np.arange(0.0, 2.0, 0.5)
    run = RunResult(
        scenario="thr", time=t, step_s=0.5,
        signals={
            "diag.df.residual[3]": np.array([0.0, 0.01, -0.02, 0.5]),
            "diag.df.threshold_in_use[3]": np.array([0.0, 0.0, 0.04, 0.04]),
        },
    )
    figs = dict(plots.figures_for_result(run))
    (ax,) = figs["detection-filter channel — diag"].axes
    upper = np.asarray(ax.get_lines()[1].get_ydata(), dtype=float)
    assert np.all(np.isnan(upper[:2]))  # nothing drawn while calibrating
    np.testing.assert_array_equal(upper[2:], [0.04, 0.04])


def test_residual_plot_is_not_squashed_by_a_start_up_transient() -> None:
    t = np.arange(0.0, 60.0, 0.01)
    residual = 1e-3 * np.sin(7.0 * t)
    residual[:50] = -0.25 * np.exp(-t[:50] / 0.1)  # observer start-up, 0.5 s
    run = RunResult(scenario="tr", time=t, step_s=0.01,
                    signals={"diag.df.residual[3]": residual,
                             "diag.df.threshold_in_use[3]": np.full(t.size, 5e-3)})
    (ax,) = dict(plots.figures_for_result(run))["detection-filter channel — diag"].axes
    lo, hi = ax.get_ylim()
    assert -0.05 < lo < -5e-3 and 5e-3 < hi < 0.05  # the thresholds stay readable


def test_write_html_standalone(tmp_path: Path) -> None:
    run = _broken_run()
    verdicts = verify_results([run], [BROKEN_SCENARIO])
    path = report.write_html(verdicts, [run], tmp_path / "sub" / "r.html")
    text = path.read_text(encoding="utf-8")
    assert text.startswith("<!DOCTYPE html>") and "0/1 scenarios passed" in text
    path_xml = report.write_junit(verdicts, tmp_path / "j.xml")
    assert ET.parse(path_xml).getroot().get("errors") == "1"


def test_disabled_theta_channel_and_flag_lane_order() -> None:
    t = np.arange(100) * STEP_S
    sig = {f"diag.dtg.theta_x[{i}]": np.zeros(t.size) for i in range(1, 6)}
    sig.update({f"inj.fault_active_{i}": np.zeros(t.size) for i in range(1, 21)})
    sig["diag.df.detected"] = (t >= 0.5).astype(float)
    run = RunResult("lanes", t, sig, [], STEP_S)
    # no DTG figure for an all-zero channel; the detection flag in its channel's figure
    (df_title, df), (_title, fig) = plots.figures_for_result(run)
    assert df_title == "detection-filter channel — diag"
    assert [ax.get_ylabel() for ax in df.axes] == ["detected"]
    lanes = [ax.get_ylabel() for ax in fig.axes]
    assert len(lanes) == plots.MAX_TIMELINE_LANES
    assert lanes[:2] == ["inj.fault_active_1", "inj.fault_active_2"]
    assert "4 constant flags not shown" in fig.get_suptitle()


def test_grey_plot_keeps_the_measurement_visible_when_prediction_diverges() -> None:
    t = np.arange(1000) * STEP_S
    y = 2.0 + np.sin(t)
    p = y.copy()
    p[500:] = np.exp(np.arange(500) * 0.05)  # a predictor fed its own output runs away
    run = RunResult("grey", t, {"d.y": y, "d.grey.prediction": p}, [], STEP_S)
    top, bottom = plots.plot_grey_prediction(run, "d.grey.prediction", "d.y",
                                             threshold=0.05).axes
    lo, hi = top.get_ylim()
    # measurement spans [1, 3]: shown with half its span as margin, prediction clipped
    assert lo == pytest.approx(0.0, abs=0.05) and hi == pytest.approx(4.0, abs=0.05)
    assert bottom.get_yscale() == "log"


# ------------------------------------------------------- plots people read (issue 15)
def _df_run(with_flag: bool) -> RunResult:
    """Detection filter: observer start-up, calibration to 8 s, a bias 20× the
    threshold from 10 s, six per-residual alarms."""
    rng = np.random.default_rng(5)
    t = np.arange(2001) * STEP_S
    r = rng.normal(0.0, 1e-3, t.size) - 0.25 * np.exp(-t / 0.3) + 0.1 * (t >= 10.0)
    sig = {"diag.df.residual[3]": r,
           "diag.df.threshold_in_use[3]": np.where(t >= 8.0, 5e-3, 0.0),
           "diag.df.detected": (t >= 10.0).astype(float)}
    sig.update({f"diag.df.alarm[{i}]": ((t >= 10.0) & (i in (2, 3))).astype(float)
                for i in range(1, 7)})
    if with_flag:
        sig["diag.df.calibrating"] = (t < 7.5).astype(float)
    return RunResult("df", t, sig, [FaultWindow("q_bias", "inj.out_3", "bias", 10.0)],
                     STEP_S)


def _grey_spans(ax) -> list:
    return [p for p in ax.patches if p.get_alpha() == pytest.approx(plots._STARTUP_ALPHA)]


def test_calibration_window_is_shaded_from_the_channels_own_outputs() -> None:
    # from the calibrating flag when recorded, else from the threshold being 0
    for with_flag, end in ((True, 7.5), (False, 8.0)):
        run = _df_run(with_flag)
        shades = plots.startup_shades(run, None, "diag", "df")
        assert [(s.label, s.start_s) for s in shades] == [("calibration", 0.0)]
        assert shades[0].end_s == pytest.approx(end)
        fig = dict(plots.figures_for_result(run))["detection-filter channel — diag"]
        for ax in fig.axes:
            (span,) = _grey_spans(ax)
            assert span.get_x() == pytest.approx(0.0) and span.get_width() == pytest.approx(end)
            assert len(_spans(ax)) == 1  # and the fault window
        assert "calibrating" not in [ax.get_ylabel() for ax in fig.axes]  # shaded instead
    # else from the scenario's parameters; a DTG learning window likewise
    bare = RunResult("x", np.arange(100) * STEP_S, {"d.df.residual[1]": np.ones(100),
                                                     "d.dtg.eta_x[1]": np.ones(100)}, [],
                     STEP_S)
    scenario = {"name": "x", "fmus": {"d": {"fmu": "Diagnoser", "parameters": {
        "df.calibrate_s": 0.6, "dtg.learn_start_s": 0.1, "dtg.learn_end_s": 0.4}}}}
    assert plots.startup_shades(bare, scenario, "d", "df") == [
        plots.Shade("calibration", 0.0, 0.6)]
    assert plots.startup_shades(bare, scenario, "d", "dtg") == [
        plots.Shade("θ0 learning", 0.1, 0.4)]
    assert plots.startup_shades(bare, None, "d", "dtg") == []


def test_residual_axis_shows_noise_against_threshold_and_the_fault_size() -> None:
    run = _df_run(with_flag=True)
    fig = dict(plots.figures_for_result(run))["detection-filter channel — diag"]
    residual = fig.axes[0]
    # a fault of 20 thresholds: linear within ± 2 thresholds, logarithmic beyond
    assert residual.get_yscale() == "symlog"
    lo, hi = residual.get_ylim()
    assert hi >= 0.1 and lo <= -0.1
    # the six alarms share one raster lane, indices 1..6 as ticks
    assert [ax.get_ylabel() for ax in fig.axes] == ["r3", "detected", "alarm[i]"]
    assert list(fig.axes[2].get_yticks()) == [1, 2, 3, 4, 5, 6]
    assert len(fig.axes[2].collections) == 6
    # without the fault: a linear axis from the post-calibration data, thresholds inside
    quiet = _df_run(with_flag=True)
    quiet.signals["diag.df.residual[3]"] = np.where(
        quiet.time >= 10.0, quiet.signals["diag.df.residual[3]"] - 0.1,
        quiet.signals["diag.df.residual[3]"])
    ax = dict(plots.figures_for_result(quiet))["detection-filter channel — diag"].axes[0]
    lo, hi = ax.get_ylim()
    assert ax.get_yscale() == "linear" and -0.01 < lo < -5e-3 and 5e-3 < hi < 0.01
    assert any("y clipped" in text.get_text() for text in ax.texts)  # the start-up


def test_legends_sit_below_the_panels_never_on_the_data(full_run: RunResult) -> None:
    for title, fig in plots.figures_for_result(full_run, FULL_SCENARIO):
        assert all(ax.get_legend() is None for ax in fig.axes), title
        (legend,) = fig.legends
        labels = [t.get_text() for t in legend.get_texts()]
        assert "fault: q_bias" in labels, (title, labels)
        fig.canvas.draw()
        box = legend.get_window_extent()
        lowest = min(ax.get_window_extent().y0 for ax in fig.axes)
        assert box.y1 <= lowest + 1.0, title  # entirely under the lowest panel


def test_titles_say_what_passed(full_run: RunResult) -> None:
    (verdict,) = verify_results([full_run], [FULL_SCENARIO])
    titles = [t for t, _ in plots.figures_for_result(full_run, FULL_SCENARIO, verdict)]
    # FULL_SCENARIO: two detected_within on df.detected (0.5 s passes, 0.3 s fails) and an
    # isolation check; nothing reads the grey or DTG signals
    assert titles == [
        "detection-filter channel — diag: 1 of 3 expectations FAILED: fast <detection> & "
        "more",
        "grey-prediction channel — diag: no expectation on it",
        "DTG channel — diag: no expectation on it"]
    broken = _broken_run()
    (v,) = verify_results([broken], [BROKEN_SCENARIO])
    broken.signals["diag.df.detected"] = np.array([0.0, 1.0, 1.0])
    ((title, _fig),) = plots.figures_for_result(broken, BROKEN_SCENARIO, v)
    assert title == ("detection-filter channel — diag: 2 expectations not evaluated "
                     "(run incomplete)")


def test_plots_drawn_in_worker_processes_give_the_page_drawn_here(
        written: dict, full_run: RunResult, tmp_path: Path) -> None:
    """Sections (tables and plots) rendered by two worker processes are the ones
    rendered in this process, byte for byte, in the verdicts' order."""
    runs = [full_run, _broken_run()]
    scenarios = [FULL_SCENARIO, BROKEN_SCENARIO, MISSING_SCENARIO]
    verdicts = written["verdicts"]
    here = report.write_html(verdicts, runs, tmp_path / "here.html", scenarios, workers=1)
    pool = report.write_html(verdicts, runs, tmp_path / "pool.html", scenarios, workers=2)

    def body(path: Path) -> str:
        return re.sub(r"generated [^<]* UTC", "", path.read_text(encoding="utf-8"))

    assert body(here) == body(pool)
    assert body(pool).count("data:image/png;base64,") >= 2


def test_report_names_both_witnesses_verdicts_on_one_root_cause(tmp_path: Path) -> None:
    """The report's "One root cause, independent witnesses" section: one row per
    witnesses_agree expectation, with the verdict and each witness's delay."""
    t = np.arange(3001) * 0.01
    run = RunResult("sys", t, {"diag.dtg.alarm": (t >= 20.05).astype(float),
                               "diag.df.detected": (t >= 20.3).astype(float),
                               "diag.df.isolated_sensor": np.where(t >= 20.3, 3.0, 0.0)},
                    [FaultWindow("spin", "dtg.spin_fraction", "physical", 20.0)], 0.01)
    scenario = {"name": "sys", "expect": [
        {"kind": "witnesses_agree", "name": "one root cause",
         "witnesses": ["diag.dtg.alarm", "diag.df.detected"], "fault": "spin",
         "max_delay_s": 1.0, "details": ["diag.df.isolated_sensor"]},
        {"kind": "witnesses_agree", "name": "too slow",
         "witnesses": ["diag.dtg.alarm", "diag.df.detected"], "fault": "spin",
         "max_delay_s": 0.2}]}
    verdicts = verify_results([run], [scenario])
    text = report.write_html(verdicts, [run], tmp_path / "r.html", [scenario],
                             workers=1).read_text(encoding="utf-8")
    section = text.split("One root cause, independent witnesses", 1)[1].split("<h2 id=", 1)[0]
    rows = re.findall(r"<tr>(.*?)</tr>", section, flags=re.S)[1:]
    assert len(rows) == 2
    assert "AGREE" in rows[0] and "DISAGREE" not in rows[0]
    assert "diag.dtg.alarm: detected after 0.05 s" in rows[0]
    assert "diag.df.detected: detected after 0.3 s" in rows[0]
    assert "diag.df.isolated_sensor = 3 at the end" in rows[0]
    assert "DISAGREE" in rows[1] and "the witnesses disagree" in rows[1]
    assert report.witness_table(verify_results([run], [{"name": "sys", "expect": []}])) == ""
