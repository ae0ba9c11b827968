"""The delayed UISE (relative degree 2), the matching refusal and System.with_scales."""

import casadi as ca
import numpy as np
import pytest

from uiest import BoundWarning, ModelError, OptionError, System, simulate
from uiest.delay import delayed_system, matching_ranks
from uiest.design import DesignOptions
from uiest.detectability import certify_strong_detectability
from uiest.estimators import UISE, DelayedUISE, Outcome, UISEWeights, WindowOptions
from uiest.models import linear

V_MAX = 0.05


def _chain(a3=0.5):
    # x1+ = x1 + w, x2+ = x1, x3+ = a3 x3 + u, y = x2 + v: w shows in y two steps later (relative degree 2)
    A = np.array([[1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, a3]])
    return linear.linear_system(A, [[1.0], [0.0], [0.0]], [[0.0, 1.0, 0.0]], B_u=[[0.0], [0.0], [1.0]],
                                x_bounds=(-100, 100), v_bounds=(-V_MAX, V_MAX), u_bounds=(-5, 5))  # fmt: skip


def test_lagged_error_of_the_delayed_uise_is_the_closed_form():
    # The delayed system has state b = (x2, x3) and free inputs (w, a = x1). Every window node after
    # the first fits x2 = y exactly (x2 is free through a, v = v_bar = 0 is cheapest), and x3 is only
    # propagated from the prior (P diagonal: nothing couples it to x2). Hence, for x[j] read at
    # k = j + lag from an interior node: x_lag[j] - x[j] = (v[j+1], v[j], 0.5^j (x3_hat[0] - x3[0])).
    system = _chain()
    delayed = delayed_system(system)
    assert delayed.system.x.names == ("x[1]", "x[2]") and delayed.system.w.names == ("w[0]", "x[0]")
    rng = np.random.default_rng(3)
    K = 60
    v = rng.uniform(-V_MAX, V_MAX, (K + 1, 1))
    u = np.sin(0.2 * np.arange(K))[:, None]
    truth = simulate(system, [2.0, -1.0, 3.0], K, u=u, w=(2.0 * rng.standard_normal(K))[:, None], v=v)
    weights = UISEWeights(mu=0.5, P=np.eye(2), R_y=np.eye(1), R_v=np.eye(1))
    est = DelayedUISE(system, weights=weights, N=5, lag=2, x0_prior=[0.0, 0.0, 0.0])
    result = est.run(u, truth.y)
    j = np.arange(1, K - 1)
    expected = np.column_stack([v[j + 1, 0], v[j, 0], 0.5**j * (0.0 - 3.0)])
    np.testing.assert_allclose(result.x_lag[j] - truth.x[j], expected, atol=1e-8)
    assert result.lag == 2 and np.all(np.isnan(result.x_lag[-2:]))
    frame = result.to_pandas()  # the lagged estimates are exported with the rest
    np.testing.assert_array_equal(frame[[f"{name}_lag" for name in system.x.names]].to_numpy(), result.x_lag)
    # the unknown input w[j] = x1[j+1] - x1[j] is fitted to consecutive lagged estimates
    i = np.arange(1, K - 2)  # w[i], delivered at k = i + lag + 1 <= K
    np.testing.assert_allclose(result.w_hat[i, 0] - truth.w[i, 0], v[i + 2, 0] - v[i + 1, 0], atol=1e-8)
    assert str(est.guarantee).startswith("none: explicit weights")
    # uiest estimate scores the delayed UISE on its lagged estimates, any other estimator on x_hat, per state
    from uiest.estimate import error_text, errors_against_truth

    rmse = errors_against_truth(truth, {"delayed": result, "uise": result})
    np.testing.assert_allclose(rmse["delayed"], np.sqrt(np.nanmean((result.x_lag - truth.x) ** 2, axis=0)))
    np.testing.assert_allclose(rmse["uise"], np.sqrt(np.mean((result.x_hat - truth.x) ** 2, axis=0)))
    assert error_text(system, rmse["delayed"], lagged=True).startswith(f"x[0] {rmse['delayed'][0]:.3g}, x[1] ")


def test_a_system_without_matching_is_refused_unless_forced():
    system = _chain()
    assert matching_ranks(system) == (0, 1)
    weights = UISEWeights.from_scales(system, 0.5)
    with pytest.raises(ModelError, match=r"matching fails \(rank\(C B\) = 0 < rank\(B\) = 1.*DelayedUISE"):
        UISE(system, weights=weights, N=5)
    with pytest.raises(OptionError, match="lag: expected an integer >= 1, got 0"):
        DelayedUISE(system, weights=UISEWeights.from_scales(delayed_system(system).system, 0.5), N=5, lag=0)
    forced = UISE(system, weights=weights, N=5, force=True, x0_prior=np.zeros(3))
    truth = simulate(system, [2.0, -1.0, 3.0], 20, u=np.zeros((20, 1)), w=np.ones((20, 1)))
    with pytest.warns(BoundWarning, match=r"UISE: the estimate of x\[0\] at or beyond X's upper side 100"):
        result = forced.run(np.zeros((20, 1)), truth.y)  # x[k] is not determined by y[..k]: it runs to X's side
    assert set(result.outcome) == {Outcome.SOLVED} and result.failures == 0
    assert not forced.guaranteed and str(forced.guarantee).startswith("none: matching fails")
    with pytest.raises(ModelError, match="matching holds"):
        delayed_system(linear.linear_system(0.5 * np.eye(2), [[1.0], [0.0]], [[1.0, 0.0]], x_bounds=(-1, 1)))


def _nonlinear():
    def f(x, u, w):
        return [x[0] + w[0], x[0] + 0.3 * ca.sin(x[2]), (0.5 + 0.3 * ca.tanh(x[1])) * x[2] + u[0]]

    bounds = {"x_bounds": ((-5, -5, -5), (5, 5, 5)), "u_bounds": (-1, 1), "v_bounds": (-1e-3, 1e-3)}
    return System.from_callables(f, lambda x, v: [x[1] + v[0]], nx=3, nu=1, nw=1, nv=1, **bounds)


def test_nonlinear_delayed_uise_is_certified_and_exact_without_noise():
    system = _nonlinear()
    delayed = delayed_system(system)
    cert = certify_strong_detectability(delayed.system)
    # zero dynamics x3+ = a(x2) x3 + u with x2 measured: mu* = max a^2 over x2 in [-5, 5]
    assert cert.certified and cert.mu_min == pytest.approx((0.5 + 0.3 * np.tanh(5.0)) ** 2, abs=0.01)
    K = 60
    u = 0.5 * np.sin(0.3 * np.arange(K))[:, None]
    truth = simulate(system, [0.5, 0.2, -1.0], K, u=u, w=lambda k, x: [0.3 * np.cos(0.5 * k) - 0.05 * x[0]])
    est = DelayedUISE(system, certificate=cert, lag=1, x0_prior=np.zeros(3))
    assert est.guarantee.applies and cert.min_horizon() == est.N
    assert not est.guaranteed  # no bound for x[0], which depends on the delayed system's unknown input
    result = est.run(u, truth.y)
    assert np.abs(result.x_lag[40:-1] - truth.x[40:-1]).max() < 1e-8
    assert np.abs(result.w_hat[40:-2] - truth.w[40:-2]).max() < 1e-8
    # x[k] itself is not determined by y[..k]: its x1 is held from k-1, so it is off by about w
    assert np.abs(result.x_hat[40:, 0] - truth.x[40:, 0]).max() > 1e-2


def test_relative_degree_three_and_inputs_that_never_show_are_refused():
    A3 = np.array([[1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    chain3 = linear.linear_system(A3, [[1.0], [0.0], [0.0]], [[0.0, 0.0, 1.0]], x_bounds=(-1, 1))
    with pytest.raises(ModelError, match="relative degree is 3 or more"):
        delayed_system(chain3)
    hidden = linear.linear_system(np.diag([0.5, 0.5]), [[1.0], [0.0]], [[0.0, 1.0]], x_bounds=(-1, 1))
    with pytest.raises(ModelError, match="do not all reach the rest of the state"):
        DelayedUISE(hidden, weights=UISEWeights(mu=0.5, P=np.eye(1), R_y=np.eye(1), R_v=np.eye(1)), N=3)


def test_scales_from_a_trajectory_and_explicit_scales():
    system = linear.linear_system(0.5 * np.eye(2), [[1.0], [0.0]], [[1.0, 0.0]], x_bounds=(-1e9, 1e9))
    traj = simulate(system, [3.0, -200.0], 20, w=np.ones((20, 1)))
    scaled = system.with_scales(traj)
    np.testing.assert_allclose(scaled.x.scale, [3.0, 200.0])
    assert scaled.w.scale[0] == 1.0 and scaled.x.bounds == system.x.bounds
    assert system.with_scales(x=[1.0, 2.0], y=4.0).y.scale.tolist() == [4.0]
    with pytest.raises(OptionError, match="x: expected 2 positive finite scales"):
        system.with_scales(x=[1.0, -2.0])
    with pytest.raises(OptionError, match="unknown signals"):
        system.with_scales(z=1.0)


def test_an_oblique_invisible_direction_certifies_and_stays_in_X():
    # w enters along (1, 1, 0)/sqrt(2) and the output sees x1 - x2: C B = 0 with B0 not a coordinate axis
    A = np.array([[0.5, 0.2, 0.1], [0.1, 0.4, 0.0], [0.2, -0.1, 0.6]])
    B = np.array([[1.0], [1.0], [0.0]]) / np.sqrt(2)
    system = linear.linear_system(A, B, [[1.0, -1.0, 0.0]], x_bounds=((-1, -100, -10), (1, 100, 10)),
                                  v_bounds=(-1e-3, 1e-3))  # fmt: skip
    delayed = delayed_system(system)
    np.testing.assert_allclose(delayed.M_a @ delayed.T_a + delayed.M_b @ delayed.T_b, np.eye(3), atol=1e-12)
    cert = certify_strong_detectability(delayed.system)  # rounding in T_b B must not count as an input direction
    assert cert.certified, cert.reason
    rng = np.random.default_rng(0)
    truth = simulate(system, [0.3, 2.0, -1.0], 60, w=(0.3 * rng.standard_normal(60))[:, None])
    est = DelayedUISE(system, certificate=cert, lag=1, x0_prior=np.zeros(3))
    result = est.run(None, truth.y)
    assert np.abs(result.x_lag[30:-1] - truth.x[30:-1]).max() < 1e-6
    assert all(system.x.bounds.contains(x) for x in result.x_lag[:-1])
    with pytest.raises(OptionError, match=r"lag: expected 1 <= lag <= N - 1 = 3"):
        DelayedUISE(system, certificate=cert, N=4, lag=4)


def test_designed_delayed_uise_is_certified_and_its_lagged_error_is_the_noise():
    # On the chain x_lag[j] - x[j] = (v[j+1], v[j], ...) for any weights that fit y exactly at interior nodes;
    # the design certifies the delayed system, keeps N >= lag + 1 and the RMS error is the noise's.
    system = _chain()
    rng = np.random.default_rng(4)
    K = 200
    v = rng.uniform(-V_MAX, V_MAX, (K + 1, 1))
    u = np.sin(0.2 * np.arange(K))[:, None]
    truth = simulate(system, [2.0, -1.0, 3.0], K, u=u, w=(2.0 * rng.standard_normal(K))[:, None], v=v)
    est = DelayedUISE.design(system, x0_prior=np.zeros(3), lag=2, rates=(0.5, 0.9))
    assert est.guarantee.applies and est.options.lag == 2 and est.N >= 3 and est.design_report.N <= est.N
    assert not est.guaranteed  # no bound for x[0]
    error = est.run(u, truth.y).x_lag[50:-2] - truth.x[50:-2]
    np.testing.assert_allclose(error[:, :2], np.column_stack([v[51:-1, 0], v[50:-2, 0]]), atol=1e-6)


def test_the_delayed_design_refuses_records_it_could_not_score():
    with pytest.raises(OptionError, match=r"records: DelayedUISE\.design scores its candidates on noise trials only"):
        DelayedUISE.design(_chain(), x0_prior=np.zeros(3), records=[])
    with pytest.raises(OptionError, match=r"records: DelayedUISE\.design scores its candidates on noise trials only"):
        DelayedUISE.design(_chain(), x0_prior=np.zeros(3), design=DesignOptions(records=[]))


def test_a_window_options_object_gets_the_delayed_uise_s_lag():
    system = _chain()
    weights = UISEWeights(mu=0.5, P=np.eye(2), R_y=np.eye(1), R_v=np.eye(1))
    est = DelayedUISE(system, weights=weights, N=5, lag=2, window=WindowOptions(solver="ipopt"))
    assert est.options == WindowOptions(solver="ipopt", lag=2)
    assert est.options == DelayedUISE(system, weights=weights, N=5, lag=2, solver="ipopt").options
    with pytest.raises(OptionError, match="window: its lag 1 differs from lag = 2"):
        DelayedUISE(system, weights=weights, N=5, lag=2, window=WindowOptions(lag=1))
