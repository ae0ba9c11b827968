"""UISE.design: mu and N chosen for accuracy, against the linear UIO on systems without invariant zeros."""

import pickle
import warnings

import numpy as np
import pytest

from uiest import CertificationError, DataError, HorizonError, OptionError, simulate
from uiest.design import ERROR_TOLERANCE, DesignOptions, design_uise, regret
from uiest.detectability import certify_reduced_model, certify_strong_detectability
from uiest.detectability.certificate import horizon_condition
from uiest.estimators import UISE, LinearUIO
from uiest.estimators.design_search import search_uise
from uiest.models import closed_form, linear


def benchmark(seed: int):
    """A random stable 3-state system, one unknown input, two outputs (no invariant zeros), noise +-0.05."""
    rng = np.random.default_rng(seed)
    A = rng.standard_normal((3, 3))
    A *= 0.9 / max(abs(np.linalg.eigvals(A)))
    B, C = rng.standard_normal((3, 1)), rng.standard_normal((2, 3))
    system = linear.linear_system(A, B, C, x_bounds=(-50, 50), v_bounds=(-0.05, 0.05))
    K = 300
    w = (3 * np.sin(0.05 * np.arange(K)) + rng.uniform(-1, 1, K))[:, None]
    v = rng.uniform(-0.05, 0.05, (K + 1, 2))
    return system, simulate(system, [1.0, -1.0, 2.0], K, w=w, v=v), v


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.slow
def test_designed_uise_is_as_accurate_as_the_linear_uio(seed):
    system, traj, v = benchmark(seed)
    uio = LinearUIO(system, x0_prior=np.zeros(3))
    reference = uio.run(None, traj.y)
    # the known answer: x_hat - x = -e + H v[k] with e = T x - z, e[k+1] = F e[k] - K v[k], whatever w
    e = uio.T @ traj.x[0] - uio.T @ np.zeros(3)
    for k in range(traj.steps + 1):
        np.testing.assert_allclose(reference.x_hat[k] - traj.x[k], -e + uio.H @ v[k], atol=1e-9)
        e = uio.F @ e - uio.K @ v[k]
    designed = UISE.design(system, x0_prior=np.zeros(3))
    report = designed.design_report
    assert designed.guaranteed and designed.N == report.N and designed.weights.mu == report.certificate.mu
    key = (report.certificate.mu, report.N, report.certificate.output_weight)
    chosen = [c for c in report.candidates if (c.mu, c.N, c.output_weight) == key]
    assert len(chosen) == 1 and np.all(chosen[0].bound == report.bound)
    np.testing.assert_array_equal(report.bound, designed.guarantee.error_bound)  # one formula: the guarantee's
    # among the candidates as accurate as the best on every state and input, the smallest bound
    errors = np.array([np.concatenate([c.rms / system.x.scale, c.w_rms / system.w.scale]) for c in report.candidates])
    score = regret(errors)
    tied = score <= ERROR_TOLERANCE * score.min()
    assert score[report.candidates.index(chosen[0])] <= ERROR_TOLERANCE * score.min()
    bounds = [max(c.bound / system.x.scale) for c, t in zip(report.candidates, tied, strict=True) if t]
    assert max(chosen[0].bound / system.x.scale) == min(bounds)

    def rmse(r):
        return float(np.sqrt(np.mean(r.error(traj.x)[50:] ** 2)))

    result = designed.run(None, traj.y)
    assert rmse(result) <= 1.2 * rmse(reference)
    minimal = certify_strong_detectability(system)  # the fastest certified rate: the worse design under noise
    assert minimal.mu == report.candidates[0].mu
    fastest = UISE(system, certificate=minimal, N=report.candidates[0].N, x0_prior=np.zeros(3)).run(None, traj.y)
    assert rmse(fastest) > 1.2 * rmse(result)


def test_regret_scores_every_component_against_its_best():
    errors = np.array([[1.0, 0.5, 2.0], [1.0, 0.05, 2.2], [3.0, 0.05, 2.0]])
    np.testing.assert_allclose(regret(errors), [10.0 ** (1 / 3), 1.1 ** (1 / 3), 3.0 ** (1 / 3)])
    # an input no window informed is not scored; a candidate's NaN elsewhere is the worst; rounding is floored
    np.testing.assert_allclose(regret(np.array([[1.0, np.nan], [2.0, np.nan]])), [1.0, 2.0])
    np.testing.assert_allclose(regret(np.array([[1.0, 1.0], [1.0, np.nan]])), [1.0, np.inf])
    np.testing.assert_allclose(regret(np.array([[1.0, 1e-15], [1.0, 1e-13]])), [1.0, 1.0])


@pytest.mark.slow
def test_design_is_within_the_tolerance_of_the_best_candidate_on_every_state():
    # the README's linear benchmark: x1 is measured (its error ties across rates), x2 is not; scoring the worst
    # state alone broke the tie by list order (mu 0.3, N 4: x2 error 330x the best candidate's)
    A = np.array([[0.8, 0.3, 0.0], [-0.2, 0.7, 0.4], [0.1, -0.3, 0.6]])
    B, C = np.array([[1.0], [0.0], [0.5]]), np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    system = linear.linear_system(A, B, C, x_bounds=(-50, 50), v_bounds=(-0.05, 0.05), x_scale=10.0)
    report = UISE.design(system, x0_prior=np.zeros(3), trials=1, steps=60).design_report
    key = (report.certificate.mu, report.N, report.certificate.output_weight)
    (chosen,) = [c for c in report.candidates if (c.mu, c.N, c.output_weight) == key]
    best = np.min([c.rms for c in report.candidates], axis=0)
    assert np.all(chosen.rms <= 1.2 * best), (chosen, best)


def test_design_refuses_what_it_cannot_do():
    system, _, _ = benchmark(0)
    with pytest.raises(OptionError, match="rates: expected numbers in"):
        UISE.design(system, x0_prior=np.zeros(3), rates=(0.5, 1.5))
    with pytest.raises(OptionError, match="max_horizon: expected an integer"):
        UISE.design(system, x0_prior=np.zeros(3), max_horizon=0)
    # an invariant zero at 0.6: mu >= 0.36, and 8 mu^N cond(P) < 1 has no solution with N = 1 (cond(P) >= 1)
    zero, *_ = linear.with_invariant_zeros([0.6], seed=3, x_bounds=(-10.0, 10.0), v_bounds=(-1e-3, 1e-3))
    with pytest.raises(HorizonError, match="max_horizon: no certified rate") as refused:
        UISE.design(zero, x0_prior=np.zeros(zero.nx), max_horizon=1, rates=(0.5,))
    # the shortest certified window as data (the CLI names its own flag with it), kept through pickling
    shortest = min(certify_strong_detectability(zero, mu=mu).min_horizon() for mu in (None, 0.5))
    assert isinstance(refused.value, CertificationError)
    assert (refused.value.limit, refused.value.shortest) == (1, shortest)
    copy = pickle.loads(pickle.dumps(refused.value))
    assert (copy.limit, copy.shortest, str(copy)) == (1, shortest, str(refused.value))
    with pytest.raises(HorizonError, match="fallback_horizon: no certified rate") as refused:
        UISE.design(zero, x0_prior=np.zeros(zero.nx), max_horizon=1, fallback_horizon=2, rates=(0.5,))
    assert (refused.value.limit, refused.value.shortest) == (2, shortest)


def test_a_fallback_horizon_reuses_the_certificates(monkeypatch):
    # no window of at most 1 certifies: the fallback limit admits the shortest one, certifying each rate once
    from uiest.estimators import design_search

    zero, *_ = linear.with_invariant_zeros([0.6], seed=3, x_bounds=(-10.0, 10.0), v_bounds=(-1e-3, 1e-3))
    shortest = min(certify_strong_detectability(zero, mu=mu).min_horizon() for mu in (None, 0.5))
    rates = []
    certify = design_search.certify_strong_detectability

    def counted(system, mu=None, **options):
        rates.append((mu, "max_condition" in options))
        return certify(system, mu=mu, **options)

    monkeypatch.setattr(design_search, "certify_strong_detectability", counted)
    design = design_uise(zero, np.zeros(zero.nx), max_horizon=1, fallback_horizon=shortest, rates=(0.5,), trials=1)
    assert shortest <= design.N <= design.ranked_horizon <= shortest
    assert [mu for mu, bounded in rates if not bounded] == [None, 0.5]  # each rate certified once


@pytest.mark.slow
def test_two_stage_design_is_certified_and_picks_its_most_accurate_candidate():
    from uiest.estimators import TwoStageUISE
    from uiest.estimators.bounds import noise_quadratic, two_stage_z_bound
    from uiest.reduction import reduce_quasi_state_affine

    system, traj, _ = benchmark(0)
    reduced = reduce_quasi_state_affine(system)
    designed = TwoStageUISE.design(reduced, x0_prior=np.zeros(3), rates=(0.5, 0.8), projection="none")
    report = designed.design_report
    assert designed.guarantee.applies and designed.N == report.N and designed.projection.mode == "none"
    assert not designed.guaranteed  # its bound exceeds X's width 100 (the design warns)
    assert [c.mu for c in report.candidates] == [report.candidates[0].mu, 0.5, 0.8]
    np.testing.assert_array_equal(report.bound, designed.guarantee.error_bound)  # per state, in x's units
    lam = max(np.sqrt(report.certificate.mu) * (2 * np.sqrt(report.certificate.c_x)) ** (1 / report.N),
              np.sqrt(report.certificate.mu))  # fmt: skip
    assert lam < 1 and report.bound.shape == (system.nx,) and np.all(np.isfinite(report.bound))
    # N minimises theo:stab's settled bound on z_sharp (decreasing in N: the longest window admitted)
    cert = report.certificate
    noise = noise_quadratic(cert.R_v, system.v.bounds, np.zeros(system.nv))
    best = min(range(cert.min_horizon(), 31), key=lambda n: two_stage_z_bound(cert.mu, cert.c_x, n, noise))
    assert best == report.N
    assert max(c.rms.max() for c in report.candidates if c.mu == report.certificate.mu) == min(
        c.rms.max() for c in report.candidates
    )  # all states share the scale 100 (X = +-50)
    uio = LinearUIO(system, x0_prior=np.zeros(3)).run(None, traj.y)

    def rmse(r):
        return float(np.sqrt(np.mean(r.error(traj.x)[50:] ** 2)))

    assert rmse(designed.run(None, traj.y)) <= 1.2 * rmse(uio)


def _logistic():
    """A logistic map driving a second state whose contraction 0.55 + 0.35 cos(3 x1) spans [0.2, 0.9]; y = x1."""
    from uiest import System

    return System.from_callables(
        lambda x, u, w: [3.7 * x[0] * (1 - x[0]) + 0.02 * x[1] + w[0],
                         (0.55 + 0.35 * np.cos(3 * x[0])) * x[1] + 0.4 * np.sin(3 * x[0]) + 0.3],
        lambda x, v: [x[0] + v[0]], nx=2, nw=1, nv=1, x_bounds=((-2, -3), (3, 3)), v_bounds=(-0.01, 0.01),
    )  # fmt: skip


@pytest.mark.slow
def test_a_rate_whose_window_is_too_long_is_certified_again_with_a_bounded_condition():
    # mu_min = 0.81 (0.9^2); the gain-optimal P has cond ~250, so min_horizon is 37 > 30 and the design once refused
    # the model. cond(P) bounded to fit N = 30 certifies the same rate.
    system = _logistic()
    free = certify_strong_detectability(system, samples=1000)
    assert free.certified and free.min_horizon() > 30
    bound = 0.99 * horizon_condition(free.mu, 30)
    fitted = certify_strong_detectability(system, mu=free.mu, samples=1000, max_condition=bound)
    assert fitted.certified and np.linalg.cond(fitted.P_scaled) <= bound * (1 + 1e-6) and fitted.min_horizon() <= 30
    assert fitted.verify(2000).worst_ratio <= 1.0
    design = UISE.design(system, x0_prior=[0.5, 0.5], rates=(0.9,), trials=1, steps=40,
                         certify_options={"samples": 1000})  # fmt: skip
    assert design.N <= 30 and design.certificate.min_horizon() <= design.N
    with pytest.raises(OptionError, match="max_condition"):
        certify_strong_detectability(system, max_condition=1.0)


@pytest.mark.slow
def test_a_design_whose_guarantee_bounds_nothing_under_the_noise_says_so():
    import warnings

    # y = 0.01 x + v with |v| <= 0.05 on X = [-1, 1]: certified (no zeros, CB != 0), but the noise can leave an
    # error of 5 / 0.01 scales; with y = x the bound is well inside X.
    weak = linear.linear_system(np.array([[0.5]]), [[1.0]], [[0.01]], x_bounds=(-1, 1), v_bounds=(-0.05, 0.05))
    with pytest.warns(UserWarning, match=r"guarantee is not informative for \['x\[0\]'\] .* holds but vacuous: bound"):
        designed = UISE.design(weak, x0_prior=[0.0], rates=(0.5,), trials=1, steps=40)
    assert designed.guarantee.applies and not designed.guarantee.informative
    strong = linear.linear_system(np.array([[0.5]]), [[1.0]], [[1.0]], x_bounds=(-1, 1), v_bounds=(-0.05, 0.05))
    with warnings.catch_warnings():
        warnings.simplefilter("error", UserWarning)
        assert UISE.design(strong, x0_prior=[0.0], rates=(0.5,), trials=1, steps=40).guarantee.informative


@pytest.mark.slow
def test_a_design_scores_its_candidates_on_the_users_records_when_given():
    from uiest.results import Trajectory

    system = linear.linear_system(np.array([[0.5]]), [[1.0]], [[1.0]], x_bounds=(-1, 1), v_bounds=(-0.05, 0.05))
    rng = np.random.default_rng(4)
    record = simulate(system, [0.2], 60, w=0.3 * np.sin(0.2 * np.arange(60))[:, None],
                      v=rng.uniform(-0.05, 0.05, (61, 1)))  # fmt: skip
    design = UISE.design(system, x0_prior=[0.0], rates=(0.5,), records=[record]).design_report
    for candidate in design.candidates:
        cert = certify_strong_detectability(system, mu=candidate.mu).with_output_weight(candidate.output_weight)
        estimator = UISE(system, certificate=cert, N=candidate.N, x0_prior=[0.0])
        error = estimator.run(None, record.y).error(record.x)[15:]
        np.testing.assert_allclose(candidate.rms, np.sqrt(np.mean(error**2, axis=0)), rtol=1e-6)
    measured = Trajectory.from_pandas(record.to_pandas()[list(system.y.names)], system)
    with pytest.raises(DataError, match=r"records\[0\]: expected a record with its states"):
        UISE.design(system, x0_prior=[0.0], rates=(0.5,), records=[measured])
    with pytest.raises(DataError, match="records: expected a non-empty sequence"):
        UISE.design(system, x0_prior=[0.0], rates=(0.5,), records=record)


@pytest.mark.slow
def test_a_certificate_with_larger_output_weights_still_holds_and_the_design_tries_them():
    system, _, _ = benchmark(1)
    cert = certify_strong_detectability(system, mu=0.6)
    heavier = cert.with_output_weight(10.0)
    assert heavier.certified and heavier.mu == cert.mu and heavier.min_horizon() == cert.min_horizon()
    np.testing.assert_allclose(heavier.R_y, 10.0 * cert.R_y)
    np.testing.assert_allclose(heavier.noise_gain, np.sqrt(10.0) * cert.noise_gain)
    assert heavier.verify(5000).worst_ratio <= 1.0 and heavier.output_weight == 10.0
    with pytest.raises(OptionError, match="factor: expected a finite number >= 1"):
        cert.with_output_weight(0.5)
    design = UISE.design(system, x0_prior=np.zeros(3), rates=(0.6,), trials=1, steps=40).design_report
    best = min((c for c in design.candidates if c.output_weight == 1.0), key=lambda c: max(c.rms / system.x.scale))
    assert {c.output_weight for c in design.candidates if (c.mu, c.N) == (best.mu, best.N)} == {1.0, 10.0, 100.0}


def chen_patton(dt=0.1, noise=1e-2, x_scale=1.0):
    """The 3-state UIO example of Chen and Patton (Robust Model-Based Fault Diagnosis for Dynamic Systems, 1999),
    ``dx/dt = A x + E d``, ``y = C x``, sampled by zero-order hold (d held over a step), X = +-1e9 with unit scales
    (None: none given): "unbounded" as a user writes it. No invariant zeros, so a linear UIO's poles are free."""
    import scipy.linalg

    A = np.array([[-1.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, -1.0, -1.0]])
    E = np.array([[-1.0], [0.0], [0.0]])
    C = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    M = scipy.linalg.expm(np.block([[A, E], [np.zeros((1, 4))]]) * dt)
    return linear.linear_system(M[:3, :3], M[:3, 3:], C, x_bounds=(-1e9, 1e9), v_bounds=(-noise, noise),
                                x_scale=x_scale, name="chen-patton")  # fmt: skip


def chen_patton_record(system, K=300):
    """A sine, uniform noise and a step of 50 at K/2 as the unknown input; output noise uniform in +-0.01."""
    rng = np.random.default_rng(0)
    w = (3 * np.sin(0.05 * np.arange(K)) + rng.uniform(-1, 1, K) + 50.0 * (np.arange(K) >= K // 2))[:, None]
    return simulate(system, [1.0, -1.0, 2.0], K, w=w, v=rng.uniform(-1e-2, 1e-2, (K + 1, 2)))


@pytest.mark.slow
def test_uise_design_where_x_means_unbounded_takes_scales_from_data_and_matches_the_linear_uio():
    # X = +-1e9 and no scales: X's width as every state's scale (2e9) made the design pick mu 0.1, N 4 and gave
    # 45-4600x the UIO's RMSE per state, with a scale warning per noise trial; the scales now come from the prior
    # and a short simulation (uiest.scales)
    from uiest.signal import ScaleSource

    system = chen_patton(x_scale=None)
    assert system.x.scale.tolist() == [2e9] * 3
    traj = chen_patton_record(system)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        designed = UISE.design(system, x0_prior=np.zeros(3))
        result = designed.run(None, traj.y)
    assert not [w for w in caught if "scale" in str(w.message)], [str(w.message) for w in caught]
    assert set(designed.system.x.scale_source) == {ScaleSource.DATA} and np.all(designed.system.x.scale < 10)
    uio = LinearUIO(system, x0_prior=np.zeros(3)).run(None, traj.y)

    def rmse(r):
        return np.sqrt(np.mean(r.error(traj.x)[50:] ** 2, axis=0))

    assert result.failures == 0 and designed.guaranteed
    assert np.all(rmse(result) <= 1.2 * rmse(uio)), (rmse(result), rmse(uio))


@pytest.mark.slow
def test_two_stage_design_on_the_chen_patton_benchmark_matches_the_linear_uio():
    # the reduced certificate once failed at every rate tried here ("solver failed") and the design raised
    from uiest.estimators import TwoStageUISE
    from uiest.reduction import reduce_quasi_state_affine

    system = chen_patton()
    reduced = reduce_quasi_state_affine(system)
    cert = certify_reduced_model(reduced)
    assert cert.certified, cert.reason
    assert cert.mu_min <= 2e-4 and cert.verify(20_000).holds  # no invariant zeros: any rate, to the bisection's floor
    K = 300
    rng = np.random.default_rng(0)
    w = (3 * np.sin(0.05 * np.arange(K)) + rng.uniform(-1, 1, K) + 50.0 * (np.arange(K) >= 150))[:, None]
    traj = simulate(system, [1.0, -1.0, 2.0], K, w=w, v=rng.uniform(-1e-2, 1e-2, (K + 1, 2)))
    designed = TwoStageUISE.design(reduced, x0_prior=np.zeros(3))
    assert designed.guaranteed and designed.design_report.certificate.certified
    uio = LinearUIO(system, x0_prior=np.zeros(3)).run(None, traj.y)

    def rmse(result):
        return np.sqrt(np.mean(result.error(traj.x)[50:] ** 2, axis=0))

    result = designed.run(None, traj.y)
    assert result.failures == 0
    assert np.all(rmse(result) <= 1.2 * rmse(uio)), (rmse(result), rmse(uio))


def test_design_options_are_checked_once_and_equal_to_the_keywords():
    with pytest.raises(OptionError, match="rates: expected numbers in"):
        DesignOptions(rates=(0.5, 1.5))
    with pytest.raises(OptionError, match="steps \\(at least 14"):
        DesignOptions(max_horizon=10, steps=13)
    with pytest.raises(OptionError, match="budget: expected CPU seconds"):
        DesignOptions(budget=-1.0)
    with pytest.raises(OptionError, match="certify_options: expected a mapping"):
        DesignOptions(certify_options=[("solver", "CLARABEL")])
    with pytest.raises(OptionError, match="seed"):
        DesignOptions(seed=-1)
    with pytest.raises(OptionError, match="fallback_horizon \\(at least max_horizon = 10\\)"):
        DesignOptions(max_horizon=10, fallback_horizon=9)
    assert DesignOptions(max_horizon=10, fallback_horizon=90).steps == 120  # a full window of 90 is scored


def test_a_fallback_horizon_beyond_the_memory_limit_is_checked_only_where_it_is_used(monkeypatch):
    # uiest estimate passes 60 to every design: a model whose window may hold 46 transitions once failed at once
    from uiest.window import size

    system, _, _ = benchmark(0)
    stage = size.STAGE_BYTES_PER_SIZE2 * (system.nx + system.nw + system.nv + system.ny) ** 2
    monkeypatch.setattr(size, "MEMORY_BUDGET", 21 * stage)  # windows of at most 20 transitions
    design = design_uise(system, np.zeros(3), max_horizon=8, fallback_horizon=30, rates=(0.5,), trials=1)
    assert design.N <= 8
    with pytest.raises(OptionError, match="max_horizon: expected a horizon <= 20"):
        design_uise(system, np.zeros(3), max_horizon=30, rates=(0.5,), trials=1)
    options = DesignOptions(max_horizon=8, rates=(0.9, 0.5, 0.5), trials=1)
    assert (options.rates, options.steps) == ((0.5, 0.9), 80)
    system, _, _ = benchmark(0)
    with pytest.raises(OptionError, match="design: given together with trials"):
        design_uise(system, np.zeros(3), design=options, trials=2)
    by_object = design_uise(system, np.zeros(3), design=options)
    by_keywords = design_uise(system, np.zeros(3), max_horizon=8, rates=(0.5, 0.9), trials=1)
    assert (by_object.certificate.mu, by_object.N) == (by_keywords.certificate.mu, by_keywords.N)
    np.testing.assert_array_equal(by_object.bound, by_keywords.bound)
    designed = UISE.design(system, x0_prior=np.zeros(3), design=options)
    assert (designed.design_report.certificate.mu, designed.N) == (by_object.certificate.mu, by_object.N)


class _CappedUISE(UISE):
    """A UISE that runs at most 12 nodes, as one capped at its information horizon does."""

    def __init__(self, system, *, N, **options):
        super().__init__(system, N=min(N, 12), **options)


def test_a_candidate_records_the_window_its_estimator_runs():
    system = closed_form.system(x_bounds=((-100.0, -10.0), (100.0, 10.0)))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        design = search_uise(_CappedUISE, system, [0.0, 0.0], rates=(0.8,), max_horizon=30, trials=1)
    assert design.N == 12 and {c.N for c in design.candidates} == {12}
    assert design.ranked_horizon > 12 and "capped at the information horizon" in design.summary()


def test_a_designed_uise_beyond_its_information_horizon_runs_capped_and_says_so():
    system = closed_form.system(x_bounds=((-100.0, -10.0), (100.0, 10.0)))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        est = UISE.design(system, x0_prior=[0.0, 0.0], rates=(0.5,), max_horizon=80, trials=1)
    report = est.design_report
    assert est.horizon_capped and est.N == report.N < report.ranked_horizon == est.requested_N
    assert est.guarantee.capped and est.guarantee.horizon == est.N and est.guarantee.applies
    assert f"The window runs N={est.N}, not the N={est.requested_N} asked for" in str(est.guarantee)


@pytest.mark.slow
def test_a_design_with_a_lag_builds_no_candidate_whose_window_is_shorter():
    # a Navion-like aircraft's lateral motion, a rudder fault unknown: at mu = 0.1 the certificate's weights cap the
    # window at its information horizon, N = 1; with lag = 2 building that candidate raised OptionError and ended
    # the design (and uiest estimate --lag 2, with every other estimator of the command)
    from uiest import System

    def rhs(x, u, w):
        b, p, r, phi = x[0], x[1], x[2], x[3]
        return [-0.254 * b - r + 0.183 * phi + 0.0708 * w[0],
                -15.98 * b - 8.4 * p + 2.19 * r - 28.98 * u[0] + 2.548 * w[0],
                4.549 * b - 0.349 * p - 0.76 * r - 0.2218 * u[0] - 4.597 * w[0], p]  # fmt: skip

    lateral = System.from_ode(rhs, lambda x, v: [x[1] + v[0], x[2] + v[1], x[3] + v[2]], nx=4, nu=1, nw=1, nv=3,
                              dt=0.02, x_bounds=((-0.5, -3, -2, -1.5), (0.5, 3, 2, 1.5)), u_bounds=(-0.3, 0.3),
                              v_bounds=(-1e-3, 1e-3))  # fmt: skip
    designed = UISE.design(lateral, x0_prior=np.zeros(4), lag=2, trials=1, steps=60)
    assert designed.N >= 2 and designed.options.lag == 2
    assert all(candidate.N >= 2 for candidate in designed.design_report.candidates)


def test_the_designs_own_noise_trial_names_the_prior_when_it_fails():
    # a prior outside X was refused as "x0:", and a trial that diverged ended with a bare simulation error
    from uiest import DataError, ModelError, System

    henon = System.from_callables(lambda x, u, w: [1.76 - x[1] ** 2 - 0.1 * x[2] + w[0], x[0], x[1]],
                                  lambda x, v: [x[0] + v[0]], nx=3, nw=1, nv=1, x_bounds=(-2.5, 2.5),
                                  v_bounds=(-1e-3, 1e-3))  # fmt: skip
    with pytest.raises(DataError, match=r"x0_prior: expected a point in X"):
        UISE.design(henon, x0_prior=[3.0, 0.0, 0.0], max_horizon=15, trials=1, steps=60)
    with pytest.raises(ModelError, match=r"x0_prior: the design.s noise trial.*pass records="):
        UISE.design(henon, x0_prior=[2.4, -2.4, 2.4], max_horizon=15, trials=1, steps=60)


def test_a_designs_trial_runs_count_their_failed_steps_without_warning(monkeypatch):
    # each trial run is the design's business: FailureWarning (more than 5 % of a run's steps failed) belongs to the
    # user's own runs, and a design whose trials fail in a third of their solves stays silent
    from uiest import FailureWarning
    from uiest.estimators import design_search
    from uiest.window import gauss_newton

    zero, *_ = linear.with_invariant_zeros([0.6], seed=3, x_bounds=(-10.0, 10.0), v_bounds=(-1e-3, 1e-3))
    solve, calls = gauss_newton.GaussNewtonSolver.solve, []

    def flaky(self, *args, **kwargs):
        calls.append(1)
        if len(calls) % 3 == 0:
            raise RuntimeError("a failed solve")
        return solve(self, *args, **kwargs)

    monkeypatch.setattr(gauss_newton.GaussNewtonSolver, "solve", flaky)
    options = {"x0_prior": np.zeros(zero.nx), "rates": (0.5,), "trials": 1, "steps": 60, "max_horizon": 10}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        designed = UISE.design(zero, **options)
    assert not [w for w in caught if issubclass(w.category, FailureWarning)] and len(calls) > 100
    truth = simulate(zero, np.zeros(zero.nx), 40, w=np.zeros((40, zero.nw)), seed=0)
    with pytest.warns(FailureWarning, match="steps failed"):  # the same failures in a run of the user's
        designed.run(truth.u, truth.y)
    monkeypatch.setattr(design_search, "_design", design_search._design.__wrapped__)  # control: not silenced
    with pytest.warns(FailureWarning):
        UISE.design(zero, **options)
