"""The crop-growth model against the paper's equations, evaluated by hand."""

import numpy as np
import pytest

from uiest import OptionError, simulate
from uiest.models import crop_growth as cg


def test_one_step_matches_hand_computation():
    # Point: x = (x^c, x^{d,1}, x^{d,2}) = (1e-3, 0.09, 0.085), u^d = 25 degC, w = 0.98, Delta_t = 60 s.
    # phi_u(25) = -5.11e-6 * 25^2 + 2.3e-4 * 25 - 6.29e-4
    #           = -3.19375e-3 + 5.75e-3 - 6.29e-4           = 1.92725e-3
    # (x^c - c_Gamma) phi_u = (1e-3 - 5.2e-5) * 1.92725e-3  = 1.827033e-6
    # 100 c_rad,phot = 100 * 3.55e-9                        = 3.55e-7
    # phi = 3.55e-7 * 1.827033e-6 / (3.55e-7 + 1.827033e-6) = 2.9724422820e-7
    # F = exp(-53 * 0.09) - 1 = exp(-4.77) - 1              = -0.99151961984
    # 2^(0.1 * 25 - 2.5) = 2^0 = 1, so g_1 = 0.09, g_2 = 0.085
    # x^c+:  60/4.1 * (F - w) * phi = 14.634146 * (-1.971519620) * 2.972442e-7 = -8.575943821e-6
    #        60 * (4.87e-7/4.1) * (0.09 + 0.085)                                 =  1.247195122e-6
    #        1e-3 - 8.575943821e-6 + 1.247195122e-6                              =  9.926712513e-4
    # x^d1+: 60 * 0.544 * F * phi = -9.619774523e-6;  60 * 2.65e-7 * 0.09 = 1.431e-6
    #        0.09 + 9.619774523e-6 - 1.431e-6                                    =  0.0900081887745
    # x^d2+: 60 * 0.8 * phi * w = 1.398236849e-5;   60 * 1.85e-7 * 0.085 = 9.435e-7
    #        0.085 + 1.398236849e-5 - 9.435e-7                                   =  0.0850130388685
    system = cg.system()
    x_next = system.step([1e-3, 0.09, 0.085], [25.0], [0.98])
    expected = [9.926712513006663e-4, 0.09000818877452259, 0.0850130388684947]
    np.testing.assert_allclose(x_next, expected, rtol=1e-12, atol=0)
    phi = cg.photosynthesis(cg.CropParameters(), 25.0, 1e-3)
    assert phi == pytest.approx(2.9724422820369815e-7, rel=1e-12)


def test_outputs_are_co2_and_total_weight():
    system = cg.system()
    y = system.output([1e-3, 0.09, 0.085], [2e-6, -1e-6])
    np.testing.assert_allclose(y, [1e-3 + 2e-6, 0.175 - 1e-6], rtol=1e-14)


def test_domains_sizes_and_names_are_the_papers():
    system = cg.system()
    assert (system.nx, system.nu, system.nw, system.nv, system.ny) == (3, 1, 1, 2, 2)
    np.testing.assert_array_equal(system.x.bounds.lower, [0.0, 0.08, 0.08])
    np.testing.assert_array_equal(system.x.bounds.upper, [0.0027, 0.1, 0.1])
    np.testing.assert_array_equal(system.v.bounds.upper, [3e-6, 3e-6])
    np.testing.assert_array_equal(system.w_range.lower, [0.965])
    np.testing.assert_array_equal(system.w_range.upper, [1.0])
    assert not np.isfinite(system.w.bounds.upper).any()  # the UISEs see w as unbounded
    np.testing.assert_array_equal(system.u.bounds.lower, [25.0])
    assert system.dt == 60.0
    assert system.x.names == ("x_c", "x_d1", "x_d2")


def test_unknown_input_law_and_range_over_long_simulation():
    system = cg.system()
    law = cg.UnknownInputLaw()
    assert law(0, np.array([0.0, 0.09, 0.09]))[0] == pytest.approx(1 - np.exp(-45 * 0.09))
    scenario = cg.DEFAULT_SCENARIO
    traj = simulate(system, scenario.x0, 3000, w=law, v=scenario.noise(), seed=3)
    assert system.x.bounds.contains(traj.x).all()
    assert np.all((traj.w >= 0.965) & (traj.w <= 1.0))
    np.testing.assert_allclose(traj.w[:, 0], 1 - np.exp(-45 * traj.x[:-1, 2]))
    assert np.all(np.abs(traj.v) <= 3e-6)
    assert traj.w[-1, 0] > traj.w[0, 0]  # the unknown input grows as the crop grows


def test_parameters_are_overridable_and_checked():
    system = cg.system(dt=30.0, temperature=20.0)
    assert system.dt == 30.0
    np.testing.assert_array_equal(system.u.bounds.upper, [20.0])
    with pytest.raises(OptionError, match="not_a_parameter"):
        cg.system(not_a_parameter=1.0)


def test_scenario_prior_uses_first_co2_measurement():
    prior = cg.DEFAULT_SCENARIO.prior([1.1e-3, 0.17])
    np.testing.assert_array_equal(prior, [1.1e-3, 0.09, 0.09])
    x0 = cg.DEFAULT_SCENARIO.sample_x0(np.random.default_rng(0))
    assert cg.system().x.bounds.contains(x0)
