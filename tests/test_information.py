"""The window information bound against cases with known answers."""

import numpy as np
import pytest

from uiest import OptionError, simulate
from uiest.detectability import window_information
from uiest.models import crop_growth, linear


def test_fully_measured_system_with_free_inputs_resolves_each_state_to_the_noise_level():
    # y = x + v and w moves every state: only y_k informs x_k, so the bound is sigma itself
    A = np.array([[0.9, 0.2], [0.0, 0.7]])
    system = linear.linear_system(A, np.eye(2), np.eye(2), x_bounds=(-20, 20), v_bounds=(-1e-2, 1e-2))
    traj = simulate(system, [1.0, -1.0], 20, w=np.ones((20, 2)))
    assert not traj.x_outside.any()
    bound = window_information(system, traj.x, None, traj.w, k=15, N=5, noise_std=[0.01, 0.02], mu=0.5)
    np.testing.assert_allclose(bound.std_bound, [0.01, 0.02], rtol=1e-8)
    np.testing.assert_allclose(bound.std_discounted, [0.01, 0.02], rtol=1e-8)
    assert not bound.rank_deficient


def test_more_samples_tighten_the_bound_when_nothing_is_unknown_but_x():
    # no unknown-input direction hides x2: a longer window resolves it better
    A = np.array([[1.0, 0.1], [0.0, 1.0]])
    system = linear.linear_system(A, [[0.0], [0.0]], [[1.0, 0.0]], x_bounds=(-10, 10), v_bounds=(-1, 1))
    traj = simulate(system, [0.0, 1.0], 40, w=np.zeros((40, 1)))
    short = window_information(system, traj.x, None, traj.w, k=10, N=5, noise_std=0.1)
    long = window_information(system, traj.x, None, traj.w, k=30, N=30, noise_std=0.1)
    assert long.std_bound[1] < 0.2 * short.std_bound[1]
    assert np.isnan(short.std_discounted).all()


def test_unseen_direction_is_rank_deficient_and_bad_input():
    system = linear.linear_system(np.eye(2), [[1.0], [0.0]], [[1.0, 0.0]], x_bounds=(-10, 10), v_bounds=(-1, 1))
    traj = simulate(system, [0.0, 1.0], 10, w=np.zeros((10, 1)))
    assert window_information(system, traj.x, None, traj.w, k=8, N=4, noise_std=0.1).rank_deficient
    with pytest.raises(OptionError, match="k, N"):
        window_information(system, traj.x, None, traj.w, k=3, N=4, noise_std=0.1)
    with pytest.raises(OptionError, match="noise_std"):
        window_information(system, traj.x, None, traj.w, k=8, N=4, noise_std=0.0)


def test_crop_window_cannot_resolve_the_crop_weights_at_the_papers_noise():
    system = crop_growth.system()
    scenario = crop_growth.DEFAULT_SCENARIO
    traj = simulate(system, scenario.x0, 40, w=crop_growth.UnknownInputLaw())
    bound = window_information(system, traj.x, traj.u, traj.w, k=30, N=30, noise_std=3e-6 / np.sqrt(3), mu=0.48)
    assert bound.std_bound[0] < 1e-5  # CO2 is measured
    assert bound.std_bound[1] > 5e-3  # x^{d,1}: about 0.015, most of X's width 0.02
    assert bound.std_discounted[1] > bound.std_bound[1]
