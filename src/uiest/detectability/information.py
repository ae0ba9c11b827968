r"""How much the data of one window can tell about the state: a Cramer-Rao-type bound.

For the window ending at k (``N`` transitions) the unknowns are ``theta = (x_{k-N}, w_{k-N..k-1})``
(the unknown input is a free nuisance parameter, as in the UISE) and the data are
``y_{k-N..k} = h(x_j(theta), v_j)`` with independent noise of covariance ``Sigma = diag(sigma^2)``
per sample. With ``J = dy/dtheta`` at the true trajectory, the Fisher information is
``F = J^T Sigma^-1 J`` and any unbiased estimator of the window's end state has covariance at
least ``G F^+ G^T`` with ``G = dx_k/dtheta`` (pseudo-inverse: directions the data cannot see
at all have infinite variance and show up as NaN-free but huge values only if F is singular in
them; ``rank_deficient`` flags it). A weighted least-squares estimator with the weights
``W = diag(mu^(j) R)`` of a discounted cost has the sandwich covariance
``G (J^T W J)^+ J^T W Sigma W J (J^T W J)^+ G^T`` (>= the bound). Their square-rooted diagonals are
the smallest state differences the window can resolve at one standard deviation.

This ignores priors and constraints (which add information the data do not carry, for example
the bounds of X) and linearises along the true trajectory.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike

from uiest.box import FloatArray
from uiest.checks import check_real, real_array, shown
from uiest.errors import DataError, OptionError
from uiest.system import System

__all__ = ["InformationBound", "window_information"]


@dataclass(frozen=True, kw_only=True)
class InformationBound:
    """Resolution of the window ending at ``k`` (see the module docstring).

    Attributes
    ----------
    k : int
        End of the window.
    N : int
        Transitions in the window.
    std_bound : ndarray (nx,)
        ``sqrt(diag(G F^+ G^T))``: Cramer-Rao standard deviation of each end-state component.
    std_discounted : ndarray (nx,)
        The same for the weighted least-squares estimator with discount ``mu`` (NaN without mu).
    rank_deficient : bool
        Whether F is singular in a direction that reaches the end state (then the bound there is
        not finite: the data cannot resolve it at all).

    """

    k: int
    N: int
    std_bound: FloatArray
    std_discounted: FloatArray
    rank_deficient: bool


def window_information(
    system: System,
    x: ArrayLike,
    u: ArrayLike | None,
    w: ArrayLike,
    *,
    k: int,
    N: int,
    noise_std: ArrayLike,
    mu: float | None = None,
) -> InformationBound:
    """The information bound of the window ``k-N .. k`` of a trajectory.

    Parameters
    ----------
    system : System
    x : array_like (K+1, nx)
        The true states (time-first); only ``x[k-N]`` and the inputs are used, the rest is simulated.
    u : array_like (K, nu) or None
        Known inputs.
    w : array_like (K, nw)
        The true unknown inputs.
    k, N : int
        Window end and number of transitions (``N <= k``).
    noise_std : array_like (ny,) or float
        Standard deviation of each output's noise (uniform noise in ``[-b, b]``: ``b / sqrt(3)``).
    mu : float, optional
        Discount of the estimator's output weights ``mu^(j)`` (j = distance from the window end).

    """
    if not isinstance(system, System):
        raise OptionError(f"system: expected a uiest.System, got {shown(system)}")
    x = real_array(x, "x", f"the true states, an array of shape (K+1, {system.nx}) (a Trajectory's .x)")
    w = real_array(w, "w", f"the true unknown inputs, an array of shape (K, {system.nw})")
    if w.ndim == 1 and system.nw == 1:
        w = w.reshape(-1, 1)
    if w.ndim != 2 or w.shape[1] != system.nw:
        raise DataError(f"w: expected shape (K, {system.nw}), got {w.shape}")
    if u is None or system.nu == 0:
        u_arr = np.zeros((w.shape[0], system.nu))
    else:
        u_arr = real_array(u, "u", f"the known inputs, an array of shape ({w.shape[0]}, {system.nu})")
        if u_arr.shape != (w.shape[0], system.nu):
            raise DataError(f"u: expected shape ({w.shape[0]}, {system.nu}) (as many rows as w), got {u_arr.shape}")
    if isinstance(N, bool) or not isinstance(N, int) or N < 1 or not isinstance(k, int) or not N <= k <= w.shape[0]:
        raise OptionError(f"k, N: expected integers with 1 <= N <= k <= {w.shape[0]}, got k={k!r}, N={N!r}")
    if x.ndim != 2 or x.shape[1] != system.nx or x.shape[0] <= k:
        raise DataError(f"x: expected shape (>= {k + 1}, {system.nx}), got {x.shape}")
    sigma = real_array(noise_std, "noise_std", f"a positive number or {system.ny} of them", error=OptionError)
    if sigma.shape not in ((), (1,), (system.ny,)):
        raise OptionError(f"noise_std: expected a positive number or {system.ny} of them, got shape {sigma.shape}")
    sigma = np.broadcast_to(sigma, (system.ny,))
    if not np.all(np.isfinite(sigma) & (sigma > 0)):
        raise OptionError(f"noise_std: expected positive finite values, got {sigma.tolist()}")
    if mu is not None and not 0.0 < check_real(mu, "mu", "a number in (0, 1]") <= 1.0:
        raise OptionError(f"mu: expected a number in (0, 1], got {mu!r}")
    start = k - N
    x0 = ca.SX.sym("x0", system.nx)
    ws = ca.SX.sym("w", system.nw * N)
    theta = ca.vertcat(x0, ws)
    v0 = system.v.bounds.center if system.v.bounds.is_bounded else np.zeros(system.nv)
    state, outputs = x0, []
    for j in range(N + 1):
        outputs.append(system.h(state, ca.DM(v0)))
        if j < N:
            state = system.f(state, ca.DM(u_arr[start + j]), ws[j * system.nw : (j + 1) * system.nw])
    y = ca.vertcat(*outputs)
    fun = ca.Function("window", [theta], [ca.jacobian(y, theta), ca.jacobian(state, theta)])
    J, G = (np.asarray(m, dtype=float) for m in fun(np.concatenate([x[start], w[start:k].ravel()])))
    # scale theta to order one before inverting
    scale = np.concatenate([system.x.scale, np.tile(system.w.scale, N)])
    J, G = J * scale, G * scale
    inv_sigma = np.tile(1.0 / sigma**2, N + 1)
    F = J.T @ (inv_sigma[:, None] * J)
    F_pinv = np.linalg.pinv(F, rcond=1e-13, hermitian=True)
    bound = G @ F_pinv @ G.T
    # directions of the end state in F's (numerical) null space
    eig, vec = np.linalg.eigh(F)
    null = vec[:, eig <= 1e-13 * max(eig.max(), 1e-300)]
    rank_deficient = bool(null.size and np.abs(G @ null).max() > 1e-9 * max(np.abs(G).max(), 1e-300))
    discounted = np.full(system.nx, np.nan)
    if mu is not None:
        weights = np.repeat(mu ** np.arange(N, -1, -1, dtype=float), system.ny) * inv_sigma
        A = J.T @ (weights[:, None] * J)
        A_pinv = np.linalg.pinv(A, rcond=1e-13, hermitian=True)
        middle = J.T @ ((weights**2 / inv_sigma)[:, None] * J)
        discounted = np.sqrt(np.clip(np.diag(G @ A_pinv @ middle @ A_pinv @ G.T), 0.0, None))
    return InformationBound(
        k=k,
        N=N,
        std_bound=np.sqrt(np.clip(np.diag(bound), 0.0, None)),
        std_discounted=discounted,
        rank_deficient=rank_deficient,
    )
