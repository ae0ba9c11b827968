r"""The spread of a window problem's curvature: the extreme eigenvalues of its reduced Gauss-Newton Hessian.

A window problem (:class:`~uiest.window.WindowProblem`, scaled variables ``z``) minimises ``|r(z)|^2``
subject to the dynamics ``x_{i+1} = f(x_i, u_i, w_i, v_i)``. Eliminating the dynamics leaves the free
variables ``theta = (x_0, w_0..w_{L-1}, v)``; with ``Z = dz/dtheta`` (identity on theta, the dynamics'
sensitivities on ``x_1..x_L``) the reduced Gauss-Newton Hessian is ``H = (J Z)^T (J Z)``, ``J = dr/dz``.
Its smallest eigenvalue over its largest says how much of the cost's curvature the least determined
direction carries: below the double-precision rounding unit (``eps = 2.2e-16``) that direction is lost
in rounding when the solver forms and factorises the curvature, and the problem's optimum along it is
not resolved.

The discount makes ``H`` graded (the terms of a node ``a`` steps older carry ``rate^a`` of the weight),
so its smallest eigenvalue can lie far below ``eps`` times its largest. It is computed accurately from
the equilibrated matrix ``A = D^-1 H D^-1`` (``D = sqrt(diag H)``): ``lambda_min(H) = 1 / lambda_max(D^-1
A^-1 D^-1)``, which has a small relative error while ``A`` is well conditioned (``A``'s condition number is
returned so that the caller can tell).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from uiest.box import FloatArray
from uiest.window.problem import WindowProblem

__all__ = ["CurvatureRange", "curvature_range"]


@dataclass(frozen=True, kw_only=True)
class CurvatureRange:
    """Extreme eigenvalues of a window problem's reduced Gauss-Newton Hessian at one point (module docstring).

    Attributes
    ----------
    smallest, largest : float
        ``lambda_min(H)``, ``lambda_max(H)`` (scaled units; ``smallest`` is 0 where a free variable
        carries no curvature at all).
    equilibrated_condition : float
        Condition number of ``A = D^-1 H D^-1``; ``smallest`` has a relative error of about
        ``eps`` times it (inf: ``smallest`` is not resolved).

    """

    smallest: float
    largest: float
    equilibrated_condition: float

    @property
    def ratio(self) -> float:
        """``smallest / largest`` (0 when the Hessian vanishes)."""
        return self.smallest / self.largest if self.largest > 0.0 else 0.0


def reduced_jacobian(problem: WindowProblem, z: FloatArray, p: FloatArray) -> FloatArray:
    """``J Z`` (n_res, n_theta): the residuals' Jacobian with the dynamics eliminated (module docstring).

    Columns in the order ``x_0`` (nx), ``w_0..w_{L-1}`` (L nw), the measured nodes' ``v`` (M nv).
    """
    _, J, _, G = (np.asarray(m, dtype=float) for m in problem.gauss_newton_function(z, p))
    free = np.concatenate([problem.x_index[0], problem.w_index.ravel(), problem.v_index.ravel()]).astype(int)
    dependent = problem.x_index[1:].ravel().astype(int)
    Z = np.zeros((problem.n_var, free.size))
    Z[free, np.arange(free.size)] = 1.0
    if dependent.size:
        dyn = G[: problem.n_dyn]
        Z[dependent] = np.linalg.solve(dyn[:, dependent], -dyn[:, free])
    reduced: FloatArray = J @ Z
    return reduced


def curvature_range(problem: WindowProblem, z: ArrayLike, p: ArrayLike) -> CurvatureRange:
    """The extreme eigenvalues of the reduced Gauss-Newton Hessian of ``problem`` at ``z`` with parameters ``p``.

    Parameters
    ----------
    problem : WindowProblem
    z : array_like (n_var,)
        Scaled variables (:meth:`WindowProblem.pack`).
    p : array_like (n_par,)
        Parameters (:meth:`WindowProblem.parameters`).

    Returns
    -------
    CurvatureRange

    """
    Jr = reduced_jacobian(problem, np.asarray(z, dtype=float), np.asarray(p, dtype=float))
    H = Jr.T @ Jr
    largest = float(np.linalg.eigvalsh(H)[-1]) if H.size else 0.0
    d = np.sqrt(np.diag(H))
    if not H.size or largest <= 0.0 or np.any(d == 0.0):
        return CurvatureRange(smallest=0.0, largest=largest, equilibrated_condition=float("inf"))
    A = H / np.outer(d, d)
    eig_A = np.linalg.eigvalsh(A)
    if eig_A[0] <= 0.0:
        return CurvatureRange(smallest=0.0, largest=largest, equilibrated_condition=float("inf"))
    A_inv = np.linalg.inv(A)
    H_inv = A_inv / np.outer(d, d)
    smallest = 1.0 / float(np.linalg.eigvalsh(0.5 * (H_inv + H_inv.T))[-1])
    return CurvatureRange(smallest=smallest, largest=largest, equilibrated_condition=float(eig_A[-1] / eig_A[0]))
