"""WindowProblem: layout, scaling, residuals, bounds, and each backend against linear least squares and IPOPT."""

import numpy as np
import pytest

from uiest import Box, DataError, OptionError
from uiest.models import crop_growth, linear
from uiest.window import (
    IPOPT_DEFAULTS,
    WindowProblem,
    WindowSolution,
    WindowTrajectory,
    WindowWeights,
    make_solver,
    predicted_guess,
    shifted_guess,
    sqrt_psd,
)

A = np.array([[0.9, 0.2], [-0.1, 0.7]])
B = np.array([[1.0], [0.5]])
C = np.array([[1.0, 0.0]])
B_U = np.array([[0.0], [1.0]])


def small_system(**spec):
    spec.setdefault("v_bounds", (-10.0, 10.0))
    return linear.linear_system(A, B, C, B_u=B_U, **spec)


def weights(L, measured, rng, with_w=False):
    def spd(n):
        M = rng.standard_normal((n, n))
        return M @ M.T + 0.5 * np.eye(n)

    return WindowWeights(
        prior=spd(2),
        y=np.array([spd(1) for _ in measured]),
        v=np.array([spd(1) for _ in measured]),
        w=np.array([spd(1) for _ in range(L)]) if with_w else None,
    )


def lstsq_reference(L, measured, W, prior, u, y, v_bar, w_bar):
    """Independent solution by substitution: unknowns (x0, w_0..w_{L-1}, v at measured nodes)."""
    M = len(measured)
    n_theta = 2 + L + M
    # x_i = Phi_i theta + c_i
    Phi = [np.hstack([np.eye(2), np.zeros((2, L + M))])]
    c = [np.zeros(2)]
    for i in range(L):
        step = A @ Phi[-1]
        step[:, 2 + i] += B[:, 0]
        Phi.append(step)
        c.append(A @ c[-1] + B_U @ u[i])
    rows, rhs = [], []
    root = sqrt_psd(W.prior, "prior")
    rows.append(root @ Phi[0])
    rhs.append(root @ (prior - c[0]))
    for m, node in enumerate(measured):
        sel_v = np.zeros((1, n_theta))
        sel_v[0, 2 + L + m] = 1.0
        ry = sqrt_psd(W.y[m], "y")
        rows.append(ry @ (C @ Phi[node] + sel_v))
        rhs.append(ry @ (y[m] - C @ c[node]))
        rv = sqrt_psd(W.v[m], "v")
        rows.append(rv @ sel_v)
        rhs.append(rv @ v_bar[m])
    if W.w is not None:
        for i in range(L):
            sel = np.zeros((1, n_theta))
            sel[0, 2 + i] = 1.0
            rw = sqrt_psd(W.w[i], "w")
            rows.append(rw @ sel)
            rhs.append(rw @ w_bar[i])
    theta, *_ = np.linalg.lstsq(np.vstack(rows), np.concatenate(rhs), rcond=None)
    x = np.array([Phi[i] @ theta + c[i] for i in range(L + 1)])
    return x, theta[2 : 2 + L].reshape(L, 1), theta[2 + L :].reshape(M, 1)


BACKENDS = ["ipopt", "gn", "rti"]


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize(("L", "one_step_ahead", "with_w"), [(0, False, False), (4, False, False), (4, True, True)])
def test_each_backend_solves_a_linear_window_to_its_least_squares_optimum(L, one_step_ahead, with_w, backend):
    """A linear window problem is a least-squares problem: its optimum is known in closed form.

    Gauss-Newton is exact on it; the real-time iteration's one step from zero reaches it too.
    """
    rng = np.random.default_rng(L)
    system = small_system()
    measured = list(range(L)) if one_step_ahead else list(range(L + 1))
    W = weights(L, measured, rng, with_w)
    problem = WindowProblem(system, L, measured, W)
    prior, u = rng.standard_normal(2), rng.standard_normal((L, 1))
    y, v_bar = rng.standard_normal((len(measured), 1)), 0.1 * rng.standard_normal((len(measured), 1))
    w_bar = rng.standard_normal((L, 1))
    p = problem.parameters(prior, u, y, v_bar=v_bar, w_bar=w_bar)
    solution = make_solver(backend, problem).solve(np.zeros(problem.n_var), p)
    assert solution.success, solution.status
    got = problem.unpack(solution.z)
    x, w, v = lstsq_reference(L, measured, W, prior, u, y, v_bar, w_bar)
    np.testing.assert_allclose(got.x, x, atol=1e-7)
    np.testing.assert_allclose(got.w, w, atol=1e-7)
    np.testing.assert_allclose(got.v, v, atol=1e-7)
    # the reported cost is |r|^2 of the residual function
    r = np.asarray(problem.residual_function(solution.z, p)).ravel()
    assert solution.cost == pytest.approx(float(r @ r), rel=1e-9)
    assert problem.n_res == r.size


@pytest.mark.parametrize("backend", ["ipopt", "gn"])
def test_weights_spanning_1e12_are_solved_to_the_least_squares_optimum(backend):
    """A certificate's output weight can be ~1e12 times its prior weight (the crop model's at mu = 0.48).

    Unscaled, IPOPT's step computation broke down on such windows; the NLP's cost is scaled
    (``objective_scale``) without moving the optimum, and the reported cost is still ``|r|^2``.
    """
    rng = np.random.default_rng(7)
    L, measured = 4, list(range(5))
    base = weights(L, measured, rng, with_w=True)
    W = WindowWeights(prior=base.prior, y=1e12 * base.y, v=1e12 * base.v, w=base.w)
    problem = WindowProblem(small_system(), L, measured, W)
    prior, u = rng.standard_normal(2), rng.standard_normal((L, 1))
    y, v_bar, w_bar = rng.standard_normal((5, 1)), 0.1 * rng.standard_normal((5, 1)), rng.standard_normal((L, 1))
    p = problem.parameters(prior, u, y, v_bar=v_bar, w_bar=w_bar)
    assert problem.objective_scale(p) < 1e-5
    solution = make_solver(backend, problem).solve(np.zeros(problem.n_var), p)
    assert solution.success and (backend == "ipopt" or solution.status.startswith("Converged")), solution.status
    x, w, _ = lstsq_reference(L, measured, W, prior, u, y, v_bar, w_bar)
    got = problem.unpack(solution.z)
    np.testing.assert_allclose(got.x, x, atol=1e-7)
    np.testing.assert_allclose(got.w, w, atol=1e-7)
    r = np.asarray(problem.residual_function(solution.z, p)).ravel()
    assert solution.cost == pytest.approx(float(r @ r), rel=1e-6)
    if backend == "ipopt":  # multipliers of |r|^2, whatever scale IPOPT saw: a 1e6 times smaller cost has 1e-6 of them
        smaller = WindowWeights(prior=W.prior / 1e6, y=W.y / 1e6, v=W.v / 1e6, w=W.w / 1e6)
        q = problem.parameters(prior, u, y, v_bar=v_bar, w_bar=w_bar, weights=smaller)
        reference = make_solver(backend, problem).solve(np.zeros(problem.n_var), q)
        assert problem.objective_scale(q) > 1e3 * problem.objective_scale(p)
        np.testing.assert_allclose(
            solution.lam_g, 1e6 * reference.lam_g, rtol=1e-4, atol=1e-6 * np.abs(solution.lam_g).max()
        )


def test_missing_measurement_drops_its_residual():
    rng = np.random.default_rng(3)
    system = small_system()
    L, measured = 3, [0, 1, 2, 3]
    W = weights(L, measured, rng, with_w=True)  # w weighted: without y[2] the window is otherwise not unique
    problem = WindowProblem(system, L, measured, W)
    prior, u, y = rng.standard_normal(2), rng.standard_normal((L, 1)), rng.standard_normal((4, 1))
    y_missing = y.copy()
    y_missing[2] = np.nan
    p = problem.parameters(prior, u, y_missing)
    z = np.linspace(-1.0, 1.0, problem.n_var)
    r_missing = np.asarray(problem.residual_function(z, p)).ravel()
    # the same as giving any value at the missing node with zero output weight
    W_dropped = WindowWeights(prior=W.prior, y=W.y.copy(), v=W.v, w=W.w)
    W_dropped.y[2] = 0.0
    reference = WindowProblem(system, L, measured, W_dropped)
    r_ref = np.asarray(reference.residual_function(z, reference.parameters(prior, u, np.nan_to_num(y_missing)))).ravel()
    np.testing.assert_allclose(r_missing, r_ref, atol=1e-14)
    # and the solution matches least squares without that row
    solution = make_solver("ipopt", problem).solve(np.zeros(problem.n_var), p)
    w_bar = np.zeros((L, 1))
    x, *_ = lstsq_reference(L, measured, W_dropped, prior, u, np.nan_to_num(y_missing), np.zeros((4, 1)), w_bar)
    np.testing.assert_allclose(problem.unpack(solution.z).x, x, atol=1e-7)


def test_layout_scaling_and_round_trip():
    system = crop_growth.system()
    L, measured = 3, [0, 1, 2]
    W = WindowWeights(prior=np.eye(3), y=np.tile(np.eye(2), (3, 1, 1)), v=np.tile(np.eye(2), (3, 1, 1)))
    problem = WindowProblem(system, L, measured, W, w_box=system.w_range)
    # stage-wise layout [x0 v0 w0 x1 v1 w1 x2 v2 w2 x3]
    assert problem.n_var == 4 * 3 + 3 * 2 + 3 * 1
    assert problem.x_index[0].tolist() == [0, 1, 2] and problem.v_index[0].tolist() == [3, 4]
    assert problem.w_index[0].tolist() == [5] and problem.x_index[1].tolist() == [6, 7, 8]
    assert problem.x_index[3].tolist() == [18, 19, 20]
    rng = np.random.default_rng(0)
    traj = WindowTrajectory(
        x=system.x.bounds.sample(rng, 4), w=rng.uniform(0.97, 1.0, (3, 1)), v=rng.uniform(-3e-6, 3e-6, (3, 2))
    )
    z = problem.pack(traj)
    back = problem.unpack(z)
    for name in ("x", "w", "v"):
        np.testing.assert_allclose(getattr(back, name), getattr(traj, name), rtol=1e-12, atol=1e-20)
    # scaled variables are order one: X maps to [-1/2, 1/2] per component
    np.testing.assert_allclose(problem.lbx[problem.x_index[0]], -0.5)
    np.testing.assert_allclose(problem.ubx[problem.x_index[0]], 0.5)
    assert np.all(np.abs(z) <= 0.5 + 1e-12)
    # the dynamics constraints vanish on a model trajectory
    x = [traj.x[0]]
    for i in range(L):
        x.append(system.step(x[-1], [25.0], traj.w[i]))
    on_model = WindowTrajectory(np.array(x), traj.w, traj.v)
    p = problem.parameters(traj.x[0], np.full((L, 1), 25.0), np.zeros((3, 2)))
    g = np.asarray(problem.constraint_function(problem.pack(on_model), p)).ravel()
    assert g.shape == (problem.n_con,) and np.abs(g).max() < 1e-9
    assert "length=3" in repr(problem)


def test_unbounded_unknown_input_and_output_constraints():
    system = small_system(y_bounds=(-1.0, 1.0))
    W = WindowWeights(prior=np.eye(2), y=np.ones((3, 1, 1)), v=np.ones((3, 1, 1)))
    problem = WindowProblem(system, 2, [0, 1, 2], W)
    assert np.all(np.isinf(problem.lbx[problem.w_index])) and np.all(np.isinf(problem.ubx[problem.w_index]))
    assert problem.has_output_constraints and problem.n_con == 2 * 2 + 3
    # a measurement far outside Y: the fitted outputs stay in Y
    p = problem.parameters(np.zeros(2), np.zeros((2, 1)), np.full((3, 1), 5.0))
    solution = make_solver("ipopt", problem).solve(np.zeros(problem.n_var), p)
    traj = problem.unpack(solution.z)
    y_hat = traj.x @ C.T + traj.v
    assert solution.success and np.all(y_hat <= 1.0 + 1e-6)


@pytest.mark.parametrize("backend", ["gn", "rti"])
def test_each_backend_finds_ipopts_optimum_with_active_bounds_and_inequalities(backend):
    """Linear windows whose optimum sits on output constraints or on the state box (a convex QP: one optimum)."""
    bounded = small_system(x_bounds=(-0.5, 0.5))
    W = WindowWeights(prior=1e-6 * np.eye(2), y=np.ones((4, 1, 1)), v=np.ones((4, 1, 1)))
    on_box = WindowProblem(bounded, 3, [0, 1, 2, 3], W)
    y_box = np.array([[0.0], [3.0], [3.0], [3.0]])
    constrained = small_system(y_bounds=(-1.0, 1.0))
    W = WindowWeights(prior=np.eye(2), y=np.ones((3, 1, 1)), v=np.ones((3, 1, 1)))
    on_outputs = WindowProblem(constrained, 2, [0, 1, 2], W)
    for problem, y in ((on_box, y_box), (on_outputs, np.full((3, 1), 5.0))):
        p = problem.parameters(np.zeros(2), np.zeros((problem.length, 1)), y)
        # IPOPT polished: its interior-point iterate ends ~1e-5 inside or outside active bounds
        reference = make_solver("ipopt", problem, polish=True).solve(np.zeros(problem.n_var), p)
        solution = make_solver(backend, problem).solve(np.zeros(problem.n_var), p)
        assert reference.success and solution.success, (reference.status, solution.status)
        assert solution.cost == pytest.approx(reference.cost, rel=1e-8)
        np.testing.assert_allclose(solution.z, reference.z, atol=1e-6)


def test_state_box_is_enforced_at_every_node():
    system = small_system(x_bounds=(-0.5, 0.5))
    W = WindowWeights(prior=1e-6 * np.eye(2), y=np.ones((4, 1, 1)), v=np.ones((4, 1, 1)))
    problem = WindowProblem(system, 3, [0, 1, 2, 3], W)
    p = problem.parameters(np.zeros(2), np.zeros((3, 1)), np.array([[0.0], [3.0], [3.0], [3.0]]))
    solution = make_solver("ipopt", problem).solve(np.zeros(problem.n_var), p)
    x = problem.unpack(solution.z).x
    assert solution.success
    assert x.max() <= 0.5 + 1e-7 and x.min() >= -0.5 - 1e-7
    assert x[1:, 0].max() == pytest.approx(0.5, abs=1e-6)  # the fit pushes x1 onto the bound


def test_bad_arguments():
    system = small_system()
    good = WindowWeights(prior=np.eye(2), y=np.ones((2, 1, 1)), v=np.ones((2, 1, 1)))
    with pytest.raises(OptionError, match="length"):
        WindowProblem(system, -1, [], good)
    with pytest.raises(OptionError, match="measured"):
        WindowProblem(system, 1, [1, 0], good)
    with pytest.raises(OptionError, match=r"weights\.y"):
        WindowProblem(system, 1, [0], good)
    with pytest.raises(OptionError, match="x_box"):
        WindowProblem(system, 1, [0, 1], good, x_box=Box.unbounded(3))
    problem = WindowProblem(system, 1, [0, 1], good)
    with pytest.raises(DataError, match="prior"):
        problem.parameters([np.inf, 0.0], np.zeros((1, 1)), np.zeros((2, 1)))
    with pytest.raises(OptionError, match="solver"):
        make_solver("acados", problem)
    with pytest.raises(OptionError, match="solver_options"):
        make_solver("ipopt", problem, options={"no_such_option": 1})
    assert IPOPT_DEFAULTS["nlp_scaling_method"] == "none"


def test_sqrt_psd():
    M = np.array([[4.0, 1.0], [1.0, 3.0]])
    root = sqrt_psd(M, "M")
    np.testing.assert_allclose(root @ root, M, atol=1e-12)
    np.testing.assert_allclose(root, root.T)
    np.testing.assert_allclose(sqrt_psd(np.diag([4.0, 0.0]), "M"), np.diag([2.0, 0.0]))
    with pytest.raises(OptionError, match="symmetric"):
        sqrt_psd([[1.0, 2.0], [0.0, 1.0]], "M")
    with pytest.raises(OptionError, match="semidefinite"):
        sqrt_psd(np.diag([1.0, -1.0]), "M")
    with pytest.raises(OptionError, match="square"):
        sqrt_psd(np.ones((2, 3)), "M")


def test_sqrt_psd_of_a_stack_is_each_matrix_s_root_and_names_the_bad_one():
    rng = np.random.default_rng(0)
    A = rng.standard_normal((4, 3, 3))
    stack = A @ A.transpose(0, 2, 1)
    roots = sqrt_psd(stack, "W")
    assert roots.shape == (4, 3, 3)
    for matrix, root in zip(stack, roots, strict=True):
        np.testing.assert_allclose(root, sqrt_psd(matrix, "W"), rtol=0, atol=1e-14)
    assert sqrt_psd(np.zeros((0, 2, 2)), "W").shape == (0, 2, 2)
    stack[2] = np.diag([1.0, -1.0, 1.0])
    with pytest.raises(OptionError, match=r"W\[2\]: expected a positive semidefinite"):
        sqrt_psd(stack, "W")
    stack[1, 0, 1] += 1.0
    with pytest.raises(OptionError, match=r"W\[1\]: expected a symmetric"):
        sqrt_psd(stack, "W")


def test_shifted_guess_maps_nodes_by_time_and_predicts_new_ones():
    system = small_system()
    W3 = WindowWeights(prior=np.eye(2), y=np.ones((4, 1, 1)), v=np.ones((4, 1, 1)))
    W4 = WindowWeights(prior=np.eye(2), y=np.ones((5, 1, 1)), v=np.ones((5, 1, 1)))
    old = WindowProblem(system, 3, [0, 1, 2, 3], W3)
    rng = np.random.default_rng(1)
    # a model trajectory over times 0..4
    u = rng.standard_normal((4, 1))
    w = rng.standard_normal((4, 1))
    x = [rng.standard_normal(2)]
    for i in range(4):
        x.append(system.step(x[-1], u[i], w[i]))
    x = np.array(x)
    v = rng.standard_normal((5, 1))
    z_old = old.pack(WindowTrajectory(x[:4], w[:3], v[:4]))
    sol = WindowSolution(
        z_old, np.arange(old.n_var, dtype=float), np.arange(old.n_con, dtype=float), 0.0, "", True, 0, 0
    )
    # sliding: window 1..4 of the same length; the new transition reuses the last w estimate
    z, (lam_x, lam_g) = shifted_guess(old, sol, old, 1, u[1:4], np.zeros(1), np.zeros(1), duals=True)
    from_unpacked = shifted_guess(old, sol, old, 1, u[1:4], np.zeros(1), np.zeros(1), duals=False,
                                  old_trajectory=old.unpack(sol.z))  # fmt: skip
    np.testing.assert_array_equal(from_unpacked[0], z)  # the caller's unpacked solution: the same guess, to the bit
    guess = old.unpack(z)
    np.testing.assert_allclose(guess.x[:3], x[1:4])
    np.testing.assert_allclose(guess.x[3], system.step(x[3], u[3], w[2]))
    np.testing.assert_allclose(guess.w[:2], w[1:3])
    np.testing.assert_allclose(guess.v[:3], v[1:4])
    np.testing.assert_allclose(guess.v[3], 0.0)
    np.testing.assert_array_equal(lam_x[old.x_index[0]], sol.lam_x[old.x_index[1]])
    np.testing.assert_array_equal(lam_x[old.x_index[3]], 0.0)
    np.testing.assert_array_equal(lam_g[:4], sol.lam_g[2:6])  # dynamics rows of transitions 1, 2
    # growing: window 0..4, one node more, same start
    grown = WindowProblem(system, 4, [0, 1, 2, 3, 4], W4)
    z, duals = shifted_guess(old, sol, grown, 0, u, np.zeros(1), np.zeros(1), duals=False)
    assert duals is None
    np.testing.assert_allclose(grown.unpack(z).x[:4], x[:4])
    # no common node: None; a prediction from the prior instead
    assert shifted_guess(old, sol, old, 4, u[:3], np.zeros(1), np.zeros(1), duals=False) is None
    cold = old.unpack(predicted_guess(old, x[0], u[:3], w[0], np.zeros(1)))
    np.testing.assert_allclose(cold.x[1], system.step(x[0], u[0], w[0]))


@pytest.mark.parametrize("model", ["linear", "crop"])
def test_a_windows_data_written_into_another_windows_parameters_are_its_parameters(model):
    rng = np.random.default_rng(5)
    if model == "linear":
        system, L, measured = small_system(), 4, [0, 1, 2, 3, 4]
        W = weights(L, measured, rng, with_w=True)
    else:
        system, L, measured = crop_growth.system(), 3, [1, 2, 3]
        W = WindowWeights(prior=np.eye(3), y=np.tile(np.eye(2), (3, 1, 1)), v=np.tile(np.eye(2), (3, 1, 1)))
    problem = WindowProblem(system, L, measured, W, w_box=system.w_range if model == "crop" else None)
    v_bar = rng.uniform(-1e-3, 1e-3, (len(measured), system.nv))
    w_bar = rng.uniform(0.5, 1.0, (L, system.nw))

    def data():
        y = rng.uniform(1.0, 2.0, (len(measured), system.ny))
        y[rng.random(y.shape) < 0.3] = np.nan  # missing entries: 0 with mask 0
        return rng.uniform(0.1, 1.0, system.nx), rng.uniform(0.0, 30.0, (L, system.nu)), y

    base = problem.parameters(*data(), v_bar=v_bar, w_bar=w_bar)
    for _ in range(3):
        prior, u, y = data()
        expected = problem.parameters(prior, u, y, v_bar=v_bar, w_bar=w_bar)
        np.testing.assert_array_equal(problem.with_data(base, prior, u, y), expected)
    bad_prior = prior.copy()
    bad_prior[0] = np.inf
    with pytest.raises(DataError, match="prior: expected finite window data"):
        problem.with_data(base, bad_prior, u, y)


def test_ipopt_backtracking_from_where_the_model_is_not_finite_prints_nothing(capfd):
    # sqrt(x2 + 1) is NaN on part of X: IPOPT backtracks from such trial points, and CasADi printed one warning per
    # evaluation (thousands in a study); the solve's status says how it ended
    from uiest import System, simulate
    from uiest.estimators import UISE, UISEWeights

    system = System.from_callables(
        lambda x, u, w: [0.9 * x[0] + 0.2 * np.sqrt(x[1] + 1.0) + w[0], 0.95 * x[1] + 0.05 * np.exp(-x[0])],
        lambda x, v: [x[0] + v[0]], nx=2, nw=1, nv=1, x_bounds=(-5.0, 5.0), v_bounds=(-0.01, 0.01),
    )  # fmt: skip
    truth = simulate(system, [0.5, 1.0], 40, w=lambda k, x: [0.3 * np.sin(0.2 * k)], v=np.zeros((41, 1)))
    estimator = UISE(system, weights=UISEWeights.from_scales(system, 0.8, output=1.0), N=6, x0_prior=[0.0, -3.0],
                     solver="ipopt")  # fmt: skip
    estimator.run(truth.u, truth.y)
    assert "NaN detected" not in capfd.readouterr().err
