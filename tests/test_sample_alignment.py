"""Sample alignment of the Diagnoser's inputs (Jacobi masters, issue 12).

Library: the DTG channel's case-rate pairing (fixed delay and the opt-in aligner), the
detection filter's sensor skew; harness: the parameters derived from a coupling plan.
The FMU side is the seed scenario ``system_jacobi_doublet_torquer`` (a scenario item of
this suite) and the invalid-parameter cases of tests/test_system_diagnosis.py.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "fmu_src"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from _system_chain import PitchCommand, run_chain  # noqa: E402

from gyrodiag.df.channel import DFChannel, DFChannelConfig  # noqa: E402
from gyrodiag.dtg.alignment import CaseRateAligner  # noqa: E402
from gyrodiag.dtg.channel import DTGChannel, DTGChannelConfig  # noqa: E402
from gyrodiag_harness.cosim.master import plan_coupling  # noqa: E402
from gyrodiag_harness.cosim.scenario import Connection, load_scenario  # noqa: E402
from gyrodiag_harness.cosim.timing import timing_parameters  # noqa: E402

T = 1e-3
#: The system scenarios' DTG channel with the ratio band alone (no pattern library).
DTG = dict(classifier="paper", forgetting=0.9998, learn_start_s=2.0, learn_end_s=10.0,
           low=0.93, high=1.07, persistence_k=100, persistence_n=200, case_rate="central")
EDGE_S = 12.0


@pytest.fixture(scope="module")
def chain() -> dict[str, np.ndarray]:
    """0.1 rad doublets from 12 s in σ_w 1.5 m/s turbulence (the Jacobi check's case)."""
    return run_chain(16.0, command=PitchCommand(3, 0.1, start=EDGE_S, pulse=0.5, period=5.0),
                     sigma_w=1.5)


def _dtg_rows(o: dict[str, np.ndarray], shift: int) -> np.ndarray:
    """Voltages of sample k with the second gyro's rate of sample k + shift (shift > 0:
    the rate arrives ahead, as under Jacobi; the ends repeat the last sample)."""
    n = o["y_q"].size
    idx = np.clip(np.arange(n) + shift, 0, n - 1)
    return np.column_stack([o["Utx"], o["Uty"], o["Ux"], o["Uy"], np.zeros(n),
                            o["y_q"][idx]])


def _run(rows: np.ndarray, **kw) -> tuple[DTGChannel, list]:
    ch = DTGChannel(DTGChannelConfig(**{**DTG, **kw}))
    return ch, [ch.update(*r) for r in rows]


def _alarm_times(outs: list) -> np.ndarray:
    return (np.flatnonzero([o.alarm for o in outs]) + 1) * T


# -------------------------------------------------------------------- DTG, fixed delay
def test_a_case_rate_one_sample_ahead_alarms_at_the_first_edge(chain) -> None:
    """The failure under Jacobi, in the library: one sample of misalignment is invisible
    in level flight and alarms for good within 0.5 s of the first doublet edge
    (measured 12.11 s); aligned, the channel is silent."""
    _, aligned = _run(_dtg_rows(chain, 0))
    assert not any(o.alarm for o in aligned)
    _, shifted = _run(_dtg_rows(chain, 1))
    times = _alarm_times(shifted)
    assert times.size > 1000 and EDGE_S < times[0] < EDGE_S + 0.5, times[:3]


@pytest.mark.parametrize("shift", [1, 2, -1])
def test_the_configured_delay_restores_the_aligned_identification(chain, shift) -> None:
    """With d = shift the channel identifies what it identifies on aligned data: θ after
    the edges equal to 1e-6 (only the first samples differ, where the shifted record
    starts one rate sample off), no alarm. A negative d holds the voltages back: every
    output describes the sample |d| earlier."""
    ref_ch, aligned = _run(_dtg_rows(chain, 0))
    ch, outs = _run(_dtg_rows(chain, shift), case_rate_delay_samples=shift)
    assert ch.case_rate_delay == shift and ch.case_rate_switches == 0
    assert not any(o.alarm for o in outs)
    lag = max(0, -shift)
    theta = np.array([o.theta for o in outs[lag:]])
    ref = np.array([o.theta for o in aligned[:len(aligned) - lag]])
    k = int(EDGE_S / T)
    np.testing.assert_allclose(theta[k:], ref[k:], rtol=1e-6)
    np.testing.assert_allclose(ch.theta0, ref_ch.theta0, rtol=1e-6)


# --------------------------------------------------------------- DTG, opt-in aligner
@pytest.mark.parametrize("shift", [0, 1, -2])
def test_the_aligner_finds_the_pairing_and_stays_silent(chain, shift) -> None:
    """case_rate_align_max = 2 in turbulence: the pairing is found (once, no flapping),
    the channel stays silent through the edges; aligned data are left alone."""
    ch, outs = _run(_dtg_rows(chain, shift), case_rate_align_max=2)
    assert ch.case_rate_delay == shift
    assert ch.case_rate_switches == (0 if shift == 0 else 1)
    assert not any(o.alarm for o in outs)


def test_the_aligner_state_round_trip_continues_exactly(chain) -> None:
    """Saved just before the first edge (queue and normal equations included) and
    restored into a new channel, the run goes on bit for bit, switch included."""
    rows = _dtg_rows(chain, 1)
    k = int(EDGE_S / T) - 5
    _, outs = _run(rows, case_rate_align_max=2)
    first = DTGChannel(DTGChannelConfig(**{**DTG, "case_rate_align_max": 2}))
    for r in rows[:k]:
        first.update(*r)
    second = DTGChannel(DTGChannelConfig(**{**DTG, "case_rate_align_max": 2}))
    second.set_state(first.get_state())
    rest = [second.update(*r) for r in rows[k:]]
    np.testing.assert_array_equal([o.theta for o in rest], [o.theta for o in outs[k:]])
    assert second.case_rate_delay == 1 and second.case_rate_switches == 1
    # a channel without the aligner refuses the state
    with pytest.raises(ValueError, match="case_rate_align_max"):
        DTGChannel(DTGChannelConfig(**DTG)).set_state(first.get_state())


def test_aligner_rss_prefers_the_right_pairing_after_an_edge(chain) -> None:
    """Known answer of the model selection: after the first edge the right pairing's
    residual sum of squares is the least, the neighbours' above 1.2 times it (measured
    1.32 and 1.28 50 ms after the edge, 3.6 and 2.2 two samples off)."""
    from gyrodiag.common.prefilter import ButterworthPrefilter

    rows = _dtg_rows(chain, 1)
    f = ButterworthPrefilter(6, 50.0, 1.0 / T, 6)
    al = CaseRateAligner(T, max_delay=2, hold_samples=10**9)
    for r in rows[: int((EDGE_S + 0.05) / T)]:
        al.update(tuple(f.step(tuple(r))))
    rss = al.rss / al.rss.min()
    assert int(np.argmin(al.rss)) - 2 == 1
    assert rss[2] > 1.2 and rss[4] > 1.2 and rss[0] > 2.0, rss


@pytest.mark.parametrize(("kw", "match"), [
    ({"case_rate_delay_samples": 3, "case_rate_align_max": 2}, "case_rate_delay_samples"),
    ({"case_rate_delay_samples": 51}, "case_rate_delay_samples"),
    ({"case_rate_delay_samples": 1.5}, "case_rate_delay_samples"),
    ({"case_rate_align_max": 51}, "case_rate_align_max"),
    ({"case_rate_align_max": -1}, "case_rate_align_max"),
    ({"case_rate_align_max": 5, "case_rate_lookahead_s": 0.003}, "case_rate_lookahead_s"),
    ({"case_rate_align_max": 2, "case_rate_lookahead_s": 0.0}, "case_rate_lookahead_s"),
])
def test_alignment_settings_are_validated(kw, match) -> None:
    with pytest.raises((ValueError, TypeError), match=match):
        DTGChannelConfig(**{**DTG, **kw}).validate()


def test_aligner_arguments_are_validated() -> None:
    with pytest.raises(ValueError, match="max_delay"):
        CaseRateAligner(T, max_delay=0)
    with pytest.raises(ValueError, match="delay"):
        CaseRateAligner(T, max_delay=1, delay=2)
    with pytest.raises(ValueError, match="ratio"):
        CaseRateAligner(T, ratio=1.0)


# ------------------------------------------------------------------ DF, sensor skew
def _df(o: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    u = np.column_stack([np.zeros_like(o["elevator"]), o["elevator"]])
    y = np.column_stack([o["y_v"], o["y_alpha"], o["y_q"], o["y_theta"], o["y_gamma"],
                         o["y_h"]])
    return u, y


@pytest.mark.parametrize("decision", ["paper", "sequential"])
def test_sensor_skew_undoes_a_late_sensor_exactly(chain, decision) -> None:
    """q arriving one sample after the other sensors (as the DTG read-out under Jacobi)
    with sensor_delay_samples[2] = 1 gives the aligned run's outputs one sample later,
    to the bit; without it the filter sees a q error of q̇·T at every edge."""
    u, y = _df(chain)
    late = y.copy()
    late[1:, 2] = y[:-1, 2]
    cfg = dict(sample_period_s=T, decision=decision, calibrate_s=8.0, burn_in_s=2.0,
               align_auto=False)
    ref = DFChannel(DFChannelConfig(**cfg))
    skew = DFChannel(DFChannelConfig(**cfg, sensor_delay_samples=[0, 0, 1, 0, 0, 0]))
    a = [ref.update(u[k], y[k]) for k in range(u.shape[0] - 1)]
    b = [skew.update(u[k], late[k]) for k in range(u.shape[0])]
    np.testing.assert_array_equal([o.residual for o in b[1:]], [o.residual for o in a])
    assert [o.detected for o in b[1:]] == [o.detected for o in a]


def test_sensor_skew_state_round_trip_and_validation(chain) -> None:
    u, y = _df(chain)
    cfg = dict(sample_period_s=T, decision="sequential", calibrate_s=1.0, burn_in_s=0.2,
               align_auto=False, sensor_delay_samples=[0, 0, 2, 0, 0, 0])
    first = DFChannel(DFChannelConfig(**cfg))
    for k in range(1500):
        first.update(u[k], y[k])
    second = DFChannel(DFChannelConfig(**cfg))
    second.set_state(first.get_state())
    for k in range(1500, 1600):
        np.testing.assert_array_equal(first.update(u[k], y[k]).residual,
                                      second.update(u[k], y[k]).residual)
    with pytest.raises(ValueError, match="sensor_delay_samples must have 6"):
        DFChannelConfig(**{**cfg, "sensor_delay_samples": [0, 1]}).validate()
    with pytest.raises(ValueError, match=r"sensor_delay_samples\[2\]"):
        DFChannelConfig(**{**cfg, "sensor_delay_samples": [0, 0, -1, 0, 0, 0]}).validate()
    with pytest.raises(ValueError, match="skew"):
        DFChannel(DFChannelConfig(**{**cfg, "sensor_delay_samples": None})).set_state(
            first.get_state())


# ------------------------------------------------------------------ harness timing
SYSTEM = ROOT / "scenarios" / "system_doublet_torquer_turbulence.toml"


def test_gauss_seidel_in_topological_order_needs_no_alignment() -> None:
    s = load_scenario(SYSTEM)
    assert timing_parameters(s, plan_coupling(s).delayed) == {}


def test_jacobi_delays_the_dtg_voltages_and_the_readout_by_one_step() -> None:
    s = load_scenario(SYSTEM).model_copy(update={"coupling": "jacobi"})
    assert timing_parameters(s, plan_coupling(s).delayed) == {
        "diag": {"dtg.case_rate_delay_samples": 1, "df.sensor_delay[3]": 1}}


def test_one_more_fmu_on_the_gyro_path_adds_one_more_step() -> None:
    """An FMU between the aircraft and the DTG (e.g. a fault injector on the rate) under
    Jacobi: the voltages are two steps older than the case rate, the read-out too."""
    s = load_scenario(SYSTEM)
    conns = [c for c in s.connections if c.to != "dtg.omega_y"]
    conns += [Connection(**{"from": "aircraft.x_q", "to": "relay.u"}),
              Connection(**{"from": "relay.y", "to": "dtg.omega_y"})]
    fmus = {**s.fmus, "relay": s.fmus["controller"]}
    s = s.model_construct(**{**dict(s), "fmus": fmus, "connections": conns,
                             "coupling": "jacobi"})
    assert timing_parameters(s, s.connections) == {
        "diag": {"dtg.case_rate_delay_samples": 2, "df.sensor_delay[3]": 2}}


def test_alignment_states_survive_the_fmu_state_encoding(chain) -> None:
    """fmi2GetFMUstate serialises the channels' states as JSON (gd_fmu_base.encode): the
    aligner's queue and normal equations and the detection filter's skew line come back
    and the runs go on bit for bit."""
    import json

    from gd_fmu_base import decode, encode

    rows = _dtg_rows(chain, 1)
    k = int(EDGE_S / T) + 100
    cfg = DTGChannelConfig(**{**DTG, "case_rate_align_max": 2})
    first = DTGChannel(cfg)
    for r in rows[:k]:
        first.update(*r)
    second = DTGChannel(cfg)
    second.set_state(decode(json.loads(json.dumps(encode(first.get_state())))))
    a = [first.update(*r).theta for r in rows[k:k + 2000]]
    b = [second.update(*r).theta for r in rows[k:k + 2000]]
    np.testing.assert_array_equal(a, b)
    assert second.case_rate_delay == 1

    u, y = _df(chain)
    dcfg = DFChannelConfig(sample_period_s=T, decision="paper", calibrate_s=5.0,
                           align_auto=False, sensor_delay_samples=[0, 0, 1, 0, 0, 0])
    c = DFChannel(dcfg)
    for j in range(6000):
        c.update(u[j], y[j])
    d = DFChannel(dcfg)
    d.set_state(decode(json.loads(json.dumps(encode(c.get_state())))))
    for j in range(6000, 7000):
        np.testing.assert_array_equal(c.update(u[j], y[j]).residual,
                                      d.update(u[j], y[j]).residual)
