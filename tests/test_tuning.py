"""Tuning from the data alone: the innovations' likelihood, its profile, EKF/UKF.fit and the standard MHE's fit."""

import numpy as np
import pytest

from uiest import OptionError, simulate
from uiest.estimators import EKF, UKF, StandardMHE
from uiest.filter_fit import check_models, fit_filter
from uiest.input_model import InputModel
from uiest.likelihood import (
    DEFAULT_GRID,
    GRID_EXTENSION,
    LIKELIHOOD_INTERVAL,
    ProfileShape,
    Score,
    check_grid,
    maximise_likelihood,
)
from uiest.models import linear, register
from uiest.tuning import fit_standard_mhe, likelihood_weights

A = np.array([[0.8, 0.3, 0.0], [-0.2, 0.7, 0.4], [0.1, -0.3, 0.6]])
B_U = np.array([[0.0], [1.0], [0.0]])
C = np.array([[1.0, 0, 0], [0, 1.0, 0]])
B_X3 = np.array([[0.0], [0.0], [1.0]])  # the unknown input enters the unmeasured x3: relative degree 2
STEP, NOISE = 0.05, 0.02  # the random walk's step and the Gaussian noise's standard deviations


def _system(B=B_X3):
    return linear.linear_system(A, B, C, B_u=B_U, x_bounds=(-50, 50), v_bounds=(-0.1, 0.1), u_bounds=(-2, 2),
                                x_scale=10.0)  # fmt: skip


def _record(system, seed, K=400):
    """A Gaussian random walk w (step STEP) and Gaussian noise (NOISE): the filters' own model, variance known."""
    rng = np.random.default_rng(seed)
    u = rng.uniform(-1, 1, (K, 1))
    w = np.cumsum(STEP * rng.standard_normal(K))[:, None]
    return simulate(system, [1.0, -1.0, 2.0], K, u=u, w=w, v=NOISE * rng.standard_normal((K + 1, 2)))


def _reference_log_likelihood(system, u, y, x0, P0, W0, q, R):
    """The textbook Kalman filter of z = (x, d), d+ = d + e_d, and the Gaussian log-density of its innovations."""
    nx = 3
    B = np.asarray(system.linearize(np.zeros(3)).B_w)
    Aa = np.block([[A, B], [np.zeros((1, nx)), np.eye(1)]])
    Ba, Ca = np.vstack([B_U, np.zeros((1, 1))]), np.hstack([C, np.zeros((2, 1))])
    Q = np.zeros((4, 4))
    Q[3, 3] = q
    z, P = np.concatenate([x0, [0.0]]), np.block([[P0, np.zeros((3, 1))], [np.zeros((1, 3)), W0]])
    total = 0.0
    for k in range(len(y)):
        if k:
            z, P = Aa @ z + Ba @ u[k - 1], Aa @ P @ Aa.T + Q
        seen = ~np.isnan(y[k])
        H = Ca[seen]
        S = H @ P @ H.T + R[np.ix_(seen, seen)]
        e = y[k][seen] - H @ z
        total += -0.5 * (np.linalg.slogdet(2 * np.pi * S)[1] + e @ np.linalg.solve(S, e))
        K = P @ H.T @ np.linalg.inv(S)
        z, P = z + K @ e, (np.eye(4) - K @ H) @ P
    return total


def test_the_filters_log_likelihood_is_the_kalman_filters_with_missing_channels_dropped():
    system = _system()
    truth = _record(system, 0, K=60)
    y = truth.y.copy()
    y[5, 1] = np.nan
    y[9, :] = np.nan  # a step without data adds nothing
    x0, P0 = np.array([0.5, 0.0, 1.0]), np.diag([1.0, 2.0, 3.0])
    expected = _reference_log_likelihood(system, truth.u, y, x0, P0, np.eye(1) * 4.0, 0.01, np.eye(2) * NOISE**2)
    options = {"w_variance": 0.01, "v_covariance": NOISE**2, "P0": P0, "W0": 4.0, "x0_prior": x0}
    for cls, tol in ((EKF, 1e-8), (UKF, 1e-5)):
        estimator = cls(system, **options)
        score = estimator.score(truth.u, y)
        assert score == Score(log_likelihood=estimator.log_likelihood, unscored=0, diverged=0) and score.admissible
        assert estimator.log_likelihood == pytest.approx(expected, rel=tol)


@pytest.mark.slow
def test_the_likelihood_maximum_of_a_gaussian_random_walk_lies_near_its_true_variance():
    # K = 400 steps: the profile's 95 % interval (L within LIKELIHOOD_INTERVAL of its maximum, Wilks) spans a factor
    # of 1.56 (median of 40 records in bench/tuning.py: chosen / true 0.75 .. 1.28, the true variance inside the
    # interval in 37 of 40), so the standard deviation of log(chosen) is about log(1.56) / 3.92 = 0.11 (0.13 over
    # 100 records) and a factor 2 either side is more than 5 of them
    system = _system()
    true_factor = STEP**2 / system.w.scale[0] ** 2
    for seed in (1, 2):
        truth = _record(system, seed)
        ekf = EKF.fit(system, truth.u, truth.y, x0_prior=np.zeros(3), v_covariance=NOISE**2, prior_factors=[1.0])
        profile = ekf.likelihood
        lo, hi = profile.interval
        assert profile.shape is ProfileShape.INTERIOR and lo < profile.chosen < hi
        assert 0.5 < profile.chosen / true_factor < 2.0 and hi / lo < 4.0
        # the grid and the refinement's points; the refinement brackets the maximum to 3 % of two grid spacings
        assert len(profile.factors) == len(DEFAULT_GRID) + 8
        assert profile.maximum == pytest.approx(ekf.score(truth.u, truth.y).log_likelihood)
        assert np.all(profile.log_likelihood[np.isin(profile.factors, DEFAULT_GRID)] <= profile.maximum)
        assert ekf.Q[3, 3] == pytest.approx(profile.chosen * system.w.scale[0] ** 2)
        assert ekf.input_model is InputModel.RANDOM_WALK and ekf.filter_fit.margin > LIKELIHOOD_INTERVAL
    # the UKF is exact on a linear model: the same profile
    ukf = UKF.fit(
        system,
        truth.u,
        truth.y,
        x0_prior=np.zeros(3),
        v_covariance=NOISE**2,
        prior_factors=[1.0],
        input_models="random walk",
    )
    assert ukf.likelihood.chosen == pytest.approx(profile.chosen, rel=1e-3)


@pytest.mark.slow
def test_the_fit_chooses_the_integrated_random_walk_for_an_input_that_drifts_smoothly():
    # the input's rate is a Gaussian random walk (step 0.002): its increments are far from independent
    system = _system()
    rng = np.random.default_rng(6)
    K = 300
    u = rng.uniform(-1, 1, (K, 1))
    w = np.cumsum(np.cumsum(0.002 * rng.standard_normal(K)))[:, None]
    truth = simulate(system, [1.0, -1.0, 2.0], K, u=u, w=w, v=NOISE * rng.standard_normal((K + 1, 2)))
    ekf = EKF.fit(system, truth.u, truth.y, x0_prior=np.zeros(3), v_covariance=NOISE**2, prior_factors=[1.0])
    found = ekf.filter_fit
    assert ekf.input_model is InputModel.INTEGRATED_RANDOM_WALK and found.best is found.fits[1]
    assert found.margin > LIKELIHOOD_INTERVAL and "integrated random walk" in found.summary()
    assert found.to_dict()["chosen"] == "integrated random walk" and found.best.prior is None
    # the rate's step variance: the chosen factor times w.scale^2 lies within a factor 3 of 0.002^2 (measured 1.3)
    assert 1 / 3 < ekf.likelihood.chosen * system.w.scale[0] ** 2 / 0.002**2 < 3
    # the model of the record beats the random walk on the states too
    rw = EKF.fit(system, truth.u, truth.y, x0_prior=np.zeros(3), v_covariance=NOISE**2, prior_factors=[1.0],
                 input_models="random walk")  # fmt: skip
    assert rw.input_model is InputModel.RANDOM_WALK and len(rw.filter_fit.fits) == 1

    def rmse(estimator):
        return float(np.sqrt(np.mean(estimator.run(truth.u, truth.y).error(truth.x)[40:] ** 2)))

    assert rmse(ekf) < rmse(rw)
    for bad in ("autoregressive", [], 3):
        with pytest.raises(OptionError, match="input_models: expected some of"):
            check_models(bad)
    with pytest.raises(OptionError, match="input_model: fit compares input models"):
        EKF.fit(system, truth.u, truth.y, x0_prior=np.zeros(3), input_model="random walk")
    with pytest.raises(OptionError, match="prior_factors: expected positive numbers"):
        EKF.fit(system, truth.u, truth.y, x0_prior=np.zeros(3), prior_factors=[-1.0])


@pytest.mark.slow
def test_filters_fitted_without_the_truth_are_as_accurate_as_the_best_tuned_on_it():
    system = _system()
    truth = _record(system, 3, K=250)

    def rmse(estimator):
        return float(np.sqrt(np.mean((estimator.run(truth.u, truth.y).error(truth.x)[40:] / system.x.scale) ** 2)))

    for cls in (EKF, UKF):
        fitted = rmse(cls.fit(system, truth.u, truth.y, x0_prior=np.zeros(3), v_covariance=NOISE**2))
        grid = [rmse(cls(system, w_variance=q * system.w.scale**2, x0_prior=np.zeros(3), v_covariance=NOISE**2))
                for q in DEFAULT_GRID[::2]]  # fmt: skip
        assert fitted < 1.5 * min(grid)  # measured: 1.00x
        assert min(grid) * 3 < max(grid)  # the variance matters here


@pytest.mark.slow
def test_the_standard_mhe_fitted_by_likelihood_is_within_the_bound_of_the_best_on_the_truth():
    system = _system()
    truth = _record(system, 4, K=150)
    x0 = np.zeros(3)

    def rmse(mhe):
        return float(np.sqrt(np.mean((mhe.run(truth.u, truth.y).error(truth.x)[20:] / system.x.scale) ** 2)))

    fitted = fit_standard_mhe(system, truth.u, truth.y, x0_prior=x0, N=10, eta=0.8, v_covariance=NOISE**2)
    assert isinstance(fitted, StandardMHE) and fitted.likelihood is not None and not fitted.guaranteed
    assert fitted.weights.Q_w[0, 0] == pytest.approx(1.0 / (fitted.likelihood.chosen * system.w.scale[0] ** 2))
    best = np.inf
    for q in (1e-4, 1e-2, 1.0, 100.0):
        weights = likelihood_weights(system, truth.u, truth.y, x0_prior=x0, eta=0.8,
                                     w_variance=q * system.w.scale**2, v_covariance=NOISE**2)  # fmt: skip
        best = min(best, rmse(StandardMHE(system, weights=weights, N=10, x0_prior=x0)))
    assert rmse(fitted) < 1.5 * best


def _synthetic(peak):
    """A concave log-likelihood in log10 q with its maximum at 10**peak (None: flat); scored calls counted."""
    calls = []

    def score(q):
        calls.append(q)
        return Score(log_likelihood=0.0 if peak is None else -50.0 * (np.log10(q) - peak) ** 2)

    return score, calls


@pytest.mark.parametrize(
    ("peak", "shape"),
    [(-3.3, ProfileShape.INTERIOR), (-12.0, ProfileShape.LOWER_END), (5.0, ProfileShape.UPPER_END),
     (None, ProfileShape.FLAT)],
)  # fmt: skip
def test_the_profile_says_where_the_likelihood_interval_lies(peak, shape):
    score, calls = _synthetic(peak)
    profile = maximise_likelihood(score, DEFAULT_GRID, name="w_variance", unit="w.scale^2", scale=np.array([2.0]))
    assert profile.shape is shape and shape.value in profile.summary()
    lo, hi = profile.interval
    if shape is ProfileShape.INTERIOR:
        # golden-section refinement: within 3 % of the bracket (two grid spacings of half a decade)
        assert abs(np.log10(profile.chosen) - peak) < 0.03
        assert len(calls) == len(DEFAULT_GRID) + 8
        # L = max - 1.92 at |log10 q - peak| = sqrt(1.92 / 50), up to the linear interpolation between points
        half = np.sqrt(LIKELIHOOD_INTERVAL / 50.0)
        assert np.log10(lo) == pytest.approx(peak - half, abs=0.03)
        assert np.log10(hi) == pytest.approx(peak + half, abs=0.03)
        np.testing.assert_allclose(profile.variance, [profile.chosen * 4.0])
    else:  # no refinement at an end of the grid or on a flat profile
        assert len(calls) == len(DEFAULT_GRID)
    if shape is ProfileShape.LOWER_END:
        assert profile.chosen == DEFAULT_GRID[0] and lo == DEFAULT_GRID[0] and hi < DEFAULT_GRID[1]
    if shape is ProfileShape.FLAT:
        assert (lo, hi) == (DEFAULT_GRID[0], DEFAULT_GRID[-1]) and profile.spread == 0.0
    record = profile.to_dict()
    assert record["shape"] == shape.value and len(record["log_likelihood"]) == len(profile.factors)


@pytest.mark.parametrize("peak", [-12.0, 5.0, -20.0])
def test_the_grid_grows_beyond_an_end_where_the_likelihood_is_largest(peak):
    score, calls = _synthetic(peak)
    profile = maximise_likelihood(score, DEFAULT_GRID, name="w_variance", unit="w.scale^2", scale=np.ones(1),
                                  extend=GRID_EXTENSION)  # fmt: skip
    if peak == -20.0:  # twelve decades below the grid: six more are not enough, and the summary says so
        assert profile.extended == GRID_EXTENSION and profile.at_end and profile.chosen == pytest.approx(1e-14)
        assert "its largest value; a smaller one may fit better" in profile.summary()
        assert len(calls) == len(DEFAULT_GRID) + GRID_EXTENSION
        return
    # half-decade steps until the point beyond the peak is lower, then the golden-section refinement
    assert profile.shape is ProfileShape.INTERIOR and not profile.at_end
    assert abs(np.log10(profile.chosen) - peak) < 0.03 and profile.extended == 2 * abs(peak - np.clip(peak, -8, 2)) + 1
    assert (
        "95 % interval" in profile.summary() and f"{profile.extended} points beyond the given grid" in profile.summary()
    )
    assert profile.to_dict()["extended"] == profile.extended


def test_a_variance_at_the_grid_s_end_is_not_said_to_fit_as_well_as_smaller_ones():
    score, _ = _synthetic(-12.0)
    profile = maximise_likelihood(score, DEFAULT_GRID, name="w_variance", unit="w.scale^2", scale=np.ones(1))
    assert profile.at_end and "a smaller one may fit better" in profile.summary()
    assert "fits as well" not in profile.summary()


@pytest.mark.slow
def test_an_input_in_a_large_unit_has_its_variance_found_below_the_default_grid():
    # w in a unit 1e4 times the signal's (a flow in m^3/s where it is 1e-4): its variance factor 2.5e-11 lies below
    # the default grid's 1e-8, which used to be chosen with "any value up to 1.01e-08 fits as well"
    system = linear.linear_system(A, 1e4 * B_X3, C, B_u=B_U, x_bounds=(-50, 50), v_bounds=(-0.1, 0.1),
                                  u_bounds=(-2, 2), x_scale=10.0)  # fmt: skip
    rng = np.random.default_rng(3)
    K = 400
    u = rng.uniform(-1, 1, (K, 1))
    w = np.cumsum(1e-4 * STEP * rng.standard_normal(K))[:, None]
    truth = simulate(system, [1.0, -1.0, 2.0], K, u=u, w=w, v=NOISE * rng.standard_normal((K + 1, 2)))
    ekf = EKF.fit(system, truth.u, truth.y, x0_prior=np.zeros(3), v_covariance=NOISE**2, prior_factors=[1.0])
    profile = ekf.likelihood
    true_factor = (1e-4 * STEP) ** 2 / system.w.scale[0] ** 2
    assert profile.extended > 0 and profile.shape is ProfileShape.INTERIOR and not profile.at_end
    assert 0.5 < profile.chosen / true_factor < 2.0


def test_runs_that_diverged_or_failed_are_never_chosen():
    def score(q):
        if q > 1e-3:  # a diverged run or an unscored update: its sum is not comparable, whatever its value
            return Score(log_likelihood=1e9, unscored=1) if q < 1.0 else Score(log_likelihood=1e9, diverged=3)
        return Score(log_likelihood=-((np.log10(q) + 6.0) ** 2))

    profile = maximise_likelihood(score, DEFAULT_GRID, name="w_variance", unit="w.scale^2", scale=np.ones(1))
    assert profile.chosen < 1e-3 and np.all(np.isneginf(profile.log_likelihood[profile.factors > 1e-3]))
    assert profile.unscored[profile.factors > 1.0].min() == 3
    with pytest.raises(OptionError, match=r"w_variance: every filter of the grid .* diverged or failed"):
        maximise_likelihood(
            lambda q: Score(log_likelihood=np.nan), DEFAULT_GRID, name="w_variance", unit="-", scale=np.ones(1)
        )


def test_a_model_whose_filters_all_fail_is_set_aside_and_the_ascent_never_loses_a_point_it_scored():
    def score(model, q, c):
        if model is InputModel.INTEGRATED_RANDOM_WALK:
            return Score(
                log_likelihood=1e9, diverged=2
            )  # every filter of this model diverged: not comparable, whatever its value
        # a ridge: the best q depends on c, so the second search of q runs at another optimum
        return Score(log_likelihood=-((np.log10(q) + 3.0 + 0.5 * np.log10(c)) ** 2) - 0.01 * (np.log10(c) + 4.0) ** 2)

    grids = {"variances": DEFAULT_GRID, "prior_factors": np.logspace(-8, 2, 11), "scale": np.ones(1)}
    found = fit_filter(score, models=tuple(InputModel), **grids)
    assert found.best.input_model is InputModel.RANDOM_WALK and len(found.fits) == 1
    assert [model for model, _ in found.failed] == [InputModel.INTEGRATED_RANDOM_WALK]
    assert "integrated random walk: every filter diverged or failed" in found.summary()
    assert found.to_dict()["failed"]["integrated random walk"].startswith("w_variance: every filter")
    best = found.best
    assert best.maximum >= best.prior.maximum and best.prior_factor != 1.0
    with pytest.raises(OptionError, match="integrated random walk: w_variance: every filter"):
        fit_filter(score, models=(InputModel.INTEGRATED_RANDOM_WALK,), **grids)


@pytest.mark.slow
def test_a_flat_profile_warns_and_bad_grids_are_refused():
    system = _system(B=np.zeros((3, 1)))  # the unknown input acts nowhere: the data cannot see its variance
    truth = _record(system, 5, K=50)
    with pytest.warns(UserWarning, match="flat: the log-likelihood varies by .* the record does not determine it"):
        ekf = EKF.fit(system, truth.u, truth.y, x0_prior=np.zeros(3))
    assert ekf.likelihood.shape is ProfileShape.FLAT
    for bad in ([], [1.0, -1.0], [np.inf], "many"):
        with pytest.raises(OptionError, match="variances: expected positive numbers"):
            check_grid(bad)
    np.testing.assert_array_equal(check_grid([1.0, 1e-3, 1.0]), [1e-3, 1.0])
    with pytest.raises(OptionError, match="variances: expected positive numbers"):
        UKF.fit(system, truth.u, truth.y, x0_prior=np.zeros(3), variances=[0.0])


@pytest.mark.slow
def test_estimate_fits_the_filters_and_the_mhe_to_the_data_it_is_given():
    from uiest.estimate import build_estimator

    system = _system()
    entry = register("random-walk-for-tuning", lambda: system, replace=True)
    truth = _record(system, 6, K=120)
    ekf, note = build_estimator("ekf", entry, system, np.zeros(3), record=truth)
    assert note.startswith("random walk: w_variance") and "the likelihood's maximum (interior" in note
    assert ekf.likelihood is not None
    given, note = build_estimator("ukf", entry, system, np.zeros(3), w_variance=0.5, record=truth)
    per_step = f"{system.w.names[0]} {0.5 * system.w.scale[0] ** 2:.3g}"
    assert note == f"random-walk variance 0.5 w.scale^2 = {per_step} per step (given)" and given.likelihood is None
    with pytest.raises(OptionError, match="--w-variance: required for ekf without measurements"):
        build_estimator("ekf", entry, system, np.zeros(3))
    mhe, note = build_estimator("mhe", entry, system, np.zeros(3), record=truth)
    assert "no informative delta-IOSS design" in note and "disturbance: w_variance" in note
    assert mhe.likelihood is not None and mhe.weights.eta == 0.8


def test_estimate_keeps_an_informative_mhe_certificate():
    from uiest.estimate import build_estimator

    scalar = linear.linear_system([[0.5]], [[1.0]], [[1.0]], x_bounds=(-10, 10), v_bounds=(-0.01, 0.01),
                                  w_range=(-0.01, 0.01))  # fmt: skip
    entry = register("scalar-for-tuning", lambda: scalar, replace=True)
    mhe, note = build_estimator("mhe", entry, scalar, np.zeros(1))  # no record needed: the certificate decides
    assert note.startswith("delta-IOSS certificate") and mhe.guarantee.informative and mhe.likelihood is None


@pytest.mark.slow
def test_the_reactors_standard_mhe_fitted_by_likelihood_and_its_arrival_cost():
    # a drifting fault the MHE's white-disturbance model does not hold: with the window prior's weight P0^-1 (a prior
    # that never tightens) the window moves its oldest c_A instead of paying for the fault
    from pathlib import Path

    from uiest.estimators import MHEWeights
    from uiest.models import load

    entry = load(Path(__file__).resolve().parents[1] / "examples" / "reactor.py")
    system, setup = entry.build(), entry.simulation()
    truth = simulate(system, setup.x0, 200, u=setup.u, w=setup.w, v=setup.noise, seed=3)
    x0 = np.asarray(setup.x0)

    def rmse(mhe):
        return float(np.sqrt(np.mean((mhe.run(truth.u, truth.y).error(truth.x)[20:] / system.x.scale) ** 2)))

    fitted = fit_standard_mhe(system, truth.u, truth.y, x0_prior=x0, N=20, eta=0.8)
    best = min(
        rmse(StandardMHE(system, weights=likelihood_weights(system, truth.u, truth.y, x0_prior=x0, eta=0.8,
                                                            w_variance=q), N=20, x0_prior=x0))
        for q in (1e-6, 1e-3, 1.0, 100.0)
    )  # fmt: skip
    assert rmse(fitted) < 1.5 * best
    weak = MHEWeights.from_variances(system, 0.8, w_variance=fitted.likelihood.variance, at=x0)  # P = P0^-1
    assert rmse(StandardMHE(system, weights=weak, N=20, x0_prior=x0)) > 5 * rmse(fitted)


def test_arrival_covariance_with_the_input_extends_that_of_x():
    from uiest.run_data import check_run_data
    from uiest.tuning import arrival_covariance

    system = _system()
    record = _record(system, 4, K=120)
    u, y = check_run_data(system, record.u, record.y)
    ekf = EKF(system, w_variance=STEP**2, v_covariance=NOISE**2, x0_prior=np.zeros(3))
    x_only, joint = arrival_covariance(ekf, u, y), arrival_covariance(ekf, u, y, with_input=True)
    assert joint.shape == (4, 4) and np.all(np.linalg.eigvalsh(joint) > 0)
    np.testing.assert_allclose(joint[:3, :3], x_only, rtol=1e-9, atol=1e-12)
    # the unmeasured input's uncertainty settles at the random walk's scale, not at its prior W0 = w.scale^2
    assert STEP**2 / 10 < joint[3, 3] < 10 * STEP**2


def test_a_profile_flat_within_the_likelihood_interval_is_not_followed_beyond_the_grid():
    # rising by 0.1 over the grid's ten decades: the record does not determine the variance, and no point is added
    profile = maximise_likelihood(lambda q: Score(log_likelihood=0.01 * np.log10(q)), DEFAULT_GRID, name="w_variance",
                                  unit="w.scale^2", scale=np.ones(1), extend=GRID_EXTENSION)  # fmt: skip
    assert profile.extended == 0 and profile.shape is ProfileShape.FLAT and len(profile.factors) == len(DEFAULT_GRID)
