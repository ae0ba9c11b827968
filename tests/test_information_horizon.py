"""The information horizon (uiest.estimators.horizon): known answers, the cap, the guarantee that states it."""

import math

import numpy as np
import pytest

from uiest import OptionError, System, UniformNoise, simulate
from uiest.detectability import certify_strong_detectability
from uiest.estimators import UISE, MHEWeights, StandardMHE, TwoStageUISE, TwoStageWeights, UISEWeights
from uiest.estimators.horizon import information_horizon
from uiest.estimators.weight_range import EPS
from uiest.models import closed_form, crop_growth, linear
from uiest.window import WindowModel


def scalar_system() -> System:
    """x+ = 0.5 x + w, y = x + v; every scale 1, so the scaled weights are the numbers given to from_scales."""
    return System.from_callables(
        lambda x, u, w: [0.5 * x[0] + w[0]],
        lambda x, v: [x[0] + v[0]],
        nx=1, nu=0, nw=1, nv=1, x_bounds=(-5.0, 5.0), v_bounds=(-0.1, 0.1), x_scale=1.0, y_scale=1.0, v_scale=1.0,
        w_scale=1.0,
    )  # fmt: skip


def test_uise_horizon_is_the_longest_window_whose_prior_term_stays_above_eps_of_the_newest_output_term():
    # UISE cost: prior 4 mu^L P, node j: 2 mu^(j-1) R_y, 8 mu^(j-1) R_v. With P = 1, R_y = 1e6, R_v = 1 (scaled)
    # and mu = 0.5: smallest term 4 mu^L (the prior), largest 2e6 / mu (the newest output), so
    # ratio(L) = 0.5^L 1e-6 >= eps = 2.22e-16 up to L = 32 (0.5^32 = 2.33e-10; 0.5^33 = 1.16e-10).
    system = scalar_system()
    weights = UISEWeights.from_scales(system, 0.5, prior=1.0, output=1e6, noise=1.0)
    info = information_horizon(weights.schedule(), WindowModel.from_system(system), one_step_ahead=False)
    assert info.horizon == 32
    assert (info.oldest_term, info.oldest, info.largest_term, info.largest) == ("prior", 4.0, "output", 4e6)
    assert info.ratio(32) >= EPS > info.ratio(33)
    assert info.ratio(32) == pytest.approx(0.5**32 * 1e-6)


def test_standard_mhe_horizon_counts_its_one_step_ahead_newest_node():
    # standard MHE: prior 2 eta^L P; node j (newest measured j = 1): eta^(j-1) R, 2 eta^(j-1) Q_v, 2 eta^(j-1) Q_w.
    # P = Q_v = Q_w = 1, R = 1e6, eta = 0.5: smallest 2 eta^L, largest 1e6: eta^L 2e-6 >= eps up to L = 33.
    system = scalar_system()
    weights = MHEWeights.from_scales(system, 0.5, prior=1.0, disturbance=1.0, noise=1.0, output=1e6)
    est = StandardMHE(system, weights=weights, N=100, x0_prior=[0.0])
    assert est.information_horizon is not None and est.information_horizon.horizon == 33
    assert (est.information_horizon.oldest, est.information_horizon.largest) == (2.0, 1e6)
    assert (est.N, est.requested_N, est.horizon_capped) == (33, 100, True)


def test_horizon_follows_the_discount_and_the_weights_spread():
    # log(eps * largest / oldest) / log(mu): a tenfold larger output weight shortens it by log(10)/log(1/mu) nodes
    system, model = scalar_system(), WindowModel.from_system(scalar_system())
    for mu in (0.3, 0.5, 0.8):
        for output in (1.0, 1e3, 1e6):
            schedule = UISEWeights.from_scales(system, mu, output=output).schedule()
            info = information_horizon(schedule, model, one_step_ahead=False)
            oldest = min(4.0, 2.0 * output / mu, 8.0 / mu)
            largest = max(2.0 * output, 8.0) / mu
            assert info.horizon == math.floor(math.log(EPS * largest / oldest) / math.log(mu))
            assert info.ratio(info.horizon) >= EPS > info.ratio(info.horizon + 1)


def test_a_window_longer_than_the_horizon_is_capped_and_runs_as_the_capped_one():
    system = scalar_system()
    weights = UISEWeights.from_scales(system, 0.3, output=1e6)  # horizon 18
    truth = simulate(system, [1.0], 60, w=lambda k, x: [np.sin(0.3 * k) + 0.01 * k], v=UniformNoise.symmetric(0.01),
                     seed=0)  # fmt: skip
    long = UISE(system, weights=weights, N=200, x0_prior=[0.0])
    assert long.information_horizon is not None
    horizon = long.information_horizon.horizon
    assert horizon == 18 and horizon == long.N and long.requested_N == 200 and long.horizon_capped
    short = UISE(system, weights=weights, N=horizon, x0_prior=[0.0])
    assert not short.horizon_capped
    a, b = long.run(truth.u, truth.y), short.run(truth.u, truth.y)
    assert a.failures == 0 and a.fallbacks == 0 and a.horizon == horizon
    np.testing.assert_array_equal(a.x_hat, b.x_hat)
    assert a.guarantee.capped and not b.guarantee.capped


def test_lag_is_checked_against_the_window_used():
    weights = UISEWeights.from_scales(scalar_system(), 0.3, output=1e6)  # horizon 18
    with pytest.raises(OptionError, match="lag: expected 0 <= lag <= N = 18"):
        UISE(scalar_system(), weights=weights, N=40, lag=30)


def test_capped_guarantee_is_the_theorem_for_the_window_used_and_says_so():
    system = linear.example()
    cert = certify_strong_detectability(system)
    capped = UISE(system, certificate=cert, N=500, x0_prior=np.zeros(system.nx))
    assert capped.information_horizon is not None
    horizon = capped.information_horizon.horizon
    assert horizon is not None and cert.min_horizon() <= horizon < 500 and horizon == capped.N
    used = UISE(system, certificate=cert, N=horizon, x0_prior=np.zeros(system.nx))
    g, reference = capped.guarantee, used.guarantee
    assert g.applies and g.capped and (g.horizon, g.requested_horizon, g.information_horizon) == (horizon, 500, horizon)
    assert g.error_bound is not None and reference.error_bound is not None
    np.testing.assert_array_equal(g.error_bound, reference.error_bound)
    assert g.text.startswith(reference.text)
    assert f"The window runs N={horizon}, not the N=500 asked for: it is capped at its information horizon" in g.text
    assert not reference.capped and "capped" not in reference.text
    data = g.to_dict()
    assert (data["capped"], data["horizon"], data["requested_horizon"]) == (True, horizon, 500)


def test_within_the_horizon_nothing_changes():
    system = closed_form.system(x_bounds=((-100.0, -10.0), (100.0, 10.0)))
    est = UISE(system, certificate=certify_strong_detectability(system), x0_prior=[0.0, 0.0])
    assert est.information_horizon is not None and est.N == est.requested_N == 30 < est.information_horizon.horizon
    assert not est.guarantee.capped and "capped" not in est.guarantee.text


@pytest.mark.parametrize(
    ("kind", "expected"),
    [("UISE", 30), ("standard MHE", 31), ("two-stage UISE", 32)],
)
def test_crop_bench_weights_horizons(kind, expected):
    # the bench's weights (mu = 0.48, output 1e6 per scaled unit): 4 mu^L against 2e6 / mu for the UISE
    system = crop_growth.system()
    if kind == "UISE":
        est = UISE(system, weights=UISEWeights.from_scales(system, 0.48, output=1e6), N=300)
    elif kind == "standard MHE":
        est = StandardMHE(system, weights=MHEWeights.from_scales(system, 0.48, output=1e6), N=300)
    else:
        reduced = crop_growth.reduction()
        est = TwoStageUISE(reduced, weights=TwoStageWeights.from_scales(reduced, 0.48, output=1e6), N=300)
    assert est.information_horizon is not None and est.information_horizon.horizon == expected
    assert expected == est.N and est.requested_N == 300
