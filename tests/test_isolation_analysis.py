"""Isolability of the seed aircraft's sensors: checks docs/methods.md §4's claims numerically."""

from __future__ import annotations

import numpy as np
import pytest

from gyrodiag.df.filter import design_detection_filter
from gyrodiag.df.isolation import (
    design_observer_bank,
    isolability_analysis,
    place_observer_gain,
)
from gyrodiag.df.plant import PAPER_EIGENVALUES, seed_aircraft

MODEL = seed_aircraft()
A, B, C = MODEL.A, MODEL.B, MODEL.C
NAMES = MODEL.output_names  # v, alpha, q, theta, gamma, h


@pytest.fixture(scope="module")
def report():
    k = design_detection_filter(A, C, np.eye(5), PAPER_EIGENVALUES)
    return isolability_analysis(A, C, NAMES, K=k)


def test_signatures_of_v_and_h_are_zero(report):
    for name in ("v", "h"):
        entry = report.sensor(name)
        np.testing.assert_allclose(entry.bias_signature, 0.0, atol=1e-12)
        assert not entry.bias_steady_state_detectable
        # A bias on v or h equals C x̄ with A x̄ = 0: no observer can see it in steady state.
        assert entry.bias_indistinguishable_from_state
    for name in ("alpha", "q", "theta", "gamma"):
        entry = report.sensor(name)
        assert entry.bias_steady_state_detectable
        assert not entry.bias_indistinguishable_from_state


def test_signature_values_by_hand(report):
    # A − K C = diag(λ): s_i = q_i + C Λ⁻¹ K q_i; for q: K[:, 2] = [0, −1.5122, −0.0241, 1, 0].
    k_q = report.K[:, 2]
    np.testing.assert_allclose(k_q, [0.0, -1.5122, -0.0241, 1.0, 0.0], atol=1e-12)
    expected = np.eye(6)[2] + C @ (k_q / PAPER_EIGENVALUES)
    np.testing.assert_allclose(report.signatures[:, 2], expected, atol=1e-12)
    np.testing.assert_allclose(
        report.signatures[:, 2], [0.0, 0.7561, 1.00803, -0.25, -1.0061, 0.0], atol=1e-5
    )


def test_onset_transient_time_constants(report):
    # K q_v = e_v excites only the λ = −1 mode, K q_h = 5 e_h only λ = −5.
    assert report.sensor("v").transient_time_constant_s == pytest.approx(1.0, abs=1e-9)
    assert report.sensor("h").transient_time_constant_s == pytest.approx(0.2, abs=1e-9)
    # q's column of K excites α, q, θ modes (λ = −2, −3, −4): slowest 0.5 s.
    assert report.sensor("q").transient_time_constant_s == pytest.approx(0.5, abs=1e-9)


def test_alpha_theta_gamma_collinear_q_apart(report):
    i = {n: k for k, n in enumerate(NAMES)}
    cos = np.abs(report.cosines)
    # docs/methods.md §4 claims |cos| > 0.98 among α, θ, γ: computed 0.9888, 0.9961, 0.9960.
    assert cos[i["alpha"], i["theta"]] == pytest.approx(0.98878, abs=1e-4)
    assert cos[i["alpha"], i["gamma"]] == pytest.approx(0.99607, abs=1e-4)
    assert cos[i["theta"], i["gamma"]] == pytest.approx(0.99604, abs=1e-4)
    for other in ("alpha", "theta", "gamma"):
        assert cos[i["q"], i[other]] < 0.06
    assert np.isnan(report.cosines[i["v"], i["q"]])
    assert report.sensor("q").direction_isolable_from == ("alpha", "theta", "gamma")
    assert report.sensor("alpha").direction_isolable_from == ("q",)
    assert report.sensor("v").direction_isolable_from == ()


def test_redundancy_flags(report):
    # v and h: nobody else sees them (docs/methods.md §4); α, q, θ, γ: observable without them.
    assert [report.sensor(n).redundant for n in NAMES] == [False, True, True, True, True, False]


def test_bank_patterns_isolate_alpha_q_theta_gamma(report):
    for idx, name in enumerate(NAMES):
        entry = report.sensor(name)
        pattern = np.array(entry.bank_pattern)
        if name in ("v", "h"):
            assert not pattern.any()
            assert entry.bank_isolable_from == ()
        else:
            # Every observer but the one excluding this sensor keeps a steady signature.
            assert not pattern[idx]
            assert pattern.sum() == 5
            assert set(entry.bank_isolable_from) == set(NAMES) - {name}
    # Weakest steady q-bias response of any bank observer (per unit bias).
    q_col = report.bank_signatures[:, 2]
    assert q_col[2] == 0.0
    assert np.delete(q_col, 2).min() > 0.7


def test_parity_relation_and_text(report):
    w = report.parity_relations
    assert w.shape == (1, 6)
    np.testing.assert_allclose(w[0] @ C, 0.0, atol=1e-12)
    text = report.to_text()
    assert "parity relation" in text
    assert "analytically redundant (observable without it) = False" in text
    assert "0.9888" in text


def test_default_gain_equals_paper_specification():
    default = isolability_analysis(A, C, NAMES)
    np.testing.assert_allclose(
        np.sort(default.closed_loop_eigenvalues.real), np.sort(PAPER_EIGENVALUES), atol=1e-9
    )


def test_analysis_rejects_bad_arguments():
    with pytest.raises(ValueError, match="sensor_names"):
        isolability_analysis(A, C, NAMES[:5])
    with pytest.raises(ValueError, match="K must"):
        isolability_analysis(A, C, NAMES, K=np.zeros((5, 6)))
    with pytest.raises(ValueError, match="collinear_cos"):
        isolability_analysis(A, C, NAMES, collinear_cos=1.5)


def test_bank_design_observable_subspaces_and_poles():
    dt = 0.01
    bank = design_observer_bank(A, B, C, dt)
    assert [b.n_observable for b in bank] == [4, 5, 5, 5, 5, 4]
    assert [b.estimates_excluded for b in bank] == [False, True, True, True, True, False]
    for b in bank:
        eig = np.sort(np.abs(np.linalg.eigvals(b.observer.closed_loop_matrix)))
        want = np.sort(np.exp(-np.arange(1.0, b.n_observable + 1.0) * dt))
        np.testing.assert_allclose(eig, want, atol=1e-9)
        assert b.excluded not in b.used


def test_place_observer_gain_with_redundant_outputs():
    # C has a parity row (rank 5 < 6 rows): plain place() would reject Cᵀ.
    poles = -np.arange(1.0, 6.0) * 2.0
    gain = place_observer_gain(A, C, poles)
    np.testing.assert_allclose(np.sort(np.linalg.eigvals(A - gain @ C).real), np.sort(poles),
                               atol=1e-8)
    with pytest.raises(ValueError, match="C must not be zero"):
        place_observer_gain(A, np.zeros((2, 5)), poles)
