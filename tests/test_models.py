import numpy as np
import pytest
import scipy.linalg

from uiest import OptionError, simulate
from uiest.models import BUILT_IN, closed_form, get, linear, names


def rosenbrock_zeros(A, B, C):
    """Finite generalised eigenvalues of the square Rosenbrock pencil [zI - A, -B; C, 0]."""
    n, m = B.shape
    M = np.block([[A, B], [-C, np.zeros((C.shape[0], m))]])
    N = np.block([[np.eye(n), np.zeros((n, m))], [np.zeros((C.shape[0], n + m))]])
    vals = scipy.linalg.eigvals(M, N)
    return np.sort_complex(vals[np.isfinite(vals)])


@pytest.mark.parametrize("zeros", [[0.5, 0.2], [0.3 + 0.4j, 0.3 - 0.4j, -0.7], [1.5]])
def test_with_invariant_zeros_places_the_zeros(zeros):
    _, A, B, C = linear.with_invariant_zeros(zeros, seed=3)
    np.testing.assert_allclose(rosenbrock_zeros(A, B, C), np.sort_complex(np.array(zeros, dtype=complex)), atol=1e-9)
    assert np.linalg.matrix_rank(C @ B) == np.linalg.matrix_rank(B)


def test_non_square_variant_keeps_rank_and_shape():
    system, _, B, C = linear.with_invariant_zeros([0.4, 0.1], nw=2, extra_outputs=1, seed=0)
    assert C.shape == (3, 4) and B.shape == (4, 2)
    assert np.linalg.matrix_rank(C @ B) == 2
    assert (system.nx, system.nw, system.ny) == (4, 2, 3)


def test_linear_system_evaluates_the_matrices():
    A, B, C, Bu = np.diag([0.5, 0.2]), np.array([[1.0], [0.0]]), np.array([[1.0, 1.0]]), np.array([[0.0], [2.0]])
    system = linear.linear_system(A, B, C, B_u=Bu)
    np.testing.assert_allclose(system.step([1.0, 1.0], [1.0], [3.0]), [3.5, 2.2])
    np.testing.assert_allclose(system.output([1.0, 2.0], [0.5]), [3.5])


def test_closed_form_error_matches_model_propagation():
    # Propagate x2 from a wrong prior with the true x1 (what a UISE does noise-free) and compare
    # with the closed form e2_k = prod_{j<k} a(x1_j) e2_0, under a large, growing unknown input.
    system = closed_form.system(x_bounds=(-np.inf, np.inf))
    steps = 60
    traj = simulate(system, [0.5, 2.0], steps, u=np.full((steps, 1), 0.3), w=lambda k, x: [50.0 * k * np.cos(k)])
    x2_hat = np.empty(steps + 1)
    x2_hat[0] = 2.0 - 1.5
    for k in range(steps):
        x2_hat[k + 1] = system.step([traj.x[k, 0], x2_hat[k]], traj.u[k], [0.0])[1]
    e2 = traj.x[:, 1] - x2_hat
    np.testing.assert_allclose(
        e2, closed_form.noise_free_error(traj.x[:, 0], 1.5), rtol=1e-9, atol=1e-14
    )  # cancellation in x2 - x2_hat
    assert np.abs(traj.w).max() > 1e3


def test_registry():
    assert {"crop-growth", "closed-form", "linear-example"} <= set(names())
    with pytest.raises(OptionError, match="unknown name 'nope'"):
        get("nope")
    for name in sorted(BUILT_IN):  # other tests register models of their own in this process
        entry = get(name)
        system, setup = entry.build(), entry.setup()
        traj = simulate(system, setup.x0, 20, u=setup.u, w=setup.w, v=setup.noise, seed=0)
        assert system.x.bounds.contains(traj.x).all()
