"""EKF and UKF with the unknown input as a random walk: exact on linear Gaussian models, tuning, bad input."""

import pickle
from copy import deepcopy

import casadi as ca
import numpy as np
import pytest

from uiest import BoundWarning, DataError, OptionError, System, simulate
from uiest.estimators import EKF, UISE, UKF, Outcome
from uiest.models import linear

A = np.array([[0.8, 0.3, 0.0], [-0.2, 0.7, 0.4], [0.1, -0.3, 0.6]])
B, C, B_U = np.array([[1.0], [0.0], [0.5]]), np.array([[1.0, 0, 0], [0, 1.0, 0]]), np.array([[0.0], [1.0], [0.0]])


def _system():
    return linear.linear_system(A, B, C, B_u=B_U, x_bounds=(-50, 50), v_bounds=(-0.05, 0.05), u_bounds=(-2, 2))


def _kalman(system, u, y, x0, P0, w0, W0, Q, R, integrated=False):
    """The textbook Kalman filter of the augmented model z = (x, d), d+ = d + e_d, or z = (x, d, r), d+ = d + r,
    r+ = r + e_r (``integrated``, r[0] = 0 with covariance W0)."""
    A_in = np.array([[1.0, 1.0], [0.0, 1.0]]) if integrated else np.eye(1)
    m = len(A_in)
    B_in = np.hstack([B, np.zeros((3, m - 1))])
    Aa = np.block([[A, B_in], [np.zeros((m, 3)), A_in]])
    Ba, Ca = np.vstack([B_U, np.zeros((m, 1))]), np.hstack([C, np.zeros((2, m))])
    z = np.concatenate([x0, w0, np.zeros(m - 1)])
    P = np.block([[P0, np.zeros((3, m))], [np.zeros((m, 3)), np.kron(np.eye(m), W0)]])
    out = []
    for k in range(len(y)):
        if k:
            z, P = Aa @ z + Ba @ u[k - 1], Aa @ P @ Aa.T + Q
        S = Ca @ P @ Ca.T + R
        K = P @ Ca.T @ np.linalg.inv(S)
        z, P = z + K @ (y[k] - Ca @ z), (np.eye(3 + m) - K @ Ca) @ P
        out.append(z.copy())
    return np.array(out)


def test_ekf_and_ukf_equal_the_kalman_filter_on_a_linear_gaussian_model():
    system = _system()
    rng = np.random.default_rng(0)
    K = 80
    u = rng.uniform(-1, 1, (K, 1))
    truth = simulate(system, [1.0, -1.0, 2.0], K, u=u, w=np.cumsum(0.3 * rng.standard_normal(K))[:, None],
                     v=0.02 * rng.standard_normal((K + 1, 2)))  # fmt: skip
    x0, P0, w0, W0 = np.array([0.5, 0.0, 1.0]), np.diag([1.0, 2.0, 3.0]), np.zeros(1), np.eye(1) * 4.0
    Q = np.diag([1e-4, 2e-4, 3e-4, 0.09])
    R = np.diag([4e-4, 4e-4])
    options = {"w_variance": 0.09, "x_variance": [1e-4, 2e-4, 3e-4], "v_covariance": [4e-4, 4e-4],
               "P0": P0, "w0": w0, "W0": W0, "x0_prior": x0}  # fmt: skip
    reference = _kalman(system, u, truth.y, x0, P0, w0, W0, Q, R)
    ekf = EKF(system, **options).run(u, truth.y)
    np.testing.assert_allclose(ekf.x_hat, reference[:, :3], rtol=0, atol=1e-10)
    np.testing.assert_allclose(ekf.w_hat[:, 0], reference[1:, 3], rtol=0, atol=1e-10)
    ukf = UKF(system, **options).run(u, truth.y)
    np.testing.assert_allclose(ukf.x_hat, reference[:, :3], rtol=0, atol=1e-6)
    assert ekf.estimator == "EKF" and ukf.estimator == "UKF" and str(ekf.guarantee).startswith("none: ")
    # missing channels are dropped from the update: the same as the filter with that row removed
    y = truth.y.copy()
    y[5, 1] = np.nan
    ekf_missing = EKF(system, **options).run(u, y)
    assert ekf_missing.missing[5, 1] and np.all(np.isfinite(ekf_missing.x_hat))
    # the integrated random walk: z = (x, d, r), w_variance the rate's step; w_hat[k-1] = d - r at k
    Q_int = np.diag([1e-4, 2e-4, 3e-4, 0.0, 0.09])
    reference = _kalman(system, u, truth.y, x0, P0, w0, W0, Q_int, R, integrated=True)
    for cls, atol in ((EKF, 1e-10), (UKF, 1e-6)):
        integrated = cls(system, **options, input_model="integrated random walk").run(u, truth.y)
        np.testing.assert_allclose(integrated.x_hat, reference[:, :3], rtol=0, atol=atol)
        np.testing.assert_allclose(integrated.w_hat[:, 0], reference[1:, 3] - reference[1:, 4], rtol=0, atol=atol)


def test_output_noise_through_a_coupling_that_is_not_square_gives_the_kalman_filters_R():
    """``y = C x + D v`` with D (2, 3), neither square nor diagonal: both filters use R = D Sigma_v D^T."""
    D = np.array([[1.0, 0.5, 0.0], [0.2, 0.0, 1.5]])
    x, u, w, v = (ca.SX.sym(name, n) for name, n in (("x", 3), ("u", 1), ("w", 1), ("v", 3)))
    x_next = ca.mtimes(ca.DM(A), x) + ca.mtimes(ca.DM(B_U), u) + ca.mtimes(ca.DM(B), w)
    system = System.from_expressions(x, u, w, v, x_next, ca.mtimes(ca.DM(C), x) + ca.mtimes(ca.DM(D), v),
                                     x_bounds=(-50, 50), v_bounds=(-0.2, 0.2), u_bounds=(-2, 2))  # fmt: skip
    rng = np.random.default_rng(3)
    K = 60
    u_data = rng.uniform(-1, 1, (K, 1))
    sigma_v = np.array([4e-4, 1e-4, 9e-4])
    truth = simulate(system, [1.0, -1.0, 2.0], K, u=u_data, w=np.cumsum(0.3 * rng.standard_normal(K))[:, None],
                     v=np.sqrt(sigma_v) * rng.standard_normal((K + 1, 3)))  # fmt: skip
    x0, P0, w0, W0 = np.array([0.5, 0.0, 1.0]), np.diag([1.0, 2.0, 3.0]), np.zeros(1), np.eye(1) * 4.0
    options = {"w_variance": 0.09, "x_variance": [1e-4, 2e-4, 3e-4], "v_covariance": sigma_v, "P0": P0, "w0": w0,
               "W0": W0, "x0_prior": x0}  # fmt: skip
    reference = _kalman(system, u_data, truth.y, x0, P0, w0, W0, np.diag([1e-4, 2e-4, 3e-4, 0.09]),
                        D @ np.diag(sigma_v) @ D.T)  # fmt: skip
    np.testing.assert_allclose(EKF(system, **options).run(u_data, truth.y).x_hat, reference[:, :3], rtol=0, atol=1e-10)
    np.testing.assert_allclose(UKF(system, **options).run(u_data, truth.y).x_hat, reference[:, :3], rtol=0, atol=1e-10)


def test_a_filter_pickles_and_deep_copies_and_runs_as_before():
    system = _system()
    rng = np.random.default_rng(4)
    u = rng.uniform(-1, 1, (30, 1))
    truth = simulate(system, [1.0, -1.0, 2.0], 30, u=u, w=np.zeros((30, 1)), v=0.02 * rng.standard_normal((31, 2)))
    for cls in (EKF, UKF):
        original = cls(system, w_variance=0.09, x0_prior=np.zeros(3))
        expected = original.run(u, truth.y).x_hat
        for copy in (pickle.loads(pickle.dumps(original)), deepcopy(original)):
            np.testing.assert_array_equal(copy.run(u, truth.y).x_hat, expected)


@pytest.mark.slow
def test_tuned_ekf_beats_the_uise_on_a_smooth_input_and_loses_on_a_ramp():
    # the measurement: EKF wins when w is a slow random walk, the UISE when w ramps far away
    system = _system()
    rng = np.random.default_rng(1)
    K = 200
    u = rng.uniform(-1, 1, (K, 1))
    v = rng.uniform(-0.05, 0.05, (K + 1, 2))
    training = simulate(system, [1.0, -1.0, 2.0], K, u=u, w=np.cumsum(0.05 * rng.standard_normal(K))[:, None], v=v)
    ekf = EKF.tuned(system, training, x0_prior=np.zeros(3))
    assert ekf.tuning is not None and len(ekf.tuning.rms) == 21
    smooth = simulate(system, [1.0, -1.0, 2.0], K, u=u, w=np.cumsum(0.05 * rng.standard_normal(K))[:, None], v=v)
    from uiest.estimators import UISEWeights

    uise = UISE(system, weights=UISEWeights.from_scales(system, 0.8), N=20, x0_prior=np.zeros(3))

    def rmse(estimator, traj):
        return float(np.sqrt(np.mean(estimator.run(u, traj.y).error(traj.x)[50:] ** 2)))

    assert rmse(ekf, smooth) < rmse(uise, smooth)  # measured: 0.0166 vs 0.0175
    # w ramps to 1e4: a wide X with the state scales of the smooth record
    wide = linear.linear_system(A, B, C, B_u=B_U, x_bounds=(-1e6, 1e6), v_bounds=(-0.05, 0.05), u_bounds=(-2, 2))
    wide = wide.with_scales(training)
    ramp = simulate(wide, [1.0, -1.0, 2.0], K, u=u, w=(50.0 * np.arange(K))[:, None], v=v)
    ekf_wide = EKF(wide, w_variance=ekf.tuning.chosen * wide.w.scale**2, x0_prior=np.zeros(3))
    uise_wide = UISE(wide, weights=UISEWeights.from_scales(wide, 0.8), N=20, x0_prior=np.zeros(3))
    assert rmse(uise_wide, ramp) * 10 < rmse(ekf_wide, ramp)  # measured: 0.0175 vs 0.866 (49x)


def test_bad_kalman_options_are_refused():
    system = _system()
    with pytest.raises(OptionError, match="w_variance: expected variances"):
        EKF(system, w_variance=[1.0, 2.0, 3.0])
    with pytest.raises(OptionError, match="v_covariance: expected a positive semidefinite"):
        EKF(system, w_variance=1.0, v_covariance=[[1.0, 0.0], [0.0, -1.0]])
    with pytest.raises(OptionError, match="alpha"):
        UKF(system, w_variance=1.0, alpha=0.0)
    with pytest.raises(OptionError, match="input_model: expected one of"):
        EKF(system, w_variance=1.0, input_model="autoregressive")
    with pytest.raises(DataError, match="training: expected a simulated Trajectory"):
        EKF.tuned(system, "data.csv", x0_prior=np.zeros(3))
    with pytest.raises(OptionError, match="x0_prior: required"):
        EKF(system, w_variance=1.0).step(None, [0.0, 0.0])


def _tanks(top=4.0):
    """Two tanks in cascade, the lower one measured: h+ = h + 0.1 (inflow - sqrt(h)), X = [0, top]^2, NaN below 0."""
    from uiest import System

    return System.from_callables(
        lambda x, u, w: [x[0] + 0.1 * (0.5 + w[0] - x[0] ** 0.5), x[1] + 0.1 * (x[0] ** 0.5 - x[1] ** 0.5)],
        lambda x, v: [x[1] + v[0]], nx=2, nw=1, nv=1, x_bounds=((0.0, 0.0), (top, top)), v_bounds=(-0.01, 0.01),
        x_scale=4.0,
    )  # fmt: skip


@pytest.mark.parametrize(("cls", "prior", "top"), [(EKF, [3.0, 0.3], 4.0), (EKF, [3.0, 0.3], np.inf),
                                                   (UKF, [0.01, 0.3], 4.0)])  # fmt: skip
def test_a_filter_evaluates_the_model_inside_x_where_it_is_not_finite_and_recovers(cls, prior, top):
    # The UKF's default P0 (X's uniform variance) puts sigma points of the unmeasured upper level below 0 at a
    # prior near 0; the EKF's update from a far prior takes it below 0 (its Jacobian at 0 is infinite). Before
    # the retry inside X the EKF held that estimate for the rest of the record (149 of 151 steps).
    system = _tanks(top)  # X = [0, inf)^2: the retry keeps a margin of x's scale from the side at 0
    rng = np.random.default_rng(1)
    truth = simulate(system, [0.3, 0.3], 150, w=0.05 * np.sin(0.1 * np.arange(150))[:, None],
                     v=rng.uniform(-0.01, 0.01, (151, 1)))  # fmt: skip
    result = cls(system, w_variance=1e-3, x0_prior=prior).run(None, truth.y)
    assert all(result.success), sorted(set(result.status))
    assert result.evaluated_inside.any() and set(result.outcome) == {Outcome.UPDATED}
    assert np.all(np.sqrt(np.mean(result.error(truth.x)[50:] ** 2, axis=0)) < 0.02)


def test_tuned_never_chooses_a_filter_that_diverged():
    from uiest import System

    # Henon with the unknown input in x2 and y = x2: the UKF's sigma points at X's uniform variance leave the
    # attractor and the quadratic map throws them far outside X (beyond its width by step 3 on every variance).
    henon = System.from_callables(lambda x, u, w: [1.0 - 1.4 * x[0] ** 2 + x[1], 0.3 * x[0] + w[0]],
                                  lambda x, v: [x[1] + v[0]], nx=2, nw=1, nv=1,
                                  x_bounds=((-1.4, -0.5), (1.4, 0.5)), v_bounds=(-0.01, 0.01))  # fmt: skip
    training = simulate(henon, [0.1, 0.1], 60, w=np.zeros((60, 1)), v=np.zeros((61, 1)))
    short = simulate(henon, [0.1, 0.1], 8, w=np.zeros((8, 1)), v=np.zeros((9, 1)))
    ukf = UKF(henon, w_variance=1e-4 * henon.w.scale**2, x0_prior=[0.0, 0.0])
    with pytest.warns(BoundWarning, match=r"UKF: the estimate of x\[0\] at or beyond X's lower side -1.4"):
        result = ukf.run(None, short.y)
    assert (result.outcome == Outcome.DIVERGED).any() and not all(result.success)
    for record in (short, training):
        with np.errstate(all="ignore"), pytest.raises(OptionError, match="P0: every UKF of the variance grid diverged"):
            UKF.tuned(henon, record, x0_prior=[0.0, 0.0], variances=[1e-4, 1e-2])
    # one variance diverges, the other does not: the finite one is chosen whatever their RMS
    tuned = UKF.tuned(henon, training, x0_prior=[0.0, 0.0], P0=1e-4, variances=[1e-4, 1e-2])
    assert tuned.tuning is not None and tuned.tuning.diverged is not None
    assert tuned.tuning.diverged[tuned.tuning.rms.tolist().index(min(tuned.tuning.rms))] == 0


def test_tuned_warns_when_the_chosen_filter_failed_steps():
    class SkippingEKF(EKF):
        """An EKF whose every third update fails (as a singular innovation covariance would)."""

        def _update(self, z, P, y, observed, inside):  # type: ignore[no-untyped-def]
            if self._k % 3 == 2:
                raise np.linalg.LinAlgError("singular")
            return super()._update(z, P, y, observed, inside)

    system = _system()
    training = simulate(system, np.zeros(3), 30, u=np.zeros((30, 1)), w=np.zeros((30, 1)), seed=1)
    with pytest.warns(UserWarning, match=r"failed 10 of 31 training steps \(an update skipped or the estimate kept\)"):
        SkippingEKF.tuned(system, training, x0_prior=np.zeros(3), variances=[1e-2, 1.0])
