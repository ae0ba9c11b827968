"""Initial guesses for window solves: model predictions and the previous solution shifted in time.

A window problem's node ``i`` is time ``start + i``. Shifting a solution from a window that
started at ``old_start`` to one that starts ``d = start - old_start >= 0`` steps later copies every
state node, transition and noise estimate both windows hold (and their multipliers, for
primal-dual warm starts) and predicts the new nodes with the model. This covers the sliding
window (same length, ``d = 1``), the growing one (length + 1, ``d = 0``) and gaps after a failed
solve (the last successful solution is older). Models with node data (the two-stage UISE's
reduced model) need the window's ``data (L+1, nd)`` to predict.
"""

from __future__ import annotations

import numpy as np

from uiest.box import FloatArray
from uiest.checks import all_finite
from uiest.window.problem import WindowProblem, WindowTrajectory
from uiest.window.solvers import WindowSolution

__all__ = ["predicted_guess", "shifted_guess"]


def _node_data(problem: WindowProblem, data: FloatArray | None) -> FloatArray:
    if data is None:
        return np.zeros((problem.length + 1, problem.model.nd))
    return np.asarray(data, dtype=float).reshape(problem.length + 1, problem.model.nd)


def predict_states(
    problem: WindowProblem,
    x: FloatArray,
    w: FloatArray,
    u: FloatArray,
    first: int,
    v: FloatArray | None = None,
    data: FloatArray | None = None,
) -> None:
    """Fill ``x[first+1:]`` in place by ``x[i+1] = f(x[i], u[i], w[i], v_i, d_i)``, clipped into the state box.

    ``v`` holds the noise estimates of the measured nodes (M, nv) (default: the box centre);
    ``data`` the node data (L+1, nd).
    """
    model, box, L = problem.model, problem.x_box, problem.length
    d = _node_data(problem, data)
    v_rows = problem.measured_row  # node -> its row of v, -1 where not measured (the box centre)
    v_arr = np.asarray(v, dtype=float).reshape(problem.n_meas, model.nv) if v is not None and problem.n_meas else None
    for i in range(first, L):
        v_i = v_arr[v_rows[i]] if v_arr is not None and v_rows[i] >= 0 else problem.v_center
        nxt = model.step(x[i], u[i], w[i], v_i, d[i])
        x[i + 1] = box.clip(nxt) if all_finite(nxt) else x[i]


def predicted_guess(
    problem: WindowProblem,
    prior: FloatArray,
    u: FloatArray,
    w_guess: FloatArray,
    v_guess: FloatArray,
    data: FloatArray | None = None,
) -> FloatArray:
    """Scaled guess from the prior simulated forward with a constant ``w_guess`` (clipped to the w box)."""
    L = problem.length
    x = np.empty((L + 1, problem.model.nx))
    x[0] = problem.x_box.clip(prior)
    w = problem.w_box.clip(np.tile(w_guess, (L, 1)))
    v = np.tile(v_guess, (problem.n_meas, 1))
    predict_states(problem, x, w, u, 0, v, data)
    return problem.pack(WindowTrajectory(x, w, v))


def shifted_guess(
    old_problem: WindowProblem,
    old_solution: WindowSolution,
    problem: WindowProblem,
    shift: int,
    u: FloatArray,
    w_fill: FloatArray,
    v_fill: FloatArray,
    *,
    duals: bool,
    data: FloatArray | None = None,
    old_trajectory: WindowTrajectory | None = None,
) -> tuple[FloatArray, tuple[FloatArray, FloatArray] | None] | None:
    """The old solution moved ``shift`` steps forward onto ``problem``; None when the windows share no node.

    Parameters
    ----------
    old_problem, old_solution
        The previous window and its (successful) solution.
    problem : WindowProblem
        The new window; its last node must be later than the old window's last node.
    shift : int
        ``start - old_start``.
    u : ndarray (L, nu)
        The new window's known inputs (to predict the new nodes).
    w_fill, v_fill : ndarray
        Values for transitions and noise estimates the old window does not hold (the unknown
        input's fill is replaced by the old window's last estimate when it has one).
    duals : bool
        Also shift the multipliers (new entries 0).
    data : ndarray (L+1, nd), optional
        The new window's node data (models with node data).
    old_trajectory : WindowTrajectory, optional
        ``old_problem.unpack(old_solution.z)`` where the caller has it.

    Returns
    -------
    (z0, (lam_x0, lam_g0) or None) or None

    """
    L, M = problem.length, problem.n_meas
    n_x = min(old_problem.length + 1 - shift, L + 1)  # state nodes both windows hold
    if shift < 0 or n_x < 1:
        return None
    old = old_problem.unpack(old_solution.z) if old_trajectory is None else old_trajectory
    n_w = min(n_x - 1, L)
    n_v = min(max(old_problem.n_meas - shift, 0), M)
    x = np.empty((L + 1, problem.model.nx))
    x[:n_x] = old.x[shift : shift + n_x]
    w = np.empty((L, problem.model.nw))
    w[:] = old.w[-1] if old_problem.length else w_fill
    w[:n_w] = old.w[shift : shift + n_w]
    v = np.empty((M, problem.model.nv))
    v[:] = v_fill
    v[:n_v] = old.v[shift : shift + n_v]
    predict_states(problem, x, w, u, n_x - 1, v, data)
    z0 = problem.pack(WindowTrajectory(x, w, v))
    if not duals:
        return z0, None
    lam_x = np.zeros(problem.n_var)
    for new_index, old_index, count in (
        (problem.x_index, old_problem.x_index, n_x),
        (problem.w_index, old_problem.w_index, n_w),
        (problem.v_index, old_problem.v_index, n_v),
    ):
        if count:
            lam_x[new_index[:count]] = old_solution.lam_x[old_index[shift : shift + count]]
    nx, ny = problem.model.nx, problem.model.ny
    lam_g = np.zeros(problem.n_con)
    old_dyn = old_solution.lam_g[: old_problem.n_dyn].reshape(old_problem.length, nx)
    lam_g[: n_w * nx] = old_dyn[shift : shift + n_w].ravel()
    if problem.has_output_constraints and old_problem.has_output_constraints and n_v:
        old_out = old_solution.lam_g[old_problem.n_dyn : old_problem.n_dyn + old_problem.n_out_con]
        old_out = old_out.reshape(old_problem.n_meas, ny)
        lam_g[problem.n_dyn : problem.n_dyn + n_v * ny] = old_out[shift : shift + n_v].ravel()
    nc = problem.node_rows.size
    if nc and np.array_equal(problem.node_rows, old_problem.node_rows) and n_v:
        old_node = old_solution.lam_g[old_problem.n_dyn + old_problem.n_out_con :].reshape(old_problem.n_meas, nc)
        start = problem.n_dyn + problem.n_out_con
        lam_g[start : start + n_v * nc] = old_node[shift : shift + n_v].ravel()
    return z0, (lam_x, lam_g)
