r"""Unknown-input reconstruction from two consecutive state estimates.

:class:`InputFit` returns the ``w`` that best explains ``x_hat[k]`` from ``x_hat[k-1]``::

    w_hat[k-1] = argmin_w | S_x^-1 ( f(x_hat[k-1], u[k-1], w) - x_hat[k] ) |^2

(``S_x = diag(system.x.scale)``) by Gauss-Newton from a guess (the previous estimate): one
step when f is affine in w (detected symbolically; then the answer is exact), at most
``max_iter`` otherwise. Rank-deficient Jacobians take the minimum-norm step, so directions of w
that do not move the state keep the guess. Used by the two-stage UISE, whose optimisation does
not carry w; the linear UIO has the closed form ``B^+ (x_hat[k] - A x_hat[k-1] - B_u u[k-1])``,
which is the same thing for a linear system (with ``S_x = I``).
"""

from __future__ import annotations

import math

import casadi as ca
import numpy as np

from uiest.box import FloatArray
from uiest.checks import all_finite
from uiest.system import System
from uiest.window.buffered import BufferedFunction

__all__ = ["InputFit"]


class InputFit:
    """Gauss-Newton least-squares fit of w in ``f(x_prev, u, w) = x_next`` (see the module docstring).

    Parameters
    ----------
    system : System
    max_iter : int
        Iterations for f not affine in w.
    tol : float
        Stop when the step is below ``tol`` in scaled units (``|dw / s_w|_inf``).

    """

    def __init__(self, system: System, *, max_iter: int = 20, tol: float = 1e-12) -> None:
        self.system = system
        self.max_iter = max_iter
        self.tol = tol
        x, u, w, x_next = (ca.SX.sym(s, n) for s, n in (("x", system.nx), ("u", system.nu), ("w", system.nw),
                                                        ("x_next", system.nx)))  # fmt: skip
        r = (system.f(x, u, w) - x_next) / ca.DM(system.x.scale)
        J = ca.jacobian(r, w)
        self.affine = not bool(ca.depends_on(J, w)) if system.nw else True
        self._fun = BufferedFunction(ca.Function("w_fit", [x, u, w, x_next], [r, ca.densify(J)]))

    def __call__(self, x_prev: FloatArray, u: FloatArray, x_next: FloatArray, w_guess: FloatArray) -> FloatArray:
        """The fitted w (shape (nw,)); the guess when a model evaluation is not finite."""
        w = np.array(w_guess, dtype=float).reshape(self.system.nw)
        if not self.system.nw:
            return w
        scale = self.system.w.scale
        iterations = 1 if self.affine else self.max_iter
        for iteration in range(1, iterations + 1):
            r, J_nonzeros = self._fun(x_prev, u, w, x_next)
            J = J_nonzeros.reshape(self.system.nw, self.system.nx).T  # column-major nonzeros
            if not (all_finite(r) and all_finite(J_nonzeros)):
                break
            step = _minimum_norm_step(J, r)
            w = w + step
            if iteration == iterations:  # affine in w: the one step is exact
                break
            if np.max(np.abs(step) / scale) <= self.tol * (1.0 + np.max(np.abs(w) / scale)):
                break
        return w


def _minimum_norm_step(J: FloatArray, r: FloatArray) -> FloatArray:
    """The minimum-norm least-squares step ``argmin |J s + r|`` (``J`` (nx, nw), ``r`` (nx,)), as ``lstsq`` gives it.

    One column (a single unknown input, the common case) in closed form where its square neither underflows nor
    overflows (else ``lstsq``, which costs several microseconds per call).
    """
    if J.shape[1] == 1:
        column = J[:, 0]
        curvature = float(column @ column)
        if _SAFE_SQUARE[0] < curvature < _SAFE_SQUARE[1]:
            closed_form = -float((column / curvature) @ r)  # scaled first: J^T r alone may under- or overflow
            if math.isfinite(closed_form):
                return np.array([closed_form])
    step: FloatArray = np.asarray(np.linalg.lstsq(J, -r, rcond=None)[0], dtype=np.float64)
    return step


_SAFE_SQUARE = (1e-200, 1e200)
"""Squared column norms within which :func:`_minimum_norm_step` tries its closed form."""
