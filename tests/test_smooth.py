"""The smooth-input MHE: the augmented model, known answers (Kalman filter, the window's least squares), sampled
mechanical systems whose sampling zero defeats the UISE, jumps, guarantees, bad input, CLI and study."""

import json
import warnings

import numpy as np
import pandas as pd
import pytest
from scipy.integrate import solve_ivp
from typer.testing import CliRunner

from uiest import BoundWarning, CertificationError, DataError, ModelError, OptionError, System, UniformNoise, simulate
from uiest.augmented import W_SPREAD, augmented_system
from uiest.cli import app
from uiest.detectability import certify_delta_ioss, invariant_zeros
from uiest.estimators import EKF, UISE, MHEWeights, SmoothInputMHE, StandardMHE, UISEWeights, Verdict
from uiest.estimators.smooth_mhe import variance_weights
from uiest.models import linear

DT = 0.05


def double_integrator(v_bound=1e-3, x_bound=10.0):
    """A force on a mass, its position measured, sampled exactly: the zero at -1 of every ZOH double integrator."""
    A, B, C = [[1.0, DT], [0.0, 1.0]], [[DT**2 / 2], [DT]], [[1.0, 0.0]]
    return linear.linear_system(A, B, C, x_bounds=(-x_bound, x_bound), v_bounds=(-v_bound, v_bound),
                                name="double-integrator"), np.array(A), np.array(B), np.array(C)  # fmt: skip


def pendulum():
    """A damped pendulum with an unknown torque, its angle measured (the issue's model)."""
    return System.from_ode(lambda x, u, w: [x[1], -9.81 * np.sin(x[0]) - 0.5 * x[1] + w[0]],
                           lambda x, v: [x[0] + v[0]], nx=2, nw=1, nv=1, dt=DT,
                           x_bounds=((-3.0, -8.0), (3.0, 8.0)), v_bounds=(-1e-3, 1e-3),
                           x_names=("theta", "omega"), w_names=("torque",), name="pendulum")  # fmt: skip


def spring_cart():
    """A cart on a spring with friction and an unknown force, its position measured."""
    return System.from_ode(lambda x, u, w: [x[1], -4.0 * x[0] - 0.4 * x[1] + w[0]], lambda x, v: [x[0] + v[0]],
                           nx=2, nw=1, nv=1, dt=DT, x_bounds=((-10.0, -10.0), (10.0, 10.0)), v_bounds=(-1e-3, 1e-3),
                           x_names=("p", "speed"), w_names=("force",), name="cart")  # fmt: skip


PENDULUM_RHS = lambda x, w: [x[1], -9.81 * np.sin(x[0]) - 0.5 * x[1] + w]  # noqa: E731
CART_RHS = lambda x, w: [x[1], -4.0 * x[0] - 0.4 * x[1] + w]  # noqa: E731


def measured(rhs, x0, w, seed=0):
    """States by scipy's solve_ivp with w held over each sample, and the first state measured with noise in 1e-3."""
    x = np.zeros((len(w) + 1, len(x0)))
    x[0] = x0
    for k, wk in enumerate(w[:, 0]):
        x[k + 1] = solve_ivp(lambda t, z, wk=wk: rhs(z, wk), (0.0, DT), x[k], rtol=1e-11, atol=1e-11).y[:, -1]
    y = x[:, :1] + np.random.default_rng(seed).uniform(-1e-3, 1e-3, (len(x), 1))
    return x, y


def rms(a):
    return float(np.sqrt(np.mean(np.square(a))))


# ---------------------------------------------------------------------------------------------- the augmented model


def test_the_augmented_model_moves_w_by_its_increment():
    system = pendulum()
    aug = augmented_system(system, 0.2, (-20.0, 20.0))
    assert (aug.nx, aug.nu, aug.nw, aug.nv, aug.ny, aug.dt) == (3, 0, 1, 1, 1, DT)
    assert aug.x.names == ("theta", "omega", "torque") and aug.w.names == ("delta_torque",)
    np.testing.assert_array_equal(aug.x.bounds.lower, [-3.0, -8.0, -20.0])
    np.testing.assert_array_equal(aug.w_range.upper, [0.2])
    np.testing.assert_array_equal(aug.x.scale, [6.0, 16.0, 1.0])
    assert aug.w.scale[0] == pytest.approx(0.4)  # the range's width
    z, dw = np.array([0.3, -1.0, 2.5]), np.array([0.1])
    np.testing.assert_allclose(aug.step(z, None, dw), [*system.step(z[:2], None, z[2:]), 2.6], rtol=1e-14)
    np.testing.assert_allclose(aug.output(z, [1e-4]), system.output(z[:2], [1e-4]), rtol=1e-14)
    # W: the system's known range of w, else nominal_w +- W_SPREAD w.scale
    np.testing.assert_array_equal(augmented_system(system, 0.2).x.bounds.upper[2:], [W_SPREAD])
    ranged, *_ = linear.with_invariant_zeros([0.5], x_bounds=(-5, 5), w_range=(-3.0, 1.0))
    np.testing.assert_array_equal(augmented_system(ranged, [0.5]).x.bounds.lower[-1:], [-3.0])


def test_the_augmented_model_refuses_bad_input():
    system = pendulum()
    for bad in (0.0, -1.0, np.inf, [0.1, 0.2], "a"):
        with pytest.raises(OptionError, match="dw_bound: expected a positive finite number"):
            augmented_system(system, bad)
    with pytest.raises(ModelError, match="w_bounds: expected a bounded range"):
        augmented_system(system, 0.1, (-np.inf, 1.0))
    with pytest.raises(ModelError, match="w_bounds: expected scalars or bounds of length 1"):
        augmented_system(system, 0.1, ([0, 0], [1, 1]))
    with pytest.raises(OptionError, match=r"system: expected a uiest\.System"):
        augmented_system("pendulum", 0.1)
    no_input = System.from_callables(lambda x, u, w: [0.5 * x[0]], lambda x, v: [x[0] + v[0]], nx=1, nw=0, nv=1)
    with pytest.raises(ModelError, match="nw >= 1"):
        augmented_system(no_input, 0.1)


def test_a_sampling_zero_at_minus_one_defeats_strong_detectability_not_the_augmented_model():
    system, A, B, C = double_integrator()
    assert np.min(np.abs(np.abs(invariant_zeros(A, B, C)) - 1.0)) < 1e-9  # the zero at -1: no UISE certificate
    cert = certify_delta_ioss(augmented_system(system, 0.3))
    assert cert.certified, cert.reason
    mhe = SmoothInputMHE(system, certificate=cert, x0_prior=[0.0, 0.0])
    assert cert.min_horizon() == mhe.N and mhe.guarantee.applies
    assert mhe.guarantee.condition == "delta_w[0] in [-0.3, 0.3] per sample and w[0] in [-100, 100]"
    # the statistical weights keep Assumption 1 (Schiller et al.) of the certificate, checked on random pairs
    rng = np.random.default_rng(0)
    aug, w = mhe.augmented, mhe.weights
    Z = aug.x.bounds
    z, zt = Z.sample(rng, 2000), Z.sample(rng, 2000)
    d, dt_ = rng.uniform(-0.3, 0.3, (2000, 1)), rng.uniform(-0.3, 0.3, (2000, 1))
    v, vt = rng.uniform(-1e-3, 1e-3, (2000, 1)), rng.uniform(-1e-3, 1e-3, (2000, 1))
    dz = aug.step(z, None, d) - aug.step(zt, None, dt_)
    dy = aug.output(z, v) - aug.output(zt, vt)
    lhs = np.einsum("mi,ij,mj->m", dz, w.P, dz)
    rhs = (w.eta * np.einsum("mi,ij,mj->m", z - zt, w.P, z - zt) + np.einsum("mi,ij,mj->m", d - dt_, w.Q_w, d - dt_)
           + np.einsum("mi,ij,mj->m", v - vt, w.Q_v, v - vt) + np.einsum("mi,ij,mj->m", dy, w.R, dy))  # fmt: skip
    assert np.all(lhs <= rhs * (1 + 1e-9))
    # ... and dominate the certificate scaled to the same prior
    scale = w.P[0, 0] / cert.P[0, 0]
    np.testing.assert_allclose(w.P, scale * cert.P, rtol=1e-12)
    for mine, theirs in ((w.Q_w, cert.Q_w), (w.Q_v, cert.Q_v), (w.R, cert.R)):
        assert np.all(np.linalg.eigvalsh(mine - scale * theirs) >= -1e-9 * np.abs(mine).max())


# ---------------------------------------------------------------------------------------------- known answers


@pytest.mark.slow
def test_while_the_window_holds_every_sample_it_is_the_kalman_filter():
    # linear, Gaussian weights, no discount (eta -> 1), N >= K: the full-information estimate, which the Kalman filter's
    # mean is; the EKF's augmented model is the same random walk with the same variances and priors
    system, *_ = double_integrator(v_bound=0.05, x_bound=100.0)
    K, variance = 60, 0.02
    w = (np.sin(0.3 * np.arange(K)) + 0.5)[:, None]
    traj = simulate(system, [0.5, -1.0], K, w=w, v=UniformNoise.symmetric(0.01), seed=1)
    aug = augmented_system(system, 3 * np.sqrt(variance))
    mhe = SmoothInputMHE(system, weights=variance_weights(aug, variance, 1.0 - 1e-12), dw_variance=variance, N=K,
                         x0_prior=[0.0, 0.0])  # fmt: skip
    ekf = EKF(system, w_variance=variance, x0_prior=[0.0, 0.0]).run(None, traj.y)
    result = mhe.run(None, traj.y)
    assert result.failures == 0 and not result.guarantee.applies
    np.testing.assert_allclose(result.x_hat, ekf.x_hat, atol=1e-7)
    np.testing.assert_allclose(result.w_hat, ekf.w_hat, atol=1e-6)
    assert rms(result.x_hat - traj.x) < 0.2  # not a vacuous agreement: both track the truth


def window_least_squares(A, B, C, weights, L, prior, y_window):
    """The smooth-input MHE's window problem for a linear model (module docstring of smooth_mhe), solved by lstsq."""
    n, nw = A.shape[0] + B.shape[1], B.shape[1]
    Abar = np.block([[A, B], [np.zeros((nw, A.shape[0])), np.eye(nw)]])
    Bbar = np.vstack([np.zeros((A.shape[0], nw)), np.eye(nw)])
    Cbar = np.hstack([C, np.zeros((C.shape[0], nw))])
    n_theta = n + L * nw + (L + 1)
    states = []  # z_i = S_i theta
    S = np.zeros((n, n_theta))
    S[:, :n] = np.eye(n)
    for i in range(L + 1):
        states.append(S.copy())
        S = Abar @ S
        S[:, n + i * nw : n + (i + 1) * nw] += Bbar
    rows, rhs = [], []

    def add(weight, M, b):
        root = np.linalg.cholesky(weight + 1e-300 * np.eye(len(weight))).T
        rows.append(root @ M)
        rhs.append(root @ b)

    eta = weights.eta
    add(2 * eta**L * weights.P, states[0], prior)
    for i in range(L):
        M = np.zeros((nw, n_theta))
        M[:, n + i * nw : n + (i + 1) * nw] = np.eye(nw)
        add(2 * eta ** (L - i - 1) * weights.Q_w, M, np.zeros(nw))
    for i in range(L + 1):
        V = np.zeros((1, n_theta))
        V[0, n + L * nw + i] = 1.0
        add(2 * eta ** (L - i - 1) * weights.Q_v, V, np.zeros(1))
        add(eta ** (L - i - 1) * weights.R, Cbar @ states[i] + V, y_window[i])
    theta = np.linalg.lstsq(np.vstack(rows), np.concatenate(rhs), rcond=None)[0]
    return [Si @ theta for Si in states]


def test_the_sliding_window_solves_its_least_squares_problem_with_the_prior_rule():
    system, A, B, C = double_integrator(v_bound=0.05, x_bound=100.0)
    cert = certify_delta_ioss(augmented_system(system, 0.3, (-50.0, 50.0)))
    N, K = 4, 30
    mhe = SmoothInputMHE(system, certificate=cert, dw_variance=0.005, N=N, x0_prior=[0.2, 0.0], w0_prior=[1.0])
    w = (2.0 * np.cos(0.2 * np.arange(K)))[:, None]
    traj = simulate(system, [0.0, 0.5], K, w=w, v=UniformNoise.symmetric(0.01), seed=3)
    result = mhe.run(None, traj.y)
    delivered = []  # the newest node of each window: the prior N steps later
    for k in range(K + 1):
        L = min(N, k)
        prior = np.array([0.2, 0.0, 1.0]) if k - L == 0 else delivered[k - L]
        nodes = window_least_squares(A, B, C, mhe.weights, L, prior, traj.y[k - L : k + 1])
        delivered.append(nodes[-1])
        np.testing.assert_allclose(result.x_hat[k], nodes[-1][:2], atol=1e-7, err_msg=f"k={k}")
        if k:
            np.testing.assert_allclose(result.w_hat[k - 1], nodes[-2][2:], atol=1e-6, err_msg=f"k={k}")
    assert cert.min_horizon() > N and "N=4 < min_horizon()" in result.guarantee.reason  # a short window, no guarantee


def test_a_window_that_starts_where_arrival_weights_are_given_is_weighted_by_them():
    # the weight of a window's prior is arrival_P[s] for the window that starts at time s (the uncertainty of the
    # estimate it starts from), the weights' P after them
    import dataclasses

    system, A, B, C = double_integrator(v_bound=0.05, x_bound=100.0)
    N, K, variance = 4, 16, 0.005
    weights = variance_weights(augmented_system(system, 3 * np.sqrt(variance)), variance, 0.9)
    arrival = np.array([(1.0 + 3.0 * s) * weights.P for s in range(7)])
    mhe = SmoothInputMHE(system, weights=weights, dw_variance=variance, N=N, x0_prior=[0.2, 0.0], w0_prior=[1.0],
                         arrival_P=arrival)  # fmt: skip
    w = (2.0 * np.cos(0.2 * np.arange(K)))[:, None]
    traj = simulate(system, [0.0, 0.5], K, w=w, v=UniformNoise.symmetric(0.01), seed=3)
    result = mhe.run(None, traj.y)
    delivered = []
    for k in range(K + 1):
        L, start = min(N, k), max(k - N, 0)
        prior = np.array([0.2, 0.0, 1.0]) if start == 0 else delivered[start]
        own = dataclasses.replace(weights, P=arrival[start]) if start < len(arrival) else weights
        nodes = window_least_squares(A, B, C, own, L, prior, traj.y[k - L : k + 1])
        delivered.append(nodes[-1])
        np.testing.assert_allclose(result.x_hat[k], nodes[-1][:2], atol=1e-7, err_msg=f"k={k}")
    with pytest.raises(OptionError, match="arrival_P: expected finite"):
        SmoothInputMHE(system, weights=weights, dw_variance=variance, N=N, arrival_P=np.eye(3))
    with pytest.raises(OptionError, match="arrival_P: expected symmetric positive semi-definite"):
        SmoothInputMHE(system, weights=weights, dw_variance=variance, N=N, arrival_P=-np.eye(3)[None])


# ---------------------------------------------------------------------------------------------- sampled mechanics


@pytest.fixture(scope="module")
def pendulum_record():
    K = 300
    torque = (2.0 * np.sin(0.8 * DT * np.arange(K)))[:, None]
    x, y = measured(PENDULUM_RHS, [0.5, 0.0], torque)
    return x, torque, y


@pytest.mark.slow
def test_on_the_pendulum_the_uise_fails_and_the_smooth_mhe_matches_a_well_tuned_ekf(pendulum_record):
    system = pendulum()
    x, torque, y = pendulum_record
    settled = slice(20, None)
    uise = UISE(system, weights=UISEWeights.from_scales(system, 0.8), N=20, x0_prior=[0.5, 0.0]).run(None, y)
    ekf = {q: EKF(system, w_variance=q, x0_prior=[0.5, 0.0]).run(None, y) for q in (1e-3, 1e-2, 1e-1, 1.0, 10.0)}
    best = min(rms(r.x_hat[settled, 1] - x[settled, 1]) for r in ekf.values())
    mhe = SmoothInputMHE.design(system, dw_variance=0.01, w_bounds=(-20.0, 20.0), x0_prior=[0.5, 0.0])
    result = mhe.run(None, y)
    smooth = rms(result.x_hat[settled, 1] - x[settled, 1])
    # measured: UISE 0.21 rad/s (its torque estimate up to 25 against 2), EKF best 0.0097 (q = 1e-2), smooth MHE 0.0106
    assert rms(uise.x_hat[settled, 1] - x[settled, 1]) > 10 * smooth
    assert smooth < 1.5 * best and result.failures == 0
    assert rms(result.w_hat[settled] - torque[settled]) < 0.3  # measured 0.12
    assert mhe.certificate is not None and result.guarantee.applies
    assert result.cpu_time.shape == (301,) and np.all(result.cpu_time >= 0)


@pytest.mark.parametrize("model", ["pendulum", "cart"])
@pytest.mark.slow
def test_after_a_jump_of_the_unknown_input_the_smooth_mhe_beats_the_ekf_with_its_variance(model):
    # a step of 12 times the smooth part's amplitude, after which the state stays in X; both estimators use the
    # increment variance that suits the smooth part (the EKF's best on the pendulum's smooth record is near 1e-3..1e-2)
    system, rhs = (pendulum(), PENDULUM_RHS) if model == "pendulum" else (spring_cart(), CART_RHS)
    K, variance = 300, 0.01
    w = (0.5 * np.sin(0.8 * DT * np.arange(K)) + 6.0 * (np.arange(K) >= K // 2))[:, None]
    x, y = measured(rhs, [0.5, 0.0] if model == "pendulum" else [0.0, 0.0], w)
    after = slice(K // 2, K // 2 + 40)
    x0 = x[0] + np.array([0.05, 0.0])
    ekf = EKF(system, w_variance=variance, x0_prior=x0).run(None, y)
    result = SmoothInputMHE.design(system, dw_variance=variance, w_bounds=(-20.0, 20.0), x0_prior=x0).run(None, y)
    smooth, filtered = rms(result.x_hat[after] - x[after]), rms(ekf.x_hat[after] - x[after])
    # measured (state RMS over the 40 samples after the jump): pendulum 0.036 against 0.048, cart 0.039 against 0.048
    assert smooth < 0.85 * filtered and result.failures == 0


@pytest.mark.slow
def test_bounded_increments_hold_each_window_to_the_bound_and_penalised_ones_follow_a_jump():
    system = spring_cart()
    K = 120
    w = (0.5 + 5.0 * (np.arange(K) >= 60))[:, None]
    x, y = measured(CART_RHS, [0.0, 0.0], w)
    kw = {"dw_variance": 0.01, "w_bounds": (-20.0, 20.0), "x0_prior": [0.0, 0.0]}
    largest, error = {}, {}
    for held in (True, False):
        mhe = SmoothInputMHE.design(system, constrain_increments=held, **kw)
        steps = [mhe.step(None, yk) for yk in y]
        largest[held] = max(float(np.max(np.abs(s.trajectory.w), initial=0.0)) for s in steps)
        error[held] = rms([s.x_hat - xk for s, xk in zip(steps[62:68], x[62:68], strict=True)])
    assert largest[True] <= 0.3 * (1 + 1e-9)  # the bound: 3 standard deviations of the increments
    assert largest[False] > 1.0  # the jump of 5 within one window
    assert error[False] < 0.6 * error[True]  # measured 0.066 against 0.20 in the samples 2..7 after the jump


# ---------------------------------------------------------------------------------------------- guarantees, errors


@pytest.mark.slow
def test_the_error_stays_within_the_guarantee_and_an_outage_is_bridged():
    system = linear.example()  # zeros {0.5, 0.2}; X = +-10
    variance, K = 1e-4, 300
    mhe = SmoothInputMHE.design(system, dw_variance=variance, w_bounds=(-5.0, 5.0), x0_prior=np.zeros(3), lag=3)
    g = mhe.guarantee
    assert g.verdict is Verdict.INFORMATIVE, g.text  # measured: x[0] 13.8, x[1] 7.42, x[2] 17 after 19 steps
    steps = 3 * np.sqrt(variance) * np.random.default_rng(0).choice([-1.0, 1.0], K)  # increments at their bound
    w = np.clip(np.cumsum(steps), -5.0, 5.0)[:, None]
    traj = simulate(system, np.zeros(3), K, w=w, v=UniformNoise.symmetric(1e-3), seed=1)
    result = mhe.run(None, traj.y)
    assert np.all(np.abs(result.x_hat - traj.x)[g.settling_steps :] <= g.error_bound)  # measured at most 0.0023
    y = traj.y.copy()
    y[100:140] = np.nan  # longer than the window: propagated with the input held, then solved again
    gap = mhe.run(None, y)
    # the samples of the outage beyond the window used (N capped at the weights' information horizon)
    assert gap.failures == 0 and np.count_nonzero(gap.outcome == "propagated") == 40 - mhe.N
    assert rms(gap.x_hat[200:] - traj.x[200:]) < 1.01 * rms(result.x_hat[200:] - traj.x[200:])  # measured equal
    assert np.all(np.isfinite(gap.x_lag[:100])) and np.all(np.isnan(gap.x_lag[-3:]))  # x[k-3] from window k


def test_the_guarantee_says_none_and_why_without_a_certificate_or_window():
    system, *_ = double_integrator()
    # X unbounded: no certificate; design falls back to explicit weights and says why
    unbounded, *_ = double_integrator(x_bound=np.inf)
    fallback = SmoothInputMHE.design(unbounded, dw_variance=0.01, x0_prior=[0.0, 0.0])
    assert fallback.certificate is None and fallback.guarantee.verdict is Verdict.NONE
    assert "augmented model's delta-IOSS is not certified" in fallback.guarantee.reason
    assert "a certificate needs a bounded state domain" in fallback.guarantee.reason
    cert = certify_delta_ioss(augmented_system(system, 0.3))
    short = SmoothInputMHE(system, certificate=cert, N=1, x0_prior=[0.0, 0.0])
    assert cert.min_horizon() > 1 and "N=1 < min_horizon()" in short.guarantee.reason
    explicit = SmoothInputMHE(system, weights=variance_weights(augmented_system(system, 0.3), 0.01, 0.8), N=5,
                              dw_bound=0.3, x0_prior=[0.0, 0.0])  # fmt: skip
    assert explicit.guarantee.reason == "explicit weights without a delta-IOSS certificate of the augmented model"
    # a certified one: bounds per state in the state's units, vacuous where they exceed X's width
    g = SmoothInputMHE(system, certificate=cert, x0_prior=[0.0, 0.0]).guarantee
    assert g.applies and g.error_bound.shape == (2,) and np.all(np.isfinite(g.error_bound))
    assert g.verdict in (Verdict.INFORMATIVE, Verdict.VACUOUS, Verdict.PARTIAL)
    assert g.text.startswith("holds while delta_w[0] in [-0.3, 0.3] per sample")


def test_bad_input_gets_typed_errors():
    system, *_ = double_integrator()
    aug = augmented_system(system, 0.3)
    cert = certify_delta_ioss(aug)
    weights = variance_weights(aug, 0.01, 0.8)
    with pytest.raises(OptionError, match="dw_bound, dw_variance: expected at least one"):
        SmoothInputMHE(system, weights=weights, N=5)
    with pytest.raises(OptionError, match="dw_variance: expected a positive finite number"):
        SmoothInputMHE(system, weights=weights, N=5, dw_variance=-1.0)
    with pytest.raises(OptionError, match="certificate's augmented model has them"):
        SmoothInputMHE(system, certificate=cert, dw_bound=0.3)
    with pytest.raises(OptionError, match="certificate, weights: expected exactly one"):
        SmoothInputMHE(system, dw_bound=0.3)
    with pytest.raises(OptionError, match="certificate: expected a certificate of augmented_system"):
        SmoothInputMHE(system, certificate=certify_delta_ioss(system, w_bounds=(-1, 1)))
    other, *_ = double_integrator(x_bound=10.0)
    wrong = certify_delta_ioss(augmented_system(spring_cart(), 0.3))
    with pytest.raises(OptionError, match="f or h differs from the augmented model"):
        SmoothInputMHE(other, certificate=wrong)
    with pytest.raises(CertificationError, match="delta-IOSS is not certified"):
        SmoothInputMHE(system, certificate=certify_delta_ioss(aug, eta=1e-3))
    with pytest.raises(OptionError, match=r"weights.P: expected shape \(3, 3\)"):
        SmoothInputMHE(system, weights=MHEWeights.from_scales(system, 0.8), dw_bound=0.3, N=5)
    with pytest.raises(DataError, match="w0_prior: expected a point in W"):
        SmoothInputMHE(system, certificate=cert, w0_prior=[1e3])
    with pytest.raises(DataError, match=r"x0_prior: expected shape \(2,\)"):
        SmoothInputMHE(system, certificate=cert, x0_prior=[0.0, 0.0, 0.0])
    with pytest.raises(OptionError, match="constrain_increments: expected True or False"):
        SmoothInputMHE(system, certificate=cert, constrain_increments="yes")
    with pytest.raises(OptionError, match="options: unknown"):
        SmoothInputMHE(system, certificate=cert, horizon=5)
    with pytest.raises(OptionError, match=r"system: expected a uiest\.System"):
        SmoothInputMHE.design("system", dw_variance=0.01)


@pytest.mark.slow
def test_cpu_per_sample_is_recorded_beside_the_standard_mhe_on_the_same_model(pendulum_record):
    # the numbers go to docs/performance.md (bench/smooth_mhe.py); here only that both are measured per step, by thread
    # CPU time
    system = pendulum()
    _, _, y = pendulum_record
    mhe = SmoothInputMHE.design(system, dw_variance=0.01, w_bounds=(-20.0, 20.0), x0_prior=[0.5, 0.0])
    standard = StandardMHE(system, certificate=certify_delta_ioss(system, w_bounds=(-20.0, 20.0)), N=mhe.N,
                           x0_prior=[0.5, 0.0])  # fmt: skip
    for result in (mhe.run(None, y[:60]), standard.run(None, y[:60])):
        assert result.cpu_time.shape == (60,) and result.cpu_time[1:].sum() > 0 and result.failures == 0


# ---------------------------------------------------------------------------------------------- CLI and studies


@pytest.mark.slow
def test_uiest_estimate_runs_the_smooth_input_mhe_on_a_model_file(tmp_path, pendulum_record):
    model = tmp_path / "pendulum.py"
    model.write_text(
        "import numpy as np\nfrom uiest import System\n\n"
        "system = System.from_ode(lambda x, u, w: [x[1], -9.81 * np.sin(x[0]) - 0.5 * x[1] + w[0]],\n"
        "                         lambda x, v: [x[0] + v[0]], nx=2, nw=1, nv=1, dt=0.05,\n"
        "                         x_bounds=((-3.0, -8.0), (3.0, 8.0)), v_bounds=(-1e-3, 1e-3),\n"
        "                         x_names=('theta', 'omega'), w_names=('torque',), name='pendulum')\n"
    )
    x, _, y = pendulum_record
    data = tmp_path / "data.csv"
    pd.DataFrame({"t": DT * np.arange(len(y)), "y[0]": y[:, 0], "theta": x[:, 0], "omega": x[:, 1]}).to_csv(data)
    out = tmp_path / "out"
    result = CliRunner().invoke(app, ["estimate", str(model), "--data", str(data), "--estimator", "smooth",
                                      "--w-variance", "0.01", "--x0", "0.5,0", "--out", str(out)])  # fmt: skip
    assert result.exit_code == 0, result.output
    estimates = pd.read_csv(out / "estimates_smooth.csv")
    assert rms(estimates["omega_hat"][20:] - x[20:, 1]) < 0.03  # measured 0.0107 (the Python run's)
    # without --w-variance: the EKF's random-walk variance fitted to the record by likelihood, as its increments'
    fitted = CliRunner().invoke(app, ["estimate", str(model), "--data", str(data), "--estimator", "smooth",
                                      "--x0", "0.5,0", "--out", str(out)], terminal_width=400)  # fmt: skip
    assert fitted.exit_code == 0, fitted.output
    assert "increment variance" in json.loads((out / "manifest.json").read_text())["weights"]["smooth"]
    estimates = pd.read_csv(out / "estimates_smooth.csv")
    assert rms(estimates["omega_hat"][20:] - x[20:, 1]) < 0.03
    from uiest.estimate import build_estimator
    from uiest.models import load

    entry = load(model)
    mhe, note = build_estimator("smooth", entry, entry.build(), np.array([0.5, 0.0]), w_variance=0.01)
    assert note.startswith("delta-IOSS certificate of the augmented model: eta=") and mhe.guarantee.applies
    per_step = f"torque {0.01 * mhe.system.w.scale[0] ** 2:.3g} per step"
    assert note.endswith(f"increment variance 0.01 w.scale^2 = {per_step} (given)")
    assert mhe.certificate.min_horizon() <= mhe.N


def test_a_study_runs_the_smooth_input_mhe_kind():
    from uiest.experiments import EstimatorSpec, Scenario, run_study

    specs = (EstimatorSpec("smooth (certificate)", "smooth-mhe", weights="certificate", N=0, w_variance=1e-2),
             EstimatorSpec("smooth", "smooth-mhe", N=8, mu=0.8, w_variance=1e-2))  # fmt: skip
    scenario = Scenario(name="smooth", model="linear-example", steps=40, runs=1, cases=("noisy",), estimators=specs)
    study = run_study(scenario)
    assert study.runs["error"].eq("").all() and study.runs["failures"].eq(0).all()
    certified = study.results[("noisy", 0, "smooth (certificate)")]
    assert certified.guarantee.applies and not study.results[("noisy", 0, "smooth")].guarantee.applies
    (row,) = study.certificates
    assert row["status"] == "certified" and row["certificate"].startswith("delta-IOSS of the model with w as a state")
    truth = study.truths[("noisy", 0)]
    assert rms(certified.x_hat[10:] - truth.x[10:]) < 0.1 * float(np.max(np.abs(truth.x)))


def test_a_run_warns_when_the_input_estimate_sits_at_w_s_side():
    # W defaults to nominal_w +- 100 w.scale: an input of 150 is estimated at 100 and the states err with it; the run
    # once said nothing (its windows were counted "at X's side")
    system, *_ = double_integrator(x_bound=1e5)
    w = np.where(np.arange(40) >= 10, 150.0, 0.0)[:, None]
    traj = simulate(system, [0.0, 0.0], 40, w=w, v=UniformNoise.symmetric(1e-3), seed=0)
    variance = 100.0
    for bounds, expected in ((None, 100.0), ((-1000.0, 1000.0), None)):
        aug = augmented_system(system, 3 * np.sqrt(variance), bounds)
        mhe = SmoothInputMHE(system, weights=variance_weights(aug, variance, 0.8), dw_variance=variance,
                             w_bounds=bounds, N=10, x0_prior=[0.0, 0.0])  # fmt: skip
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            result = mhe.run(None, traj.y)
        said = [str(c.message) for c in caught if issubclass(c.category, BoundWarning)]
        if expected is None:
            assert not said and np.nanmax(result.w_hat) > 140.0
        else:
            assert np.nanmax(result.w_hat) == pytest.approx(expected, rel=1e-6)
            assert len(said) == 1 and "the unknown-input estimate of w[0] at or beyond W's upper side 100 in" in said[0]


def test_a_design_whose_estimator_has_no_guarantee_says_so():
    # certified with min_horizon() = 4, but the certified weights' information horizon caps the window at 3: the
    # design once returned that estimator without a word (its guarantee said none, and why)
    import three_outputs

    system = three_outputs.system()
    with pytest.warns(UserWarning, match="SmoothInputMHE.design: certified, but the estimator's guarantee is none: N="):
        mhe = SmoothInputMHE.design(system, dw_variance=0.1, w_bounds=(-10, 10), x0_prior=np.zeros(4))
    assert mhe.certificate is not None and mhe.horizon_capped and not mhe.guarantee.applies
