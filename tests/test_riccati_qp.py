"""The stage-wise interior point (uiest.window.riccati_qp) against a dense reference (cvxpy + Clarabel)."""

from __future__ import annotations

import cvxpy as cp
import numpy as np
import pytest

from uiest.errors import OptionError
from uiest.window.riccati_qp import QPStatus, StageLayout, solve_stage_qp


def _blocks(layout, H, A, C):
    """Dense H (n, n), the dynamics as E z + b = 0 (E: (N nx, n)) and C (n_con, n)."""
    n, nx = layout.n_var, layout.nx
    zo, ho, ao, co, cro = layout.z_offset, layout.h_offset, layout.a_offset, layout.c_offset, layout.con_offset
    Hd = np.zeros((n, n))
    E = np.zeros((layout.n_dyn, n))
    Cd = np.zeros((layout.n_con, n))
    for k, nk in enumerate(layout.stage_sizes):
        Hd[zo[k] : zo[k + 1], zo[k] : zo[k + 1]] = H[ho[k] : ho[k + 1]].reshape(nk, nk)
        if k < layout.n_stages - 1:
            E[k * nx : (k + 1) * nx, zo[k] : zo[k + 1]] = A[ao[k] : ao[k + 1]].reshape(nx, nk)
            E[k * nx : (k + 1) * nx, zo[k + 1] : zo[k + 1] + nx] -= np.eye(nx)
        nc = layout.constraint_sizes[k]
        Cd[cro[k] : cro[k + 1], zo[k] : zo[k + 1]] = C[co[k] : co[k + 1]].reshape(nc, nk)
    return Hd, E, Cd


def _random_qp(seed, nx=2, nus=(1, 2, 0, 1, 1), ncs=None, rank_deficit=0, box=1.0):
    """A random stage QP with PSD stage Hessians (rank deficient by ``rank_deficit`` per stage)."""
    rng = np.random.default_rng(seed)
    sizes = [nx + nu for nu in nus]
    layout = StageLayout(nx, sizes, ncs)
    H = []
    for nk in sizes:
        B = rng.standard_normal((max(nk - rank_deficit, 0) + (0 if rank_deficit else 1), nk))
        H.append((B.T @ B).ravel())
    H = np.concatenate(H)
    q = rng.standard_normal(layout.n_var)
    A = 0.7 * rng.standard_normal(int(layout.a_offset[-1]))
    b = 0.3 * rng.standard_normal(layout.n_dyn)
    lb = -box * (0.2 + rng.random(layout.n_var))
    ub = box * (0.2 + rng.random(layout.n_var))
    C = rng.standard_normal(int(layout.c_offset[-1]))
    lc = -0.3 - rng.random(layout.n_con)
    uc = 0.3 + rng.random(layout.n_con)
    return layout, H, q, A, b, lb, ub, C, lc, uc


def _reference(layout, H, q, A, b, lb, ub, C, lc, uc, regularisation=0.0):
    Hd, E, Cd = _blocks(layout, H, A, C)
    Hd = Hd + regularisation * np.eye(layout.n_var)
    z = cp.Variable(layout.n_var)
    lower, upper = z >= lb, z <= ub
    cons = [lower, upper]
    if layout.n_dyn:
        dyn = E @ z + b == 0
        cons.append(dyn)
    if layout.n_con:
        cl, cu = Cd @ z >= lc, Cd @ z <= uc
        cons += [cl, cu]
    problem = cp.Problem(cp.Minimize(0.5 * cp.quad_form(z, cp.psd_wrap(Hd)) + q @ z), cons)
    problem.solve(solver=cp.CLARABEL, tol_gap_abs=1e-12, tol_gap_rel=1e-12, tol_feas=1e-12)
    assert problem.status == cp.OPTIMAL
    lam_x = upper.dual_value - lower.dual_value
    lam_c = cu.dual_value - cl.dual_value if layout.n_con else np.zeros(0)
    return z.value, problem.value, lam_x, lam_c


def _check_kkt(layout, H, q, A, C, sol, regularisation=0.0):
    """Stationarity with the returned multipliers: (H + reg I) z + q + E^T lam_dyn + lam_x + C^T lam_c = 0."""
    Hd, E, Cd = _blocks(layout, H, A, C)
    grad = (Hd + regularisation * np.eye(layout.n_var)) @ sol.z + q
    grad += E.T @ sol.lam_dyn.ravel() + sol.lam_x + Cd.T @ sol.lam_c
    assert np.abs(grad).max() <= 1e-8 * (1 + np.abs(q).max())


@pytest.mark.parametrize("seed", range(6))
def test_random_stage_qps_match_the_dense_reference(seed):
    qp = _random_qp(seed, ncs=[1, 0, 2, 0, 1] if seed % 2 else None)
    sol = solve_stage_qp(*qp)
    assert sol.status is QPStatus.SOLVED
    z, cost, lam_x, lam_c = _reference(*qp)
    assert np.abs(sol.z - z).max() <= 1e-6
    assert abs(sol.cost - cost) <= 1e-8 * (1 + abs(cost))
    assert np.abs(sol.lam_x - lam_x).max() <= 1e-6
    assert np.abs(sol.lam_c - lam_c).max(initial=0.0) <= 1e-6
    _check_kkt(*qp[:4], qp[7], sol)
    active = np.abs(lam_x) > 1e-6
    assert active.any()  # the random boxes are tight enough to bind


def test_wide_boxes_give_the_unconstrained_optimum():
    layout, H, q, A, b, _, _, C, _, _ = _random_qp(11)
    n = layout.n_var
    sol = solve_stage_qp(layout, H, q, A, b, np.full(n, -np.inf), np.full(n, np.inf))
    Hd, E, _ = _blocks(layout, H, A, C)
    kkt = np.block([[Hd, E.T], [E, np.zeros((E.shape[0], E.shape[0]))]])
    exact = np.linalg.solve(kkt, np.concatenate([-q, -b]))
    assert sol.status is QPStatus.SOLVED
    assert np.abs(sol.z - exact[:n]).max() <= 1e-9
    assert np.abs(sol.lam_dyn.ravel() - exact[n:]).max() <= 1e-8
    assert np.all(sol.lam_x == 0.0)


def test_a_variable_exactly_on_its_bound_with_zero_multiplier():
    # one stage, no dynamics: min 1/2 |z|^2 - q^T z with the unconstrained optimum z = q on the box's side
    layout = StageLayout(2, [3])
    H = np.eye(3).ravel()
    q = -np.array([1.0, 0.5, -2.0])
    lb, ub = np.array([-1.0, -1.0, -1.0]), np.array([1.0, 1.0, 1.0])
    sol = solve_stage_qp(layout, H, q, np.zeros(0), np.zeros(0), lb, ub)
    assert sol.status is QPStatus.SOLVED
    assert np.allclose(sol.z, [1.0, 0.5, -1.0], atol=1e-8)
    assert np.allclose(sol.lam_x, [0.0, 0.0, -1.0], atol=1e-7)


def test_a_flat_direction_is_singular_and_solved_with_regularisation():
    qp = _random_qp(3, nus=(1, 1, 1), rank_deficit=2)
    layout, H, q, A, b, *_, C, _, _ = qp
    free = solve_stage_qp(layout, H, q, A, b, np.full(layout.n_var, -np.inf), np.full(layout.n_var, np.inf))
    assert free.status in (QPStatus.SINGULAR, QPStatus.DIVERGED)
    regularised = solve_stage_qp(*qp, regularisation=1e-3)
    assert regularised.status is QPStatus.SOLVED
    z, cost, lam_x, _ = _reference(*qp, regularisation=1e-3)
    assert np.abs(regularised.z - z).max() <= 1e-6
    assert np.abs(regularised.lam_x - lam_x).max() <= 1e-6
    assert abs(regularised.cost - cost) <= 1e-8 * (1 + abs(cost))
    _check_kkt(*qp[:4], C, regularised, regularisation=1e-3)
    boxed = solve_stage_qp(*qp)  # the boxes alone bound the flat directions
    assert boxed.status is QPStatus.SOLVED
    assert boxed.cost == pytest.approx(_reference(*qp)[1], abs=1e-7)


def test_infeasible_and_ill_posed_qps_report_a_status():
    layout, H, q, A, b, lb, ub, *_ = _random_qp(5)
    crossed = ub.copy()
    crossed[2] = lb[2] - 1.0
    assert solve_stage_qp(layout, H, q, A, b, lb, crossed).status is QPStatus.CROSSED_BOUNDS
    # the dynamics push x_1 far outside its box: infeasible
    far = b.copy()
    far[:2] = 1e3
    infeasible = solve_stage_qp(layout, H, q, A * 0.0, far, lb, ub)
    assert infeasible.status in (QPStatus.DIVERGED, QPStatus.ITERATION_LIMIT)
    nan_q = q.copy()
    nan_q[0] = np.nan
    assert solve_stage_qp(layout, H, nan_q, A, b, lb, ub).status is QPStatus.NOT_FINITE


def test_wrong_sizes_raise_option_errors():
    layout, H, q, A, b, lb, ub, *_ = _random_qp(0)
    with pytest.raises(OptionError, match="q: expected"):
        solve_stage_qp(layout, H, q[:-1], A, b, lb, ub)
    with pytest.raises(OptionError, match="stage_sizes"):
        StageLayout(3, [2, 4])
    with pytest.raises(OptionError, match="regularisation"):
        solve_stage_qp(layout, H, q, A, b, lb, ub, regularisation=-1.0)


@pytest.mark.parametrize("seed", range(4))
def test_an_interior_iterate_reports_multipliers_only_on_its_active_set_estimate(seed):
    """Stopped before its crossover, the iterate's multipliers are its guess for the next QP: signs = active set."""
    layout, H, q, A, b, lb, ub, C, lc, uc = _random_qp(seed, nx=3, nus=(2,) * 12 + (1,), ncs=(1, 0) * 6 + (1,))
    stopped = solve_stage_qp(layout, H, q, A, b, lb, ub, C, lc, uc, max_iter=3)
    assert stopped.status is QPStatus.ITERATION_LIMIT and not stopped.exact_active_set
    lam = np.concatenate((stopped.lam_x, stopped.lam_c))
    assert np.array_equal(np.sign(lam), stopped.active_set)  # zero off the estimate, the estimate's side on it
    assert 0 < np.count_nonzero(stopped.active_set) < lam.size
    solved = solve_stage_qp(layout, H, q, A, b, lb, ub, C, lc, uc, guess=stopped.active_set)
    cold = solve_stage_qp(layout, H, q, A, b, lb, ub, C, lc, uc)
    assert solved.solved and cold.solved and abs(solved.cost - cold.cost) <= 1e-9 * (1.0 + abs(cold.cost))
