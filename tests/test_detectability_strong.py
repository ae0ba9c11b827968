"""Strong-detectability certificates (theo:Lyapunov) against known answers."""

import dataclasses
import json

import casadi as ca
import numpy as np
import pytest
from exact_rates import contraction_rate

from uiest import Box, CertificationError, ModelError, OptionError, System
from uiest.detectability import certify_strong_detectability, linear_strong_detectability
from uiest.estimators import UISE, UISEWeights
from uiest.models import closed_form, crop_growth, linear
from uiest.simulate import simulate

LINEAR_SPEC = {"x_bounds": (-10.0, 10.0), "v_bounds": (-1e-3, 1e-3)}


@pytest.mark.parametrize(
    ("zeros", "kwargs"),
    [
        ([0.5, 0.2], {}),
        ([0.3 + 0.4j, 0.3 - 0.4j, -0.7], {}),
        ([0.6, 0.1], {"nw": 2, "extra_outputs": 1}),
    ],
)
def test_linear_mu_min_is_largest_zero_squared(zeros, kwargs):
    system, A, B, C = linear.with_invariant_zeros(zeros, seed=3, **kwargs, **LINEAR_SPEC)
    cert = certify_strong_detectability(system)
    expected = max(abs(z) for z in zeros) ** 2
    assert cert.certified, cert.reason
    assert cert.mu_min == pytest.approx(expected, abs=1e-3)
    assert cert.mu == pytest.approx(cert.mu_min + 0.02 * (1 - cert.mu_min))
    assert cert.cover.kind == "constant" and cert.cover.sound
    # the nonlinear certificate's linear special case agrees with the Hautus test
    assert cert.mu_min == pytest.approx(linear_strong_detectability(A, B, C).mu_min, abs=1e-3)
    report = cert.verify(20_000, seed=1)
    assert report.pairs_used > 10_000 and report.holds, report


def test_zero_outside_unit_disk_is_infeasible_not_a_failure():
    system, *_ = linear.with_invariant_zeros([1.5], seed=3, **LINEAR_SPEC)
    cert = certify_strong_detectability(system)
    assert not cert.certified and cert.status == "infeasible", cert.reason
    with pytest.raises(CertificationError):
        cert.min_horizon()
    assert np.isnan(cert.verify().worst_ratio)


def test_matching_failure_is_a_typed_error_with_the_ranks():
    # w enters x2, only x1 is measured: C B = 0 while B != 0
    A = np.array([[0.5, 1.0], [0.0, 0.3]])
    system = linear.linear_system(A, [[0.0], [1.0]], [[1.0, 0.0]], **LINEAR_SPEC)
    with pytest.raises(ModelError, match=r"rank\(C B\) = 0 < rank\(B\) = 1"):
        certify_strong_detectability(system)


@pytest.mark.slow
def test_closed_form_rate_over_a_domain_twenty_times_wider_in_one_state():
    # x2+ = a(x1) x2 + u with a = 0.5 + 0.3 tanh(x1), x1 in [-3, 3]: mu* = max a^2; x2 in [-60, 60]
    system = closed_form.system(x_bounds=((-3.0, -60.0), (3.0, 60.0)))
    known = (0.5 + 0.3 * np.tanh(3.0)) ** 2
    cert = certify_strong_detectability(system)
    assert cert.certified, cert.reason
    assert cert.cover.kind == "exact by entries" and cert.cover.sound and len(cert.cover.vertices) == 4
    assert known - 1e-6 <= cert.mu_min <= known + 1e-3
    report = cert.verify(100_000, seed=2)
    assert report.pairs_used > 90_000 and report.holds, report
    # a sampled cover, asked for, finds the same numbers but proves nothing
    sampled = certify_strong_detectability(system, cover="sampled")
    assert not sampled.certified and sampled.status == "holds at the samples, not proved", sampled.reason
    assert sampled.mu_min == pytest.approx(known, abs=1e-3) and "the cover is sampled" in sampled.reason
    with pytest.raises(CertificationError):
        UISEWeights.from_certificate(sampled)


def test_parameter_map_gives_a_sound_cover_and_the_exact_rate():
    # after the unknown input's direction e1 is projected out, df/dx = [[0, 0], [a1 (1 - tanh^2(x1)) x2, a(x1)]]
    system = closed_form.system(x_bounds=((-3.0, -60.0), (3.0, 60.0)))
    cert = certify_strong_detectability(system, parameters=closed_form.jacobian_parameters())
    assert cert.certified, cert.reason
    assert cert.cover.kind == "parameter box" and cert.cover.sound and len(cert.cover.vertices) == 4
    assert cert.mu_min == pytest.approx((0.5 + 0.3 * np.tanh(3.0)) ** 2, abs=1e-3)
    assert cert.verify(20_000, seed=3).holds
    with pytest.raises(ModelError, match=r"not affine in the given parameters: entry \[1, 0\]"):
        certify_strong_detectability(system, parameters=lambda x, u: [np.tanh(x[0])])
    # the same functions through an identity the exact forms do not apply (sech^2 = 1 - tanh^2): refused, not fitted
    with pytest.raises(ModelError, match="not exact combinations of the parameters' expressions"):
        certify_strong_detectability(system, parameters=lambda x, u: [x[1] / np.cosh(x[0]) ** 2, np.tanh(x[0])])


def test_verify_exposes_a_certificate_that_claims_too_much():
    system = closed_form.system(x_bounds=((-3.0, -60.0), (3.0, 60.0)))
    cert = certify_strong_detectability(system)
    tampered = dataclasses.replace(cert, rate=0.5 * cert.mu)
    assert tampered.verify(20_000, seed=4).worst_ratio > 1.0


def _cstr(**kwargs):
    k0, energy, beta = 50.0, 5.0, 0.5

    def rhs(x, u, w):
        rate = k0 * x[0] * np.exp(-energy / x[1])
        return [1.0 - x[0] - rate, 2.0 - 2.0 * x[1] + beta * rate + w[0]]

    return System.from_ode(rhs, lambda x, v: [x[1] + v[0]], nx=2, nw=1, nv=1, dt=0.05,
                           x_bounds=Box(lower=(0.0, 0.8), upper=(1.0, 2.5)), v_bounds=(-1e-3, 1e-3),
                           **kwargs)  # fmt: skip


def test_continuous_time_model_with_a_constant_input_channel_certifies():
    cert = certify_strong_detectability(_cstr())
    assert cert.certified, cert.reason
    assert 0.8 < cert.mu_min < 1.0
    assert cert.verify(20_000).holds
    # w held inside RK4 turns the input's direction with the state: the outputs miss part of its span (not
    # "matching fails", which holds at each point)
    with pytest.raises(ModelError, match=r"direction varies over the domain: df/dw has rank 1 at a point.*span 2 "):
        certify_strong_detectability(_cstr(input_channel="rk4"))


def test_crop_model_certifies_at_the_papers_rate_with_its_noise_gain():
    system = crop_growth.system()
    cert = certify_strong_detectability(system, mu=0.48)
    assert cert.certified and cert.mu == 0.48, cert.reason
    assert cert.mu_min < 0.3
    assert cert.noise_gain.shape == (3,) and np.all(np.isfinite(cert.noise_gain)) and np.all(cert.noise_gain > 0)
    n = cert.min_horizon()
    assert 8 * cert.mu**n * cert.condition < 1 <= 8 * cert.mu ** (n - 1) * cert.condition
    assert cert.verify(20_000).holds


@pytest.mark.parametrize("solver", ["ipopt", "gn"])
def test_crop_uise_with_certificate_weights_solves_every_window(solver):
    # the certificate's output weight is ~1e12 times its prior weight (scaled units): before the
    # NLP's cost was scaled, IPOPT failed 59 of 60 noise-free windows (Error_In_Step_Computation)
    system = crop_growth.system()
    cert = certify_strong_detectability(system, mu=0.48)
    truth = simulate(system, np.array(crop_growth.DEFAULT_SCENARIO.x0), 40, w=crop_growth.UnknownInputLaw())
    estimator = UISE(system, certificate=cert, x0_prior=truth.x[0] + [0.0, 1e-3, -1e-3], solver=solver)
    result = estimator.run(truth.u, truth.y)
    assert result.failures == 0
    assert result.fallbacks == 0, "a Gauss-Newton sample fell back to IPOPT"
    assert np.abs(result.error(truth.x)[cert.min_horizon() + 5 :]).max() < 1e-6


def test_chaotic_map_without_zero_dynamics_certifies_at_the_floor():
    def henon(x, u, w):
        return [1.0 - 1.4 * x[0] ** 2 + x[1] + w[0], 0.3 * x[0]]

    system = System.from_callables(henon, lambda x, v: [x[0] + v[0]], nx=2, nw=1, nv=1,
                                   x_bounds=((-1.5, -0.5), (1.5, 0.5)), v_bounds=(-1e-3, 1e-3))  # fmt: skip
    cert = certify_strong_detectability(system)
    assert cert.certified and cert.mu_min <= 1e-4, cert.reason
    assert cert.verify(20_000).holds


def test_bad_models_and_options_get_typed_errors():
    with pytest.raises(ModelError, match="bounded state domain"):
        certify_strong_detectability(linear.linear_system(0.5 * np.eye(2), [[1.0], [0.0]], [[1.0, 0.0]]))
    quadratic = System.from_callables(lambda x, u, w: [0.5 * x[0] + w[0], 0.5 * x[1]], lambda x, v: [x[0] ** 2 + v[0]],
                                      nx=2, nw=1, nv=1, x_bounds=(-1, 1))  # fmt: skip
    with pytest.raises(ModelError, match="affine in the state"):
        certify_strong_detectability(quadratic)
    system = closed_form.system()
    for bad in (1.5, 0.0, "a"):
        with pytest.raises(OptionError, match="mu"):
            certify_strong_detectability(system, mu=bad)
    with pytest.raises(OptionError, match="samples"):
        certify_strong_detectability(system, samples=2)


def test_given_rate_below_the_smallest_is_refused_and_weights_follow_the_certificate():
    system, *_ = linear.with_invariant_zeros([0.5, 0.2], seed=3, **LINEAR_SPEC)
    low = certify_strong_detectability(system, mu=0.2)
    assert not low.certified and low.status == "below the smallest rate"
    cert = certify_strong_detectability(system, mu=0.48)
    weights = UISEWeights.from_certificate(cert)
    assert isinstance(weights, UISEWeights) and weights.mu == 0.48
    np.testing.assert_allclose(weights.P, cert.P)
    np.testing.assert_allclose(cert.R_y, cert.sigma_y * np.diag(1 / system.y.scale**2))
    data = json.loads(json.dumps(cert.to_dict()))
    assert data["kind"] == "strong_detectability" and data["status"] == "certified"
    assert data["min_horizon"] == cert.min_horizon()
    with pytest.raises(CertificationError):
        UISEWeights.from_certificate(low)


def test_an_input_direction_that_drifts_with_the_state_is_caught():
    # x2+ picks up 1e-9 x1 w: negligible at small w, unbounded at large w, so B must be 2-dimensional
    drifting = System.from_callables(lambda x, u, w: [0.5 * x[0] + x[1] + w[0], 0.5 * x[1] + 1e-9 * x[0] * w[0]],
                                     lambda x, v: [x[0] + v[0]], nx=2, nw=1, nv=1, x_bounds=(-1, 1))  # fmt: skip
    with pytest.raises(ModelError, match="varies"):
        certify_strong_detectability(drifting)


def test_every_state_measured_and_the_sound_flag():
    system = linear.linear_system(np.array([[0.9, 0.2], [0.0, 0.7]]), [[1.0], [0.5]], np.eye(2), **LINEAR_SPEC)
    cert = certify_strong_detectability(system)
    assert cert.certified and cert.mu_min <= 1e-4 and cert.sound, cert.reason
    assert cert.verify(20_000).holds
    sampled = certify_strong_detectability(closed_form.system(), cover="sampled")
    assert not sampled.sound and "sampled" in sampled.coverage and not sampled.certified


def test_solver_failures_are_never_reported_as_infeasible(monkeypatch):
    from uiest.detectability import strong_lmi

    system, *_ = linear.with_invariant_zeros([0.5, 0.2], seed=3, **LINEAR_SPEC)
    # the margin problem is always feasible: a solver saying "infeasible" has failed
    monkeypatch.setattr(strong_lmi.RateProblem, "solve", lambda self, mu: ("infeasible", None, float("nan")))
    cert = certify_strong_detectability(system)
    assert cert.status == "solver failed" and not cert.certified, cert.reason


def test_linear_certificate_statuses():
    _, A, B, C = linear.with_invariant_zeros([0.5, 0.2], seed=3, **LINEAR_SPEC)
    assert linear_strong_detectability(A, B, C).status == "certified"
    assert linear_strong_detectability(A, B, C, mu=0.1).status == "below the smallest rate"
    _, A, B, C = linear.with_invariant_zeros([1.5], seed=3, **LINEAR_SPEC)
    assert linear_strong_detectability(A, B, C).status == "infeasible"


def _lorenz(dt):
    """Lorenz, y = x1, w in dx1/dt, over a wide box: 9 independent entries of its projected RK4 Jacobian."""

    def rhs(x, u, w):
        return [10.0 * (x[1] - x[0]) + w[0], 28.0 * x[0] - x[1] - x[0] * x[2], x[0] * x[1] - 8.0 / 3.0 * x[2]]

    return System.from_ode(rhs, lambda x, v: [x[0] + v[0]], nx=3, nw=1, nv=1, dt=dt,
                           x_bounds=((-30.0, -30.0, 0.0), (30.0, 30.0, 60.0)), v_bounds=(-0.1, 0.1))  # fmt: skip


@pytest.mark.slow
def test_infeasible_at_a_covers_vertices_is_a_proof_only_when_the_sampled_jacobians_agree():
    # dt = 0.002: the exact box of the 9 independent Jacobian entries (512 vertices) admits no P, the Jacobians
    # themselves do (their zero dynamics contract like exp(-dt)): undecided, not "infeasible". dt = 0.01: the
    # integral input channel's error outweighs that contraction, and the sampled Jacobians are infeasible too: a proof.
    wide = certify_strong_detectability(_lorenz(0.002), samples=500)
    assert wide.status == "undecided" and not wide.certified
    assert wide.cover.kind == "exact by entries" and len(wide.cover.vertices) == 512
    assert "512 vertices" in wide.reason and "feasible at the Jacobians of" in wide.reason
    below = certify_strong_detectability(_lorenz(0.002), mu=0.5, samples=500)  # refuted at the samples (0.997)
    assert below.status == "below the smallest rate" and "sampled points of X themselves" in below.reason
    coarse = certify_strong_detectability(_lorenz(0.01), samples=500)
    assert coarse.status == "infeasible" and "sampled points of X themselves" in coarse.reason


def test_a_panic_in_the_lmi_solver_is_a_solver_failure(monkeypatch):
    import cvxpy as cp

    class PanicException(BaseException):  # pyo3's, raised by Clarabel's Rust code: not an Exception
        pass

    def panic(self, *args, **kwargs):
        raise PanicException("index out of bounds")

    system, *_ = linear.with_invariant_zeros([0.5, 0.2], seed=3, **LINEAR_SPEC)
    monkeypatch.setattr(cp.Problem, "solve", panic)
    cert = certify_strong_detectability(system)
    assert cert.status == "solver failed" and not cert.certified, cert.reason


def test_a_solver_error_in_the_design_is_retried_before_the_rate_problems_p_is_used(monkeypatch):
    # Clarabel's 'solver_error' on a Haldane chemostat's design (seeds 0 and 1) left the rate problem's P, with
    # output weights 3300x and noise gains 58x the design's, behind an unchanged reason.
    from uiest.detectability import strong_lmi

    system, *_ = linear.with_invariant_zeros([0.5, 0.2], seed=3, **LINEAR_SPEC)
    real, calls = strong_lmi.StrongLMI._design_once, []

    def failing_once(self, *args):
        calls.append(args[2])  # the margin
        return ("solver_error", None) if len(calls) == 1 else real(self, *args)

    monkeypatch.setattr(strong_lmi.StrongLMI, "_design_once", failing_once)
    cert = certify_strong_detectability(system)
    assert cert.certified and cert.design == "design" and calls[1] == pytest.approx(1e-2 * calls[0])
    monkeypatch.setattr(strong_lmi.StrongLMI, "_design_once", lambda self, *args: ("solver_error", None))
    fallback = certify_strong_detectability(system)
    assert fallback.certified and "P from the rate problem" in fallback.reason


def _band(width=3e-4):
    """Issue 33's system: x2's rate 0.6 + 0.5 g(x1) reaches 1.1 on a band of x1 of width ~1e-3; y = x1."""

    def g(x1):
        return np.exp(-(((x1 - 1.3) / width) ** 2))

    def f(x, u, w):
        return [0.5 * x[0] + 0.3 * np.sin(x[1]) + w[0], (0.6 + 0.5 * g(x[0])) * x[1] + 0.2 * x[0]]

    system = System.from_callables(f, lambda x, v: [x[0] + v[0]], nx=2, nw=1, nv=1,
                                   x_bounds=((-5.0, -3.0), (5.0, 3.0)), v_bounds=(-1e-3, 1e-3))  # fmt: skip
    return system, lambda x, u: [np.sin(x[1]), g(x[0])]


def test_a_band_where_the_zero_dynamics_expand_is_never_certified():
    # x = (1.3, 2), x~ = (1.3, 1): same y and y+, yet x2's distance grows by 1.1 per step. A fit of the
    # Jacobian's affine form on random samples never excited g and certified it (mu = 0.373).
    system, theta = _band()
    with pytest.raises(ModelError, match=r"not affine in the given parameters: entry \[1, 0\].* at x\[0\]=1\.(29|30)"):
        certify_strong_detectability(system, parameters=theta)
    exact = certify_strong_detectability(system)
    assert not exact.certified and exact.status == "infeasible", exact.reason
    assert exact.cover.kind == "exact by entries" and exact.cover.sound
    upper = exact.cover.vertices[:, 1, 1].max()  # x2's rate, scaled: 0.6 + 0.5 g up to 1.1, proved
    assert 1.1 - 1e-9 <= upper <= 1.1 + 1e-3
    sampled = certify_strong_detectability(system, cover="sampled")
    assert not sampled.certified and sampled.status in ("holds at the samples, not proved", "refuted")


def _ridge(width=1e-6):
    """y = x1 (w masks it); the unmeasured pair's coupling c jumps from 0.1 to 2.1 on a diagonal ridge."""

    def f(x, u, w):
        c = 0.1 + 2.0 * np.exp(-(((x[1] + x[2] - 0.3137) / width) ** 2))
        return [0.5 * x[0] + 0.1 * x[1] + w[0], 0.5 * x[1] + c * x[2] + 0.1 * x[0], 0.5 * x[1] + 0.5 * x[2]]

    return System.from_callables(f, lambda x, v: [x[0] + v[0]], nx=3, nw=1, nv=1,
                                 x_bounds=((-2.0, -1.0, -1.0), (2.0, 1.0, 1.0)), v_bounds=(-1e-3, 1e-3))  # fmt: skip


@pytest.mark.slow
def test_a_narrow_diagonal_ridge_in_the_coupling_is_not_certified():
    # on the ridge the unmeasured pair's dynamics [[0.5, 2.1], [0.5, 0.5]] have an eigenvalue 1.52; off it 0.72.
    # Samples miss a ridge 1e-6 wide: the sampled cover's LMI holds (mu_min 0.524) but proves nothing.
    exact = certify_strong_detectability(_ridge())
    assert not exact.certified and exact.status in ("undecided", "infeasible"), exact.reason
    assert exact.cover.vertices[:, 1, 2].max() >= 2.1 - 1e-9  # the coupling's bound covers the ridge
    sampled = certify_strong_detectability(_ridge(), cover="sampled")
    assert not sampled.certified and sampled.status in ("holds at the samples, not proved", "refuted")


def test_a_varying_input_direction_the_output_never_sees_is_a_matching_failure():
    # w enters along (cos x3, sin x3, 0), y = x3: the output sees no direction of w at any point (matching fails
    # everywhere), which a constant input direction would not mend
    def f(x, u, w):
        return [0.5 * x[0] + w[0] * ca.cos(x[2]), 0.5 * x[1] + w[0] * ca.sin(x[2]), 0.9 * x[2] + 0.1 * x[0]]

    system = System.from_callables(f, lambda x, v: [x[2] + v[0]], nx=3, nw=1, nv=1, x_bounds=(-1.0, 1.0),
                                   v_bounds=(-1e-3, 1e-3))  # fmt: skip
    with pytest.raises(ModelError, match=r"^matching fails: rank\(C B\) = 0 < rank\(B\) = 2"):
        certify_strong_detectability(system)


def test_an_input_that_leaks_into_an_unmeasured_state_on_a_narrow_band_is_refused():
    # w reaches x2 (unmeasured) only where x2 is within ~1e-4 of 0.3: samples of df/dw never see it, its exact
    # form does, so the input's span is 2-dimensional and the output (x1) cannot see both directions.
    def f(x, u, w):
        leak = 0.5 * np.exp(-(((x[1] - 0.3) / 1e-4) ** 2))
        return [0.5 * x[0] + 0.2 * x[1] + w[0], 0.6 * x[1] + 0.1 * x[0] + leak * w[0]]

    system = System.from_callables(f, lambda x, v: [x[0] + v[0]], nx=2, nw=1, nv=1,
                                   x_bounds=((-2.0, -1.0), (2.0, 1.0)), v_bounds=(-1e-3, 1e-3))  # fmt: skip
    with pytest.raises(ModelError, match=r"span 2 dimensions, of which the next output sees 1 \(rank\(C B\) = 1 < 2 "):
        certify_strong_detectability(system)


def test_a_certificate_the_search_refutes_is_not_returned_as_certified(monkeypatch):
    # a cover that holds only the Jacobian at x1 = -3 (rate a = 0.2) while a reaches 0.8 at x1 = 3: the LMI holds
    # at that vertex, the adversarial search finds the pairs that violate it
    from uiest.detectability import cover as covers
    from uiest.detectability import strong

    system = closed_form.system(x_bounds=((-3.0, -60.0), (3.0, 60.0)))
    real = covers.cover

    def too_small(fun, box, **kwargs):
        found = real(fun, box, **kwargs)
        corner = np.asarray(fun(np.array([-3.0, 0.0, 0.0])), dtype=float)[None]
        return dataclasses.replace(found, vertices=corner, samples=corner)

    monkeypatch.setattr(strong.covers, "cover", too_small)
    cert = certify_strong_detectability(system)
    assert cert.status == "refuted" and not cert.certified, cert.reason
    found = cert.falsification
    assert found.refuted and found.worst_ratio > 2.0 and found.pairs >= 20_000 and found.searches > 0
    assert f"{found.worst_ratio:.4g}" in cert.reason and "(x1, x2) = (" in cert.reason
    assert found.first[0] > 0.0  # the violation lives where a(x1) is large
    data = json.loads(json.dumps(cert.to_dict()))
    assert data["falsification"]["refuted"] and data["falsification"]["local_searches"] == found.searches
    with pytest.raises(CertificationError):
        UISEWeights.from_certificate(cert)


def test_every_certificate_reports_its_adversarial_search():
    system, *_ = linear.with_invariant_zeros([0.5, 0.2], seed=3, **LINEAR_SPEC)
    cert = certify_strong_detectability(system)
    found = cert.falsification
    assert cert.certified and not found.refuted and found.worst_ratio <= 1.0 + 1e-6
    assert found.pairs >= 20_000 and found.searches > 0 and found.evaluations > 0
    assert "no violation found" in found.text()
    assert json.loads(json.dumps(cert.to_dict()))["falsification"]["pairs"] == found.pairs
    infeasible = certify_strong_detectability(linear.with_invariant_zeros([1.5], seed=3, **LINEAR_SPEC)[0])
    assert infeasible.falsification is None and infeasible.to_dict()["falsification"] is None


def test_the_bound_on_cond_p_sets_the_rate_of_non_normal_zero_dynamics():
    # x3 is measured and carries w; the zero dynamics (x1, x2) are F = [[0.5, 2], [0, 0.3]]: mu_min(kappa) is F's
    # squared norm in the best P-norm with cond(P) <= kappa, 0.25 only as kappa grows
    A = np.array([[0.5, 2.0, 0.3], [0.0, 0.3, -0.2], [0.4, 0.1, 0.6]])
    system = linear.linear_system(A, [[0.0], [0.0], [1.0]], [[0.0, 0.0, 1.0]], **LINEAR_SPEC)
    table = certify_strong_detectability(system).tradeoff(levels=(10.0, 30.0, 100.0))
    F = A[:2, :2]
    for row in table.rows:
        assert row.status == "certified" and row.condition <= row.max_condition * (1 + 1e-6)
        assert row.mu_min == pytest.approx(contraction_rate(F, row.max_condition), abs=1e-3)
        assert row.horizon >= 1 and row.noise_gain.shape == (3,) and row.output_gain > 0
    assert certify_strong_detectability(system).mu_min == pytest.approx(0.25, abs=1e-3)
    assert certify_strong_detectability(system, max_condition=10.0).verify(5000).holds
    assert "x[0]" in str(table) and len(table.to_pandas()) == 3
    with pytest.raises(OptionError, match="max_condition: expected a finite number > 1"):
        certify_strong_detectability(system, max_condition=np.inf)


def test_nearly_equal_vertices_still_get_a_design():
    # a pendulum sampled by RK4 every 0.05: its exact cover has 16 vertices within 1e-3 of each other, on which the
    # design solve errs (Clarabel); from the two farthest vertices, grown by cutting planes, it solves
    pendulum = System.from_ode(lambda x, u, w: [x[1], -9.81 * np.sin(x[0]) - 0.5 * x[1] + w[0]],
                               lambda x, v: [x[0] + v[0]], nx=2, nw=1, nv=1, dt=0.05,
                               x_bounds=((-3.0, -8.0), (3.0, 8.0)), v_bounds=(-1e-3, 1e-3))  # fmt: skip
    cert = certify_strong_detectability(pendulum)
    assert cert.certified and cert.cover.sound and cert.n_vertices == 16, cert.reason
    assert cert.design == "design" and "rate problem" not in cert.reason
    assert cert.verify(20_000).holds


def test_a_sampled_cover_of_a_step_in_the_zero_dynamics_is_a_typed_error_or_not_certified():
    # x2's own gain jumps from 0.6 to 4.6 on a band 1e-4 wide: the sampled values span a degenerate polytope
    def f(x, u, w):
        return [0.5 * x[0] + 0.2 * np.sin(x[1]) + w[0], 0.6 * x[1] + 0.2 * x[0] + 4e-4 * np.tanh((x[1] - 0.7) / 1e-4)]

    system = System.from_callables(f, lambda x, v: [x[0] + v[0]], nx=2, nw=1, nv=1,
                                   x_bounds=((-5.0, -3.0), (5.0, 3.0)), v_bounds=(-0.01, 0.01))  # fmt: skip
    assert certify_strong_detectability(system).status == "infeasible"
    try:
        sampled = certify_strong_detectability(system, cover="sampled")
    except ModelError as exc:
        assert "sampled cover" in str(exc) and "exact cover" in str(exc)
    else:
        assert not sampled.certified


def test_the_tradeoff_of_a_reweighted_certificate_keeps_its_output_weight():
    system, *_ = linear.with_invariant_zeros([0.5, 0.2], seed=3, **LINEAR_SPEC)
    cert = certify_strong_detectability(system)
    heavier = cert.with_output_weight(10.0)
    (plain,) = cert.tradeoff(levels=(1e6,)).rows
    (row,) = heavier.tradeoff(levels=(1e6,)).rows
    assert row.certified and plain.certified
    np.testing.assert_allclose(row.noise_gain, np.sqrt(10.0) * plain.noise_gain, rtol=1e-9)
    np.testing.assert_allclose(row.noise_gain, heavier.noise_gain, rtol=1e-9)


def test_the_search_does_not_refute_with_pairs_closer_than_rounding():
    # the quadruple tank with h3, h4 down to 0.5 cm: its local maximisation once drove a pair to one unit in the last
    # place apart (h3 = 0.5 and 0.5 - 1.1e-16), where lhs / rhs measures rounding (4.13): "refuted" a valid certificate
    from test_analysis import quadruple_tank

    from uiest.detectability import falsify

    cert = certify_strong_detectability(quadruple_tank(upper=False, dt=1.0, lower=(4, 4, 0.5, 0.5)))
    assert cert.certified, cert.reason
    found = cert.falsification
    width = cert.system.x.bounds.width / cert.system.x.scale
    assert np.linalg.norm(
        (found.first - found.second) / cert.system.x.scale
    ) >= falsify.MIN_SEPARATION * np.linalg.norm(width)
    assert found.worst_ratio <= 1.0 and cert.verify(20_000).holds


def test_a_wide_domain_does_not_let_rounding_refute_a_certificate():
    # the Henon map with w into the measured x1, X = +-1e4, the states' own scales: eliminating w subtracted two terms
    # of 2e20 to leave 7e5, and rounding (2 %) refuted the certificate at a pair whose exact ratio is 0.99902
    henon = System.from_callables(lambda x, u, w: [1.0 - 1.4 * x[0] ** 2 + x[1] + w[0], 0.3 * x[0]],
                                  lambda x, v: [x[0] + v[0]], nx=2, nw=1, nv=1, x_bounds=(-1e4, 1e4),
                                  v_bounds=(-1e-3, 1e-3)).with_scales(x=[1.5, 0.5])  # fmt: skip
    cert = certify_strong_detectability(henon)
    assert cert.certified, cert.reason
    assert 0.99 < cert.falsification.worst_ratio < 1.0


def test_an_lmi_whose_data_overflow_is_a_failed_solve_not_a_crash():
    # a sampled model whose Jacobian is huge somewhere in the cover: cvxpy refuses the products as NaN or Inf
    import cvxpy as cp

    from uiest.detectability import lmi

    X = cp.Variable((2, 2), symmetric=True)
    A = np.array([[1e200, 0.0], [0.0, 1.0]])
    problem = cp.Problem(cp.Minimize(cp.trace(X)), [lmi.symmetric(A.T @ X @ A) >> np.eye(2)])
    assert lmi.solve(problem) == "nonfinite_data"
