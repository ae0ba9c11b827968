"""Bad input gives typed errors naming the argument; property tests for shapes and missing data."""

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from uiest import DataError, OptionError, simulate
from uiest.estimators import FIE, UISE, MHEWeights, Outcome, StandardMHE, UISEWeights
from uiest.models import closed_form, crop_growth, linear

SYSTEM = linear.example()  # nx=3, nu=0, nw=1, ny=nv=1, X = [-10, 10]^3
WEIGHTS = UISEWeights(mu=0.5, P=np.eye(3) / 400.0, R_y=[[0.05]], R_v=[[0.05]])
MHE_WEIGHTS = MHEWeights(eta=0.5, P=np.eye(3), Q_w=[[1.0]], Q_v=[[1.0]], R=[[1.0]])
TRAJ = simulate(SYSTEM, [0.5, -0.5, 0.25], 12, w=np.sin(np.arange(12.0))[:, None])
N_SMALL = 3
# built once: hypothesis re-runs them (run() resets)
UISE_EST = UISE(SYSTEM, weights=WEIGHTS, N=N_SMALL, x0_prior=np.zeros(3))
MHE_EST = StandardMHE(SYSTEM, weights=MHE_WEIGHTS, N=N_SMALL, x0_prior=np.zeros(3))
CF_SYSTEM = closed_form.system()
CF_EST = UISE(CF_SYSTEM, weights=UISEWeights(mu=0.8, P=np.eye(2), R_y=[[1.0]], R_v=[[1.0]]), N=2, x0_prior=[0.0, 0.0])


@pytest.mark.parametrize(
    ("u", "y", "match"),
    [
        (None, TRAJ.y[:, 0], r"y: expected shape \(K\+1, 1\)"),  # 1-D y
        (None, np.hstack([TRAJ.y, TRAJ.y]), r"y: expected shape"),  # wrong ny
        (None, np.zeros((0, 1)), r"K\+1 >= 1"),
        (None, np.where(np.arange(13)[:, None] == 4, np.inf, TRAJ.y), "y: expected finite values or NaN"),
        (None, "text", "y: expected"),
        (np.zeros((12, 1)), TRAJ.y, r"u: expected shape \(K, 0\)"),  # nu = 0 system given an input
    ],
)
def test_bad_run_data(u, y, match):
    with pytest.raises(DataError, match=match):
        UISE_EST.run(u, y)


def test_bad_known_inputs():
    y = np.zeros((6, 1))
    with pytest.raises(DataError, match="u, y: length mismatch"):
        CF_EST.run(np.zeros((4, 1)), y)
    with pytest.raises(DataError, match="u: expected finite values"):
        CF_EST.run(np.array([[0.0], [np.nan], [0.0], [0.0], [0.0]]), y)
    with pytest.raises(DataError, match=r"u: expected shape \(K, 1\)"):
        CF_EST.run(np.zeros(5), y)
    with pytest.raises(DataError, match="u: required"):
        CF_EST.run(None, y)


def test_an_outage_longer_than_the_window_is_bridged_by_the_model():
    y = TRAJ.y.copy()
    y[4 : 4 + N_SMALL + 3] = np.nan  # the UISE's whole window k-3..k at k = 7, 8, 9
    result = UISE_EST.run(None, y)
    assert list(result.outcome[7:10]) == [Outcome.PROPAGATED] * 3 and result.propagated_steps == 3
    assert result.status[7] == "propagated (no data)" and result.success.all() and result.failures == 0
    assert np.all(np.isfinite(result.x_hat))
    # the one-step-ahead MHE needs y[k-N..k-1]: a missing y[0] only matters at k = 1
    y = TRAJ.y.copy()
    y[0] = np.nan
    assert MHE_EST.run(None, y).outcome[1] == Outcome.PROPAGATED
    # streaming: steps go on through an outage of any length and recover when data return
    est = UISE(SYSTEM, weights=WEIGHTS, N=1, x0_prior=np.zeros(3))
    est.step(None, [0.1])
    assert est.step(None, [np.nan]).outcome == Outcome.SOLVED  # its window 0..1 still holds y[0]
    for _ in range(4):
        assert est.step(None, [np.nan]).outcome == Outcome.PROPAGATED
    assert est.step(None, [0.1]).outcome == Outcome.SOLVED and est.k == 7


def test_a_run_keeps_what_it_computed_when_a_step_raises(monkeypatch):
    est = UISE(SYSTEM, weights=WEIGHTS, N=N_SMALL, x0_prior=np.zeros(3))
    original = est._solve_window
    calls = {"n": 0}

    def flaky(*args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 5:
            raise ZeroDivisionError("injected")
        return original(*args, **kwargs)

    monkeypatch.setattr(est, "_solve_window", flaky)
    result = est.run(None, TRAJ.y)
    assert result.outcome[4] == Outcome.ERROR and result.reason[4] == "ZeroDivisionError: injected"  # 5th solve
    assert not result.success[4] and result.failures == 1
    assert result.success[5:].all() and np.all(np.isfinite(result.x_hat))
    strict = UISE(SYSTEM, weights=WEIGHTS, N=N_SMALL, x0_prior=np.zeros(3), strict=True)
    monkeypatch.setattr(strict, "_solve_window", lambda *a, **k: 1 / 0)
    with pytest.raises(ZeroDivisionError):
        strict.run(None, TRAJ.y)


def test_bad_priors_and_options():
    with pytest.raises(DataError, match="x0_prior: expected a point in X"):
        UISE(SYSTEM, weights=WEIGHTS, N=3, x0_prior=[11.0, 0.0, 0.0])
    with pytest.raises(DataError, match="x0_prior: expected shape"):
        UISE_EST.run(None, TRAJ.y, x0_prior=[0.0, 0.0])
    with pytest.raises(DataError, match="x0_prior: expected finite"):
        UISE_EST.reset([np.nan, 0.0, 0.0])
    with pytest.raises(OptionError, match="x0_prior: required"):
        UISE(SYSTEM, weights=WEIGHTS, N=3).run(None, TRAJ.y)
    with pytest.raises(OptionError, match="x0_prior: required"):
        UISE(SYSTEM, weights=WEIGHTS, N=3).step(None, [0.0])
    for bad in (0, -2, 1.5, True, "3"):
        with pytest.raises(OptionError, match="N: expected an integer >= 1"):
            UISE(SYSTEM, weights=WEIGHTS, N=bad)
    with pytest.raises(OptionError, match="N: expected"):
        StandardMHE(SYSTEM, weights=MHE_WEIGHTS, N=0)
    with pytest.raises(OptionError, match="solver: unknown backend"):
        UISE(SYSTEM, weights=WEIGHTS, N=3, solver="fatrop")
    with pytest.raises(OptionError, match="solver_options"):
        UISE(SYSTEM, weights=WEIGHTS, N=3, solver_options=[("tol", 1)])
    with pytest.raises(DataError, match="v_prior: expected a point in V"):
        UISE(SYSTEM, weights=WEIGHTS, N=3, v_prior=[1.0])
    with pytest.raises(OptionError, match="system"):
        UISE("crop", weights=WEIGHTS, N=3)
    with pytest.raises(OptionError, match=r"options: unknown \['horizon'\]"):
        UISE(SYSTEM, weights=WEIGHTS, N=3, horizon=4)  # unknown keywords raise
    with pytest.raises(OptionError, match="strict: expected True or False"):
        UISE(SYSTEM, weights=WEIGHTS, N=3, strict="False")
    with pytest.raises(OptionError, match="lag: expected 0 <= lag <= N = 3"):
        UISE(SYSTEM, weights=WEIGHTS, N=3, lag=4)
    crop = crop_growth.system()
    crop_weights = MHEWeights.from_scales(crop, 0.48)
    with pytest.raises(DataError, match="w_prior: expected a point in the known range"):
        StandardMHE(crop, weights=crop_weights, N=3, w_prior=[0.5])
    assert StandardMHE(crop, weights=crop_weights, N=3, w_prior=[0.5], use_w_range=False).w_range is None


def test_bad_step_arguments():
    est = UISE(CF_SYSTEM, weights=UISEWeights(mu=0.8, P=np.eye(2), R_y=[[1.0]], R_v=[[1.0]]), N=2, x0_prior=[0, 0])
    with pytest.raises(DataError, match="u_prev: expected None at k = 0"):
        est.step([0.0], [0.0])
    with pytest.raises(DataError, match=r"y: expected shape \(1,\)"):
        est.step(None, [0.0, 1.0])
    with pytest.raises(DataError, match="y: expected finite values or NaN"):
        est.step(None, [np.inf])
    est.step(None, [0.0])
    with pytest.raises(DataError, match=r"u_prev: expected the known input u\[0\]"):
        est.step(None, [0.0])
    with pytest.raises(DataError, match="u_prev: expected finite"):
        est.step([np.nan], [0.0])
    assert est.step([0.0], 0.0).k == 1  # a scalar y for ny = 1


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(steps=st.integers(0, 8), which=st.sampled_from(["uise", "mhe"]))
def test_result_shapes(steps, which):
    est = UISE_EST if which == "uise" else MHE_EST
    result = est.run(None, TRAJ.y[: steps + 1])
    assert result.x_hat.shape == (steps + 1, 3) and result.w_hat.shape == (steps, 1)
    for name in (
        "status",
        "outcome",
        "success",
        "solver_status",
        "fallback",
        "held_input",
        "iterations",
        "solve_time",
        "cost",
        "window",
        "t",
    ):
        assert getattr(result, name).shape == (steps + 1,)
    assert result.missing.shape == (steps + 1, 1) and result.at_bound.shape == (steps + 1, 3)
    assert result.window.tolist() == [min(N_SMALL, k) for k in range(steps + 1)]
    assert np.all(np.isfinite(result.x_hat)) and result.failures == 0
    assert len(result.to_pandas()) == steps + 1


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    steps=st.integers(1, 10),
    extra=st.integers(-3, 3).filter(lambda n: n != 0),
)
def test_length_mismatch_names_u(steps, extra):
    u = np.zeros((steps + extra, 1)) if steps + extra >= 0 else np.zeros((0, 1))
    if u.shape[0] == steps:
        return
    with pytest.raises(DataError, match="u, y: length mismatch"):
        CF_EST.run(u, np.zeros((steps + 1, 1)))


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    mask=st.lists(st.sampled_from([False, False, False, True]), min_size=13, max_size=13),
    which=st.sampled_from(["uise", "mhe", "fie"]),
)
def test_missing_data(mask, which):
    missing = np.array(mask)
    y = np.where(missing[:, None], np.nan, TRAJ.y)
    if which == "fie":
        est, y = FIE(SYSTEM, weights=WEIGHTS, x0_prior=np.zeros(3)), y[:7]
        missing = missing[:7]
        horizon = None
    else:
        est, horizon = (UISE_EST if which == "uise" else MHE_EST), N_SMALL
    one_step = which == "mhe"
    K = len(y) - 1
    empty_window = False
    for k in range(K + 1):
        length = k if horizon is None else min(horizon, k)
        first, last = k - length, (k - 1 if one_step else k)
        if last >= first and missing[first : last + 1].all():
            empty_window = True
            break
    if missing.all():  # a record without a single measurement is refused, not bridged
        with pytest.raises(DataError, match="every measurement is missing"):
            est.run(None, y)
        return
    result = est.run(None, y)
    np.testing.assert_array_equal(result.missing[:, 0], missing)
    bridged = result.outcome == Outcome.PROPAGATED
    assert bridged.any() == empty_window and result.propagated_steps == int(bridged.sum()) and result.failures == 0
    assert np.all(np.isfinite(result.x_hat))
    assert np.all(SYSTEM.x.bounds.contains(result.x_hat, tol=1e-9))


def test_an_estimate_held_on_the_boundary_of_x_is_flagged():
    from uiest import BoundWarning, DomainWarning
    from uiest.models import closed_form

    system = closed_form.system()  # X = [-10, 10]^2
    with pytest.warns(DomainWarning, match="x left X"):
        truth = simulate(system, [0.0, 0.5], 30, u=np.zeros(1), w=np.ones((30, 1)))
    est = UISE(system, weights=UISEWeights.from_scales(system, 0.5, output=1e4), N=5, x0_prior=[0.0, 0.5])
    with pytest.warns(BoundWarning, match="x1 at or beyond X's upper side 10 in"):
        result = est.run(truth.u, truth.y)
    flagged = result.on_boundary & result.at_bound[:, 0]
    np.testing.assert_array_equal(flagged[truth.x_outside], True)
    assert not flagged[: int(np.argmax(truth.x_outside))].any()


@pytest.mark.parametrize("rows", [[0, 1], [0]])
def test_a_sample_missing_the_outputs_the_newest_input_reaches_holds_that_input(rows):
    # y = (x1, x2), w enters x1 only: C B has its one nonzero in row 0. With y[k] missing there (the whole
    # sample, or only x1), w[k-1] is unpenalised and unseen, so the window's optimum is any x[k] along B;
    # the estimate is then the prediction with the input held at its last estimate (errors measured before
    # the hold: 38-48 on x1, the free input ran to where X stops it; noise 0.05).
    A = np.array([[0.8, 0.3, 0.0], [-0.2, 0.7, 0.4], [0.1, -0.3, 0.6]])
    system = linear.linear_system(A, [[1.0], [0.0], [0.0]], [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], x_bounds=(-50, 50),
                                  v_bounds=(-0.05, 0.05))  # fmt: skip
    rng = np.random.default_rng(3)
    K = 120
    truth = simulate(system, [1.0, -1.0, 2.0], K, w=3 * np.sin(0.05 * np.arange(K))[:, None],
                     v=rng.uniform(-0.05, 0.05, (K + 1, 2)))  # fmt: skip
    y = truth.y.copy()
    holes = [40, 70, 100]
    y[np.ix_(holes, rows)] = np.nan
    result = UISE(system, weights=UISEWeights.from_scales(system, 0.6), N=8, x0_prior=np.zeros(3)).run(None, y)
    error = np.abs(result.error(truth.x))
    assert np.flatnonzero(result.held_input).tolist() == holes and result.held_steps == 3
    assert result.success[holes].all()
    assert error[holes].max() < 0.5  # the held input's one-step change is at most 0.15


def test_only_the_part_of_the_newest_input_that_missing_outputs_see_is_held():
    # B = C = I: with y2 missing, w2[k-1] is unseen but w1[k-1] is still determined by y1[k]: a fast w1 must keep
    # being estimated (holding all of w[k-1] erred by 0.8-3.4 on x1), the slow w2 is held.
    system = linear.linear_system(np.array([[0.8, 0.1], [-0.1, 0.7]]), np.eye(2), np.eye(2), x_bounds=(-50, 50),
                                  v_bounds=(-0.01, 0.01))  # fmt: skip
    rng = np.random.default_rng(3)
    K = 120
    w = np.column_stack([5 * np.sin(0.7 * np.arange(K)), 0.1 * np.sin(0.05 * np.arange(K))])
    truth = simulate(system, [1.0, -1.0], K, w=w, v=rng.uniform(-0.01, 0.01, (K + 1, 2)))
    y = truth.y.copy()
    holes = [40, 70, 100]
    y[holes, 1] = np.nan
    result = UISE(system, weights=UISEWeights.from_scales(system, 0.6), N=8, x0_prior=np.zeros(2)).run(None, y)
    error = np.abs(result.error(truth.x))
    assert np.flatnonzero(result.held_input).tolist() == holes
    assert error[holes, 0].max() < 0.02 and error[holes, 1].max() < 0.05  # noise 0.01; w2 moves by <= 0.005


@pytest.mark.parametrize("solver", ["gn", "ipopt"])
def test_a_missing_sample_leaves_later_windows_no_free_state_to_put_anywhere(solver):
    # nx = 1 and y[20] missing: in the windows after it x[20] is free (w[19] and w[20] absorb any value). Without
    # the gap penalty gn put it on X's side: x_lag[20] = -19.1 and w_hat[20] = 10.7 (truth -3.49 and -0.33).
    import casadi as ca

    from uiest import System

    system = System.from_callables(lambda x, u, w: [0.7 * x[0] + 0.2 * ca.sin(x[0]) + u[0] + w[0]],
                                   lambda x, v: [x[0] + v[0]], nx=1, nu=1, nw=1, nv=1, x_bounds=(-20, 20),
                                   u_bounds=(-2, 2), v_bounds=(-0.01, 0.01))  # fmt: skip
    K = 30
    u = np.sin(0.3 * np.arange(K))[:, None]
    truth = simulate(system, [1.0], K, u=u, w=lambda k, x: [0.5 * np.cos(0.2 * k)])
    y = truth.y.copy()
    y[20] = np.nan
    weights = UISEWeights.from_scales(system, 0.6)
    result = UISE(system, weights=weights, N=5, x0_prior=[0.0], solver=solver, lag=1).run(u, y)
    assert abs(result.x_lag[20, 0] - truth.x[20, 0]) < 0.5 and abs(result.w_hat[20, 0] - truth.w[20, 0]) < 0.5
    reference = UISE(system, weights=weights, N=5, x0_prior=[0.0], solver=solver, lag=1).run(u, truth.y)
    np.testing.assert_array_equal(result.x_hat[:20], reference.x_hat[:20])  # windows with all their data: as before
    # the input's effect vanishing where the window starts (x u w, u = 0 there): the penalty still acts
    vanishing = System.from_callables(lambda x, u, w: [0.7 * x[0] + 0.2 * ca.sin(x[0]) + u[0] + u[0] * w[0]],
                                      lambda x, v: [x[0] + v[0]], nx=1, nu=1, nw=1, nv=1, x_bounds=(-20, 20),
                                      u_bounds=(-2, 2), v_bounds=(-0.01, 0.01))  # fmt: skip
    u = (1.0 + 0.5 * np.sin(0.3 * np.arange(K)))[:, None]
    truth = simulate(vanishing, [1.0], K, u=u, w=lambda k, x: [0.5 * np.cos(0.2 * k)])
    y = truth.y.copy()
    y[20] = np.nan
    result = UISE(vanishing, weights=UISEWeights.from_scales(vanishing, 0.6), N=5, x0_prior=[0.0], solver=solver,
                  lag=1).run(u, y)  # fmt: skip
    assert abs(result.x_lag[20, 0] - truth.x[20, 0]) < 0.5 and abs(result.w_hat[20, 0] - truth.w[20, 0]) < 0.5
