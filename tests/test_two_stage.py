"""Two-stage UISE (theo:stab) against known answers: the closed-form system, the linear UIO's limit, the crop
model; special cases n_sharp = 0 and n_flat = 0; weights, guarantees, missing data, failures; the window
model, the projection, the Gauss-Newton polish and the unknown-input fit it relies on."""

import casadi as ca
import numpy as np
import pytest
from failing_solver import FailingSolver

from uiest import Box, CertificationError, DataError, OptionError, SolverError, System, UniformNoise, simulate
from uiest.detectability import certify_reduced_model
from uiest.estimators import (
    EstimationResult,
    LinearUIO,
    Outcome,
    TwoStageUISE,
    TwoStageWeights,
    UISEWeights,
)
from uiest.estimators import base as base_module
from uiest.estimators.input_fit import InputFit
from uiest.estimators.projection import Projection
from uiest.models import closed_form, crop_growth, get, linear
from uiest.reduction import ReducedModel, reduce_quasi_state_affine
from uiest.theory import ALGEBRAIC_TWO_STAGE
from uiest.window import WindowModel, WindowProblem, WindowWeights, make_solver
from uiest.window.polish import refine

# ---------------------------------------------------------------------------------------------- fixtures


@pytest.fixture(scope="module")
def closed_form_case():
    """Closed-form model on a domain wide enough for x1 to follow a huge unknown input; certified reduction."""
    reduced = closed_form.reduction(x_bounds=((-1e9, -10.0), (1e9, 10.0)))
    certificate = certify_reduced_model(closed_form.reduction())  # the reduced model does not depend on the x1 range
    assert certificate.certified
    return reduced, certificate


@pytest.fixture(scope="module")
def linear_case():
    """Zeros {0.5, 0.2}: certificate on the bounded twin (LTI: domain-independent), estimation unbounded."""
    bounded, A, B, C = linear.with_invariant_zeros([0.5, 0.2], seed=1, x_bounds=(-10, 10), v_bounds=(-1e-3, 1e-3))
    certificate = certify_reduced_model(reduce_quasi_state_affine(bounded))
    assert certificate.certified and certificate.mu == pytest.approx(0.5, abs=1e-3)  # zeros^2 < mu: contraction
    system = linear.linear_system(A, B, C, v_bounds=(-1e-3, 1e-3))
    reduced = reduce_quasi_state_affine(system, z_bounds=Box.unbounded(2))
    return system, reduced, certificate


def crop_weights(reduced, mu=0.48, output=1e6):
    """The paper's mu = 0.48; per scaled unit: prior 1, noise 1, outputs 1e6 (as the full-order UISE's)."""
    weights = TwoStageWeights.from_scales(reduced, mu, output=output)
    s_z = reduced.z_bounds.width
    np.testing.assert_allclose(weights.prior, np.diag(1 / s_z**2))
    np.testing.assert_allclose(weights.R_y, np.diag(output / reduced.system.y.scale**2))
    return weights


# ---------------------------------------------------------------------------------------------- known answers


@pytest.mark.parametrize("w_kind", ["constant 1e6", "ramp"])
def test_closed_form_error_is_the_closed_form_despite_unbounded_input(closed_form_case, w_kind):
    reduced, certificate = closed_form_case
    K = 40
    w = np.full((K, 1), 1e6) if w_kind == "constant 1e6" else (1e5 * np.arange(K) + 3.0 * np.sin(np.arange(K)))[:, None]
    traj = simulate(reduced.system, [0.5, 1.0], K, u=np.zeros(1), w=w)
    assert np.abs(traj.x[:, 0]).max() > 1e7
    prior = np.array([traj.y[0, 0], 0.0])  # x2 off by 1
    est = TwoStageUISE(reduced, certificate=certificate, N=10, x0_prior=prior)
    assert est.guarantee.applies and "Theorem 4.8 " in est.guarantee.theorem and certificate.min_horizon() <= est.N
    assert not est.guaranteed  # vacuous for x2: bound 186 > X's width 20
    result = est.run(traj.u, traj.y)
    e1, e2 = (traj.x - result.x_hat).T
    assert result.failures == 0 and result.estimator == "TwoStageUISE"
    assert np.abs(e1).max() == 0.0  # x1 = psi(y, v_bar) = y exactly
    np.testing.assert_allclose(e2, closed_form.noise_free_error(traj.x[:, 0], traj.x[0, 1] - prior[1]), atol=1e-12)
    # w[k-1] = x1[k] - x1[k-1] - beta sin(x2[k-1]): the fit's error is -beta (sin x2 - sin x2_hat), relative to |w|
    w_err = -0.5 * (np.sin(traj.x[:-1, 1]) - np.sin(result.x_hat[:-1, 1]))
    np.testing.assert_allclose(traj.w[:, 0] - result.w_hat[:, 0], w_err, atol=1e-9 * np.abs(w).max())


@pytest.mark.parametrize("w_kind", ["constant 1e6", "ramp"])
def test_linear_two_stage_reaches_the_linear_uio_limit(linear_case, w_kind):
    system, reduced, certificate = linear_case
    K = 60
    w = np.full((K, 1), 1e6) if w_kind == "constant 1e6" else (1e4 * np.arange(K) + 1e3 * np.sin(np.arange(K)))[:, None]
    traj = simulate(system, [1.0, -1.0, 0.5], K, w=w)
    scale = np.abs(traj.x).max()
    assert scale > 1e5
    two_stage = TwoStageUISE(reduced, weights=TwoStageWeights.from_certificate(certificate), N=10)
    result = two_stage.run(None, traj.y, x0_prior=np.zeros(3))
    uio = LinearUIO(system, x0_prior=np.zeros(3)).run(None, traj.y)
    e_2s = np.linalg.norm(result.error(traj.x), axis=1)
    e_uio = np.linalg.norm(uio.error(traj.x), axis=1)
    assert result.failures == 0
    for e in (e_2s, e_uio):  # decay with the invariant zero 0.5 down to round-off of |x| ~ 1e7
        assert e[20] < 1e-5 * e[0]
        assert e[45:].max() < 1e-15 * scale * 100
    np.testing.assert_allclose(result.x_hat[45:], uio.x_hat[45:], atol=1e-14 * scale * 100)
    np.testing.assert_allclose(result.w_hat[45:], traj.w[45:], atol=1e-14 * scale * 100)


@pytest.mark.slow
def test_crop_noise_free_converges_to_solver_precision():
    reduced = crop_growth.reduction()
    scenario = crop_growth.DEFAULT_SCENARIO
    traj = simulate(reduced.system, scenario.x0, 60, w=crop_growth.UnknownInputLaw())
    prior = scenario.prior(traj.y[0])
    weights = crop_weights(reduced)
    # each backend's precision in the direction the data barely determine (gn: normal equations,
    # cond(J)^2), and with the Gauss-Newton refinement of uiest.window.polish
    floors = {("ipopt", False): 5e-7, ("gn", False): 5e-6, ("ipopt", True): 1e-10, ("gn", True): 1e-10}
    for (solver, polish), floor in floors.items():
        result = TwoStageUISE(reduced, weights=weights, N=30, x0_prior=prior, solver=solver, polish=polish).run(
            traj.u, traj.y
        )
        error = np.abs(result.error(traj.x))
        assert result.failures == 0
        assert error[0, 1] > 1e-3  # the prior of x^{d,1} is off ...
        assert error[55:, 1].max() < floor  # ... and 25 steps after the first full window it is gone
        assert error[:, 0].max() < 1e-15  # x^c = y^c: measured exactly
        assert np.abs(result.w_hat[55:] - traj.w[55:]).max() < 2000 * floor  # w is seen through x^c only
    assert np.all(result.window == np.minimum(np.arange(61), 30))


def test_crop_noisy_estimates_stay_in_X_and_near_the_truth():
    reduced = crop_growth.reduction()
    system, scenario = reduced.system, crop_growth.DEFAULT_SCENARIO
    traj = simulate(system, scenario.x0, 40, w=crop_growth.UnknownInputLaw(), v=scenario.noise(), seed=1)
    est = TwoStageUISE(reduced, weights=crop_weights(reduced), N=10, x0_prior=scenario.prior(traj.y[0]))
    result = est.run(traj.u, traj.y)
    assert result.failures == 0
    assert np.all(system.x.bounds.contains(result.x_hat))
    assert np.abs(result.error(traj.x)[:, 0]).max() <= 3e-6 + 1e-15  # x^c = y^c - v_bar: the noise itself
    assert np.abs(result.error(traj.x)[20:, 1:]).max() < 2e-2


# ---------------------------------------------------------------------------------------------- special cases


def test_n_sharp_zero_is_algebraic_and_exact():
    A, B, C = np.array([[0.9, 0.3], [-0.2, 1.1]]), np.array([[1.0], [0.5]]), np.array([[1.0, 1.0], [0.0, 2.0]])
    system = linear.linear_system(A, B, C, x_bounds=(-1e8, 1e8), v_bounds=(-1e-3, 1e-3))
    C_inv = np.linalg.inv(C)
    reduced = ReducedModel.from_maps(system, lambda x: x, lambda z: z, lambda y, z, v: C_inv @ (y - v), n_flat=2)
    traj = simulate(system, [1.0, 2.0], 20, w=(1e5 * np.arange(20.0))[:, None])
    est = TwoStageUISE(reduced, x0_prior=[0.0, 0.0])  # no certificate, no weights: nothing to optimise
    assert est.guaranteed and est.guarantee.theorem == ALGEBRAIC_TWO_STAGE
    # x = C^-1 (y - v): the error is C^-1 (v_bar - v), at most sum_j |C^-1_ij| 1e-3 per state, at every step
    np.testing.assert_allclose(est.guarantee.error_bound, 1.1 * np.abs(C_inv).sum(axis=1) * 1e-3, rtol=1e-12)
    assert est.guarantee.settling_steps == 0 and est.guarantee.informative
    result = est.run(None, traj.y)
    assert result.outcome.tolist() == [Outcome.PRIOR] + [Outcome.ALGEBRAIC] * 20 and result.window.max() == 0
    np.testing.assert_allclose(result.x_hat, traj.x, atol=1e-15 * np.abs(traj.x).max() * 10)
    np.testing.assert_allclose(result.w_hat, traj.w, atol=1e-15 * np.abs(traj.x).max() * 10)
    with pytest.raises(OptionError, match="n_sharp = 0"):
        TwoStageUISE(reduced, weights=TwoStageWeights(mu=0.5, prior=np.zeros((0, 0)), R_y=np.eye(2), R_v=np.eye(2)))


def test_n_flat_zero_is_a_one_step_ahead_mhe():
    A, B, C = np.array([[0.8, 0.4], [-0.3, 0.7]]), np.zeros((2, 1)), np.array([[1.0, 0.0]])
    system = linear.linear_system(A, B, C, x_bounds=(-10, 10), v_bounds=(-1e-3, 1e-3))
    reduced = ReducedModel.from_maps(system, lambda x: x, lambda z: z, lambda y, z, v: np.zeros(0), n_flat=0)
    traj = simulate(system, [1.0, -2.0], 30, w=np.zeros((30, 1)))
    weights = TwoStageWeights.from_scales(reduced, 0.5, output=1e4)
    est = TwoStageUISE(reduced, weights=weights, N=5, x0_prior=[0.0, 0.0])
    first = est.run(None, traj.y)
    assert first.failures == 0 and np.abs(first.error(traj.x))[20:].max() < 1e-9
    y = traj.y.copy()
    y[-1] += 5.0  # x_hat[k] = T^-1(z_hat[k]) does not use y[k]
    # the same estimator: its solvers forget the least damping the first run's failed QPs left (a run starts over)
    np.testing.assert_array_equal(est.run(None, y).x_hat, first.x_hat)


# ---------------------------------------------------------------------------------------------- weights, guarantees


def test_window_weights_are_the_papers_formulas(linear_case):
    weights = TwoStageWeights(mu=0.5, prior=np.diag([2.0, 3.0]), R_y=[[5.0]], R_v=[[7.0]])
    L = 3
    W = weights.schedule().window(L, range(L))
    np.testing.assert_allclose(W.prior, 2 * 0.5**L * np.diag([2.0, 3.0]))
    assert W.y.shape == (L, 1, 1) and W.w is None  # y[k-L .. k-1]
    for i in range(L):  # node i is time k - j, j = L - i
        j = L - i
        np.testing.assert_allclose(W.y[i], 0.5**j * 5.0)
        np.testing.assert_allclose(W.v[i], 2 * 0.5**j * 7.0)
    _, _, certificate = linear_case
    from_cert = TwoStageWeights.from_certificate(certificate)
    np.testing.assert_allclose(from_cert.prior, certificate.c_x * np.diag(1 / certificate.model.z_scale**2))
    np.testing.assert_allclose(from_cert.R_v, certificate.R_v)
    np.testing.assert_allclose(from_cert.R_y, certificate.R_y)
    assert from_cert.mu == certificate.mu


def test_certificate_gives_horizon_and_guarantee(linear_case):
    _, reduced, certificate = linear_case
    est = TwoStageUISE(reduced, certificate=certificate)
    assert certificate.min_horizon() == est.N and est.guaranteed and "Theorem 4.8 " in est.guarantee.theorem
    short = TwoStageUISE(reduced, certificate=certificate, N=1)
    assert certificate.min_horizon() > 1 and not short.guaranteed and "(Eq. (31) of" in short.guarantee.reason
    explicit = TwoStageUISE(reduced, weights=est.weights, N=5)
    assert not explicit.guaranteed and str(explicit.guarantee).startswith("none: explicit weights")
    assert "TwoStageUISE(" in repr(explicit) and "guarantee='none: explicit weights" in repr(explicit)
    result = explicit.run(None, np.zeros((3, 1)), x0_prior=np.zeros(3))
    assert isinstance(result, EstimationResult) and not result.guarantee.applies


class Uncertified:
    certified, mu, c_x, R_y, R_v, reason = False, 0.5, 1.0, None, None, "infeasible"

    def min_horizon(self):
        raise CertificationError("not certified")


def test_bad_arguments(linear_case):
    system, reduced, certificate = linear_case
    weights = TwoStageWeights.from_certificate(certificate)
    with pytest.raises(OptionError, match="reduced"):
        TwoStageUISE(system, weights=weights, N=3)
    with pytest.raises(OptionError, match="exactly one"):
        TwoStageUISE(reduced, certificate=certificate, weights=weights)
    with pytest.raises(OptionError, match="exactly one"):
        TwoStageUISE(reduced)
    with pytest.raises(OptionError, match="N: required"):
        TwoStageUISE(reduced, weights=weights)
    with pytest.raises(OptionError, match="projection"):
        TwoStageUISE(reduced, weights=weights, N=3, projection="nearest")
    with pytest.raises(OptionError, match=r"weights\.prior"):
        TwoStageUISE(reduced, weights=TwoStageWeights(mu=0.5, prior=np.eye(3), R_y=[[1.0]], R_v=[[1.0]]), N=3)
    with pytest.raises(OptionError, match="weights: expected a TwoStageWeights"):
        TwoStageUISE(reduced, weights=UISEWeights(mu=0.5, P=np.eye(3), R_y=[[1.0]], R_v=[[1.0]]), N=3)
    with pytest.raises(CertificationError, match="not certified"):
        TwoStageUISE(reduced, certificate=Uncertified())
    with pytest.raises(OptionError, match="certificate"):
        TwoStageUISE(reduced, certificate=object())
    with pytest.raises(OptionError, match="N"):
        TwoStageUISE(reduced, weights=weights, N=0)
    est = TwoStageUISE(reduced, weights=weights, N=3)
    with pytest.raises(OptionError, match="x0_prior: required"):
        est.step(None, [0.0])
    with pytest.raises(DataError, match=r"x0_prior: expected shape"):
        est.reset([0.0, 0.0])
    est.reset(np.zeros(3))
    with pytest.raises(DataError, match=r"y: expected shape \(1,\)"):
        est.step(None, [0.0, 0.0])
    with pytest.raises(DataError, match="u_prev"):
        est.step([1.0], [0.0])
    with pytest.raises(DataError, match=r"y: expected shape \(K\+1, 1\)"):
        est.run(None, np.zeros(4))


# ------------------------------------------------------------------------------------- streaming, failures, data


def test_streaming_equals_run_with_bounded_memory(closed_form_case):
    reduced, certificate = closed_form_case
    setup = get("closed-form").setup()
    traj = simulate(reduced.system, setup.x0, 20, u=setup.u, w=setup.w, v=UniformNoise.symmetric(1e-2), seed=3)
    N = 4
    est = TwoStageUISE(reduced, certificate=certificate, N=N, x0_prior=[0.0, 0.0])
    result = est.run(traj.u, traj.y)
    est.reset()
    for k in range(traj.steps + 1):
        step = est.step(None if k == 0 else traj.u[k - 1], traj.y[k])
        assert step.k == k and step.window == min(N, k)
        np.testing.assert_array_equal(step.x_hat, result.x_hat[k])
        if k:
            assert step.w_index == k - 1
            np.testing.assert_array_equal(step.w_hat, result.w_hat[k - 1])
        assert len(est._u) <= N and len(est._data) <= N and len(est._priors) <= N
    assert set(est._cache) == set(range(1, N + 1))  # one problem per window length 1..N


def test_failed_solve_propagates_the_reduced_model_and_strict_raises(closed_form_case, monkeypatch):
    reduced, certificate = closed_form_case
    setup = get("closed-form").setup()
    traj = simulate(reduced.system, setup.x0, 12, u=setup.u, w=setup.w)
    ref = []
    real = base_module.make_solver
    monkeypatch.setattr(base_module, "make_solver", lambda *a, **kw: FailingSolver(real(*a, **kw), ref, {7}))
    est = TwoStageUISE(reduced, certificate=certificate, N=4, x0_prior=[traj.y[0, 0], 0.0])
    ref.append(est)
    result = est.run(traj.u, traj.y)
    assert result.outcome[7] == Outcome.FAILED and result.solver_status[7] == "Injected_Failure"
    assert not result.success[7] and result.failures == 1
    # z_hat[7] = f_sharp(z_hat[6], y[6], u[6], v_bar) = a(y[6]) x2_hat[6] + u[6]; x1_hat[7] = y[7]
    x2 = closed_form.contraction_rate(traj.y[6, 0]) * result.x_hat[6, 1] + traj.u[6, 0]
    np.testing.assert_allclose(result.x_hat[7], [traj.y[7, 0], x2], rtol=1e-14)
    assert result.success[8] and np.isnan(result.cost[7])
    strict = TwoStageUISE(reduced, certificate=certificate, N=4, x0_prior=[traj.y[0, 0], 0.0], strict=True)
    ref[0] = strict
    with pytest.raises(SolverError, match="k=7"):
        strict.run(traj.u, traj.y)
    assert strict.k == 7  # the failed step was not committed


def test_missing_measurements_are_predicted_and_recorded():
    reduced = crop_growth.reduction()
    system, scenario = reduced.system, crop_growth.DEFAULT_SCENARIO
    traj = simulate(system, scenario.x0, 24, w=crop_growth.UnknownInputLaw())
    y = traj.y.copy()
    y[0, 1] = np.nan  # at k = 0 too
    y[5, 1] = np.nan  # y^d: psi does not use it, only its residual is dropped
    y[9:11] = np.nan  # whole samples: x^c[9], x^c[10] predicted with the last unknown-input estimate
    weights = crop_weights(reduced)
    result = TwoStageUISE(reduced, weights=weights, N=5).run(traj.u, y, x0_prior=traj.x[0])
    reference = TwoStageUISE(reduced, weights=weights, N=5).run(traj.u, traj.y, x0_prior=traj.x[0])
    assert result.failures == 0 and np.all(np.isfinite(result.x_hat))
    np.testing.assert_array_equal(result.missing, np.isnan(y))
    assert np.all(system.x.bounds.contains(result.x_hat))
    error = np.abs(result.error(traj.x))
    measured = ~np.isnan(y[:, 0])
    assert error[measured, 0].max() < 1e-15  # x^c exact wherever y^c exists
    np.testing.assert_allclose(result.x_hat[:9], reference.x_hat[:9], atol=1e-9)  # a missing y^d changes nothing
    assert error[9:11, 0].max() < 1e-6  # predicted x^c: the unknown input changes slowly here
    assert error[:, 1:].max() < 1e-5  # started at the truth, noise-free: the gap costs little
    # a run with whole windows missing is accepted (the gamma of every step is predicted)
    y_gap = traj.y.copy()
    y_gap[3:12] = np.nan
    gap = TwoStageUISE(reduced, weights=weights, N=3).run(traj.u, y_gap, x0_prior=traj.x[0])
    assert gap.failures == 0 and np.all(system.x.bounds.contains(gap.x_hat))


# ---------------------------------------------------------------------------------------------- building blocks


def test_reduced_window_model_and_node_constraints():
    reduced = crop_growth.reduction()
    model = WindowModel.from_reduced(reduced)
    assert (model.nx, model.nu, model.nw, model.nv, model.nd, model.ny, model.nc) == (2, 1, 0, 2, 2, 2, 3)
    assert model.f_uses_v  # psi(y, z, v) = y^c - v^c enters the reduced dynamics
    without = WindowModel.from_reduced(reduced, state_constraints=False)
    assert without.node_constraint is None
    W = WindowWeights(prior=np.eye(2), y=np.tile(np.eye(2), (3, 1, 1)), v=np.tile(np.eye(2), (3, 1, 1)))
    problem = WindowProblem(model, 3, [0, 1, 2], W)
    assert problem.system is None and problem.n_node_con == 3 * 3 and problem.n_con == 3 * 2 + 9
    with pytest.raises(OptionError, match="every node"):
        WindowProblem(model, 3, [0, 2], WindowWeights(prior=np.eye(2), y=W.y[:2], v=W.v[:2]))
    with pytest.raises(DataError, match="data"):
        problem.parameters(np.zeros(2), np.full((3, 1), 25.0), np.zeros((3, 2)))
    with pytest.raises(OptionError, match="System or a WindowModel"):
        WindowProblem("crop", 3, [0, 1, 2], W)
    # the node constraint is x = T^-1(psi(gamma, z, v), z) in X
    x = np.array([2e-3, 0.09, 0.085])
    z = np.asarray(reduced.T(x), dtype=float).ravel()
    c = np.asarray(model.node_constraint(z[1:], np.zeros(2), system_output := reduced.system.output(x)), dtype=float)
    np.testing.assert_allclose(c.ravel(), x, rtol=1e-14)
    assert system_output.shape == (2,)
    from_system = WindowModel.from_system(reduced.system)
    assert from_system.nd == 0 and not from_system.f_uses_v and from_system.nc == 0


def test_projection_exact_is_the_scaled_euclidean_projection():
    reduced = crop_growth.reduction()
    box = reduced.system.x.bounds
    exact, clip, none = (Projection(reduced, mode) for mode in ("exact", "clip", "none"))
    inside = np.array([2e-3, 0.09, 0.085])
    for proj in (exact, clip, none):
        np.testing.assert_array_equal(proj(inside), inside)
    outside = np.array([2e-3, 0.09, 0.075])  # x^{d,2} below X
    assert np.array_equal(none(outside), outside)
    np.testing.assert_array_equal(clip(outside), box.clip(outside))
    projected = exact(outside)
    assert box.contains(projected) and exact.used == 1

    def distance(x):
        dz = np.asarray(reduced.T(x), dtype=float).ravel() - np.asarray(reduced.T(outside), dtype=float).ravel()
        return np.linalg.norm(dz / exact.scale)

    rng = np.random.default_rng(0)
    candidates = box.clip(projected + 1e-4 * rng.standard_normal((500, 3)) * box.width)
    assert distance(projected) <= min(distance(c) for c in candidates) + 1e-12
    assert distance(projected) <= distance(clip(outside))


def test_input_fit_recovers_w_for_affine_and_nonlinear_models():
    crop = crop_growth.system()
    fit = InputFit(crop)
    assert fit.affine
    x = np.array([2e-3, 0.09, 0.085])
    x_next = crop.step(x, [25.0], [0.98])
    np.testing.assert_allclose(fit(x, np.array([25.0]), x_next, np.zeros(1)), [0.98], rtol=1e-9)
    xs, us, ws = ca.SX.sym("x", 1), ca.SX.sym("u", 0), ca.SX.sym("w", 1)
    cubic = System.from_expressions(xs, us, ws, ca.SX.sym("v", 1), 0.5 * xs + ws + 0.1 * ws**3, xs)
    fit = InputFit(cubic)
    assert not fit.affine
    target = cubic.step([1.0], None, [2.5])
    np.testing.assert_allclose(fit(np.array([1.0]), np.zeros(0), target, np.zeros(1)), [2.5], rtol=1e-12)


def test_polish_reaches_the_linear_least_squares_optimum():
    """A loose IPOPT solve of a linear window problem, refined: the exact optimum (one Gauss-Newton step)."""
    system = linear.linear_system([[0.9, 0.2], [-0.1, 0.7]], [[1.0], [0.5]], [[1.0, 0.0]], v_bounds=(-10, 10))
    rng = np.random.default_rng(0)
    L = 6
    W = WindowWeights(prior=np.eye(2), y=np.full((L + 1, 1, 1), 1e6), v=np.ones((L + 1, 1, 1)))
    problem = WindowProblem(system, L, list(range(L + 1)), W)
    p = problem.parameters(rng.standard_normal(2), np.zeros((L, 0)), rng.standard_normal((L + 1, 1)))
    tight = make_solver("ipopt", problem).solve(np.zeros(problem.n_var), p)
    off = tight.z + 1e-3 * rng.standard_normal(problem.n_var)  # infeasible and suboptimal
    z, cost, steps = refine(problem, off, p)
    assert steps >= 1 and np.abs(z - tight.z).max() < 1e-9
    assert cost == pytest.approx(tight.cost, rel=1e-8)
    polished = make_solver("ipopt", problem, polish=True).solve(np.zeros(problem.n_var), p)
    assert polished.success and np.abs(polished.z - tight.z).max() < 1e-9
    # an active bound stays active: the box of the first state pins x_0[0]
    boxed = WindowProblem(system, L, list(range(L + 1)), W, x_box=Box((-0.1, -10.0), (0.1, 10.0)))
    p_far = boxed.parameters(np.array([5.0, 0.0]), np.zeros((L, 0)), np.full((L + 1, 1), 5.0))
    solution = make_solver("ipopt", boxed, polish=True).solve(np.zeros(boxed.n_var), p_far)
    x = boxed.unpack(solution.z).x
    assert solution.success and np.all(x[:, 0] <= 0.1 + 1e-9) and x[:, 0].max() == pytest.approx(0.1, abs=1e-7)


def test_missing_outputs_hold_the_input_and_say_so_and_the_step_after_has_no_input_estimate():
    # the unknown input reaches the measured x1, missing for k = 10..14: the two-stage UISE fills it with the held
    # input, and every such step said "solved" without held_input; after the gap the fit of w[14] put the whole
    # gap's drift into one step (0.88 against a true 0.17)
    import three_outputs

    system = three_outputs.system()
    reduced = ReducedModel.from_maps(system, lambda x: x, lambda z: z, lambda y, z, v: [y[0] - v[0]], n_flat=1)
    K = 40
    u = np.column_stack([np.sin(0.3 * np.arange(K)), np.cos(0.2 * np.arange(K))])
    truth = simulate(system, [1.0, -0.5, 0.3, 2.0], K, u=u, w=lambda k, x: [-0.9 * x[0] + 0.5 * np.sin(0.4 * k)],
                     v=UniformNoise.symmetric(1e-3), seed=1)  # fmt: skip
    y = truth.y.copy()
    y[10:15, 0] = np.nan
    result = TwoStageUISE(reduced, certificate=certify_reduced_model(reduced), x0_prior=np.zeros(4)).run(u, y)
    assert result.held_input[10:15].all() and not result.held_input[15:].any()
    assert np.isnan(result.w_hat[14]).all() and np.all(np.isfinite(result.w_hat[15:]))
    assert np.abs(result.w_hat[16:] - truth.w[16:]).max() < 0.05
    y = truth.y.copy()
    y[10:15, 1] = np.nan  # an output psi does not use: only its residual drops, the input is not held
    other = TwoStageUISE(reduced, certificate=certify_reduced_model(reduced), x0_prior=np.zeros(4)).run(u, y)
    assert not other.held_input.any() and np.all(np.isfinite(other.w_hat))
