"""Reduced-order e-IOSS (ass:e-ioss) and delta-IOSS (Schiller et al. 2023) certificates."""

import json

import casadi as ca
import numpy as np
import pytest
from exact_rates import contraction_rate, kernel_rate

from uiest import CertificationError, ModelError, OptionError, System
from uiest.detectability import certify_delta_ioss, certify_reduced_ioss, certify_reduced_model, lmi
from uiest.estimators import MHEWeights, TwoStageWeights
from uiest.models import closed_form, crop_growth, linear

FAST = {"samples": 500}


def _linear_reduced(F):
    """z+ = F z + gamma[0] (1, 1) + 0.1 v, y = gamma: the output carries no information on z."""
    n = F.shape[0]
    z, g, u, v = ca.SX.sym("z", n), ca.SX.sym("g", 1), ca.SX.sym("u", 0), ca.SX.sym("v", 1)
    f = ca.Function("f", [z, g, u, v], [ca.DM(F) @ z + g[0] * np.ones(n) + 0.1 * v[0]])
    h = ca.Function("h", [z, g, v], [g])
    return f, h, {"z_bounds": (-np.ones(n), np.ones(n)), "gamma_bounds": (-1, 1), "v_bounds": (-0.1, 0.1)}


@pytest.mark.parametrize(
    ("F", "expected"),
    [
        (np.array([[0.5, 0.0], [0.0, 0.3]]), 0.25),
        (np.array([[0.5, 2.0], [0.0, 0.3]]), 0.25),  # non-normal: needs a non-identity P
        (np.array([[0.0, -0.6], [0.6, 0.0]]), 0.36),  # complex pair 0.6 e^(+-i pi/2)
    ],
)
def test_reduced_linear_mu_min_is_spectral_radius_squared(F, expected):
    f, h, bounds = _linear_reduced(F)
    cert = certify_reduced_ioss(f, h, **bounds, **FAST)
    assert cert.certified, cert.reason
    assert cert.mu_min == pytest.approx(expected, abs=1e-3)
    assert cert.verify(5000, seed=1).holds


def test_reduced_unstable_model_is_not_certified():
    f, h, bounds = _linear_reduced(np.array([[1.2, 0.0], [0.0, 0.3]]))
    cert = certify_reduced_ioss(f, h, **bounds, **FAST)
    assert not cert.certified and cert.status == "infeasible", cert.reason
    with pytest.raises(CertificationError):
        cert.min_horizon()
    assert np.isnan(cert.verify().worst_ratio)


def test_reduced_closed_form_certifies_with_itscontraction_rate():
    # the closed-form model's reduced model (module docstring): z+ = a(gamma - v) z + u, y = gamma
    a0, a1 = 0.5, 0.3
    z, g, u, v = (ca.SX.sym(s, 1) for s in "zguv")
    f = ca.Function("f", [z, g, u, v], [(a0 + a1 * ca.tanh(g - v)) * z + u])
    h = ca.Function("h", [z, g, v], [g])
    cert = certify_reduced_ioss(
        f, h, z_bounds=(-10, 10), gamma_bounds=(-10, 10), v_bounds=(-1e-2, 1e-2), u_bounds=(-1, 1)
    )
    assert cert.certified, cert.reason
    assert cert.mu_min == pytest.approx((a0 + abs(a1)) ** 2, abs=1e-3)
    n = cert.min_horizon()
    assert 4 * cert.c_x * cert.mu**n < 1 <= 4 * cert.c_x * cert.mu ** (n - 1)
    assert cert.verify(20_000, seed=3).holds
    # the constants of eq:p-eioss_quadratic are the scaled weights over mu lambda_min(P)
    lam = np.linalg.eigvalsh(cert.P_scaled)[0]
    assert cert.c_v == pytest.approx(cert.q[1] / (cert.mu * lam))
    data = json.loads(json.dumps(cert.to_dict()))
    assert data["kind"] == "reduced_eioss" and data["min_horizon"] == n


def test_reduced_given_mu_and_bad_input():
    f, h, bounds = _linear_reduced(np.diag([0.5, 0.3]))
    assert certify_reduced_ioss(f, h, **bounds, mu=0.5, **FAST).mu == 0.5
    below = certify_reduced_ioss(f, h, **bounds, mu=0.1, **FAST)
    assert not below.certified and below.status == "below the smallest rate"
    with pytest.raises(OptionError, match="mu"):
        certify_reduced_ioss(f, h, **bounds, mu=1.0)
    with pytest.raises(ModelError, match="h_sharp"):
        certify_reduced_ioss(f, f, **bounds)
    with pytest.raises(ModelError, match="z_bounds"):
        certify_reduced_ioss(f, h, **{**bounds, "z_bounds": (-np.inf, 1.0)})


def test_delta_ioss_unobservable_mode_sets_eta_min():
    # x1 (mode 0.6) is not measured, x2 (mode 0.3) is: eta_min = 0.6^2
    system = linear.linear_system(
        np.diag([0.6, 0.3]), [[1.0], [0.0]], [[0.0, 1.0]], x_bounds=(-1, 1), v_bounds=(-1e-2, 1e-2)
    )
    for structure in ("full", "identity"):
        cert = certify_delta_ioss(system, w_bounds=(-1, 1), structure=structure, **FAST)
        assert cert.certified, cert.reason
        assert cert.eta_min == pytest.approx(0.36, abs=1e-3)
        assert cert.verify(5000, seed=2).holds
    n = cert.min_horizon()
    assert 4 * cert.eta**n < 1 <= 4 * cert.eta ** (n - 1)
    with pytest.raises(OptionError, match="structure"):
        certify_delta_ioss(system, structure="diagonal")


def test_delta_ioss_closed_form():
    cert = certify_delta_ioss(closed_form.system(), w_bounds=(-1, 1))
    assert cert.certified, cert.reason
    assert cert.eta_min == pytest.approx(0.64, abs=1e-3)
    assert cert.verify(20_000, seed=4).holds
    assert cert.Q_w.shape == (1, 1) and cert.R.shape == (1, 1)
    data = json.loads(json.dumps(cert.to_dict()))
    assert data["kind"] == "delta_ioss" and data["structure"] == "full"


@pytest.mark.slow
def test_crop_certificates_hold_with_discounts_near_one():
    system = crop_growth.system()
    delta = certify_delta_ioss(system)  # w over the known range [0.965, 1]
    assert delta.certified, delta.reason
    assert 0.99 < delta.eta < 1.0 and delta.w_box == system.w_range
    assert delta.verify(5000).holds
    reduced = certify_reduced_model(crop_growth.reduction())
    assert reduced.certified, reduced.reason
    assert 0.99 < reduced.mu < 1.0
    assert reduced.verify(5000).holds


def test_bisect_rate_resolves_rates_near_one():
    for threshold in (0.3, 0.99, 1.0 - 3e-5):
        found = lmi.bisect_rate(lambda mu, t=threshold: lmi.FEASIBLE if mu >= t else lmi.INFEASIBLE)
        assert found.outcome == lmi.FEASIBLE and found.rate >= threshold
        assert found.rate - threshold <= max(1e-4, 0.011 * (1.0 - threshold))
    never = lmi.bisect_rate(lambda mu: lmi.INFEASIBLE)
    assert never.rate is None and never.outcome == lmi.INFEASIBLE


def test_bisect_rate_never_reports_a_solver_failure_as_infeasible():
    broken = lmi.bisect_rate(lambda mu: lmi.FAILED)
    assert broken.rate is None and broken.outcome == lmi.FAILED
    # failures near the answer end the bisection at the best rate proven, and say so
    threshold = 0.5

    def flaky(mu):
        if abs(mu - threshold) < 0.2 and mu != 1.0 - lmi.RATE_GAP:
            return lmi.FAILED
        return lmi.FEASIBLE if mu >= threshold else lmi.INFEASIBLE

    found = lmi.bisect_rate(flaky)
    assert found.outcome == lmi.FEASIBLE and found.rate >= threshold and found.failed_at
    assert "upper estimate" in found.note


@pytest.mark.slow
def test_certificates_share_one_interface():
    system = closed_form.system()
    delta = certify_delta_ioss(system, w_bounds=(-1, 1), **FAST)
    reduced = certify_reduced_model(closed_form.reduction(), **FAST)
    assert isinstance(MHEWeights.from_certificate(delta), MHEWeights)
    assert isinstance(TwoStageWeights.from_certificate(reduced), TwoStageWeights)
    for cert in (delta, reduced):
        assert cert.certified and cert.status == "certified" and cert.rate_min <= cert.rate < 1
        assert cert.min_horizon() >= 1 and cert.margin >= 0 and cert.sound and "exact by entries" in cert.coverage
        assert json.loads(json.dumps(cert.to_dict()))["certified"] is True
        assert not cert.falsification.refuted and cert.falsification.pairs >= 20_000
    sampled = certify_delta_ioss(system, w_bounds=(-1, 1), cover="sampled", **FAST)
    assert not sampled.certified and sampled.status == "holds at the samples, not proved", sampled.reason


def test_bisect_rate_with_a_failed_top_probe_decides_nothing():
    outcomes = {1.0 - lmi.RATE_GAP: lmi.FAILED}
    found = lmi.bisect_rate(lambda mu: outcomes.get(mu, lmi.INFEASIBLE))
    assert found.rate is None and found.outcome == lmi.FAILED


def test_a_dissipation_certificate_the_search_refutes_is_not_certified(monkeypatch):
    # the cover replaced by the Jacobian at one corner of X (x2's rate 0.2 where it reaches 0.8 elsewhere)
    import dataclasses

    from uiest.detectability import dissipation

    real = dissipation.covers.cover

    def one_corner(fun, box, **kwargs):
        found = real(fun, box, **kwargs)
        corner = np.asarray(fun(box.lower), dtype=float)[None]
        return dataclasses.replace(found, vertices=corner, samples=corner)

    monkeypatch.setattr(dissipation.covers, "cover", one_corner)
    cert = certify_delta_ioss(closed_form.system(), w_bounds=(-1, 1), **FAST)
    assert cert.status == "refuted" and not cert.certified, cert.reason
    assert cert.falsification.worst_ratio > 1.0 and "refuted: the pair" in cert.reason


@pytest.mark.slow
def test_crop_reduced_tradeoff_matches_the_exact_rates_at_each_bound_on_cond_p():
    from uiest.detectability.cover import cover

    cert = certify_reduced_model(crop_growth.reduction())
    table = cert.tradeoff()
    assert [row.max_condition for row in table.rows] == [1e6, 1e8, 1e10, 1e12]
    assert all(row.status == "certified" for row in table.rows), str(table)
    # the exact answer on the certificate's own cover (its output map sees one of the two reduced states), over the
    # points whose full state lies in X (the lifted domain: x is affine in (z_sharp, gamma, v) for the crop)
    assert cert.model.lift is not None
    J_fun, G_fun, domain = cert.model.covered_jacobians()
    vertices = cover(J_fun, domain, samples=4000, seed=0).vertices
    G = np.asarray(G_fun(domain.center), dtype=float)
    exact = [kernel_rate(vertices, G, row.max_condition) for row in table.rows]
    np.testing.assert_allclose([row.mu_min for row in table.rows], exact, atol=2e-3)
    # issue 33's independent figures (50-digit arithmetic, on the whole box) at 1e8 and 1e10: 0.985 and 0.866; the cut
    # domain's rates (0.9853, 0.8625) lie within two digits of them
    assert abs(table.rows[1].mu_min - 0.985) < 0.01 and abs(table.rows[2].mu_min - 0.866) < 0.01
    # a faster rate costs: the output weight and the noise gain grow with the bound, the rate falls
    mu_min = [row.mu_min for row in table.rows]
    assert mu_min == sorted(mu_min, reverse=True) and mu_min[-1] < 0.4 < 0.998 < mu_min[0]
    weights = [row.output_gain for row in table.rows]
    assert weights == sorted(weights) and weights[-1] > 1e6 * weights[0]
    gains = [np.max(row.noise_gain) for row in table.rows]
    assert gains == sorted(gains) and gains[-1] > 100 * gains[0]
    assert all(row.condition <= row.max_condition * (1 + 1e-6) for row in table.rows)
    text = str(table)
    assert "max cond(P)" in text and "1e+12" in text and "z2" in text
    frame = table.to_pandas()
    assert list(frame["max_condition"]) == [1e6, 1e8, 1e10, 1e12] and "noise_gain z1" in frame


@pytest.mark.slow
def test_the_bound_on_cond_p_is_an_argument_of_every_certify_function():
    f, h, bounds = _linear_reduced(np.array([[0.5, 2.0], [0.0, 0.3]]))
    system = linear.linear_system(np.diag([0.6, 0.3]), [[1.0], [0.0]], [[0.0, 1.0]], x_bounds=(-1, 1),
                                  v_bounds=(-1e-2, 1e-2))  # fmt: skip
    for bad in (1.0, 0.5, np.inf, float("nan"), True, "1e6"):
        with pytest.raises(OptionError, match="max_condition: expected a finite number > 1"):
            certify_reduced_ioss(f, h, **bounds, max_condition=bad, **FAST)
        with pytest.raises(OptionError, match="max_condition: expected a finite number > 1"):
            certify_delta_ioss(system, w_bounds=(-1, 1), max_condition=bad, **FAST)
    # the non-normal F (y carries nothing on z): mu_min(kappa) = min over cond(P) <= kappa of |P^1/2 F P^-1/2|^2
    for kappa in (10.0, 30.0, 100.0):
        tight = certify_reduced_ioss(f, h, **bounds, max_condition=kappa, **FAST)
        assert tight.certified and tight.condition <= kappa * (1 + 1e-6), tight.reason
        assert tight.mu_min == pytest.approx(contraction_rate(np.array([[0.5, 2.0], [0.0, 0.3]]), kappa), abs=1e-3)
        assert tight.verify(5000, seed=1).holds and f"cond(P) <= {kappa:g}" in tight.reason
    none = certify_reduced_ioss(f, h, **bounds, max_condition=4.0, **FAST)  # |F| >= 1 in every such norm
    assert none.status == "infeasible" and "cond(P) <= 4" in none.reason
    free = certify_reduced_ioss(f, h, **bounds, **FAST)
    assert free.mu_min == pytest.approx(0.25, abs=1e-3)
    with pytest.raises(OptionError, match="levels: expected a non-empty sequence"):
        free.tradeoff(levels=())
    with pytest.raises(OptionError, match="levels: expected a finite number > 1"):
        free.tradeoff(levels=(1e6, 0.5))


def test_a_solver_that_fails_is_never_reported_as_infeasible(monkeypatch):
    f, h, bounds = _linear_reduced(np.diag([0.5, 0.3]))
    monkeypatch.setattr(lmi, "solve", lambda problem: "solver_error")
    cert = certify_reduced_ioss(f, h, **bounds, **FAST)
    assert not cert.certified and cert.status == "solver failed", cert.reason
    monkeypatch.setattr(lmi, "solve", lambda problem: "optimal_inaccurate")  # no solution values: decides nothing
    delta = certify_delta_ioss(closed_form.system(), w_bounds=(-1, 1), **FAST)
    assert not delta.certified and delta.status == "solver failed", delta.reason


def test_dissipation_certificates_report_their_noise_gain_and_tabulate_after_pickling():
    import pickle

    f, h, bounds = _linear_reduced(np.array([[0.5, 2.0], [0.0, 0.3]]))
    cert = pickle.loads(pickle.dumps(certify_reduced_ioss(f, h, **bounds, **FAST)))  # studies ship certificates
    diameter = np.linalg.norm(0.2 / cert.model.d_scale[1:])
    np.testing.assert_allclose(cert.noise_gain, 2 * np.sqrt(cert.c_v) * diameter * cert.scale)
    assert cert.output_gain == pytest.approx(cert.r / np.linalg.eigvalsh(cert.P_scaled)[0])
    table = cert.tradeoff(levels=(10.0, 1e6))
    assert [row.status for row in table.rows] == ["certified", "certified"]
    assert table.rows[0].mu_min > table.rows[1].mu_min == pytest.approx(0.25, abs=1e-3)
    system = closed_form.system()
    delta = certify_delta_ioss(system, w_bounds=(-1, 1), **FAST)
    c_v = delta.q[1] / (delta.eta * np.linalg.eigvalsh(delta.P_scaled)[0])
    diameter = np.linalg.norm(system.v.bounds.width / system.v.scale)
    np.testing.assert_allclose(delta.noise_gain, 2 * np.sqrt(c_v) * diameter * system.x.scale)
    rows = delta.tradeoff(levels=(1e6,)).rows
    assert rows[0].mu_min == pytest.approx(0.64, abs=1e-3) and rows[0].noise_gain.shape == (2,)


def test_infeasible_at_the_vertices_only_is_undecided_not_infeasible():
    # the unmeasured pair rotates by x1 and shrinks by 0.9: P = I contracts it at 0.81, but the box of (cos, sin)
    # has corners of norm 0.9 sqrt(2) > 1, so no storage works at the cover's vertices; at the Jacobians themselves
    # one does, so "infeasible" would be false
    def f(x, u, w):
        c, s = np.cos(x[0]), np.sin(x[0])
        return [0.5 * x[0] + w[0], 0.9 * (c * x[1] - s * x[2]), 0.9 * (s * x[1] + c * x[2])]

    system = System.from_callables(f, lambda x, v: [x[0] + v[0]], nx=3, nw=1, nv=1,
                                   x_bounds=((-3, -1, -1), (3, 1, 1)), v_bounds=(-1e-3, 1e-3))  # fmt: skip
    cert = certify_delta_ioss(system, w_bounds=(-1, 1))
    assert cert.status == "undecided" and not cert.certified, cert.reason
    assert "feasible at the Jacobians of" in cert.reason and "mu_min 0.81" in cert.reason
