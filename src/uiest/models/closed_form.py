r"""A nonlinear system whose unknown-input estimation error has a closed form.

Model (``nx = 2``, ``nu = 1``, ``nw = 1``, ``nv = ny = 1``)::

    x1+ = x1 + beta sin(x2) + w
    x2+ = a(x1) x2 + u,        a(x1) = a0 + a1 tanh(x1),   0 <= a0 - |a1|,  a0 + |a1| < 1
    y   = x1 + v

Derivation of the closed form. The unknown input ``w`` enters only ``x1``, which is measured,
so ``w`` can explain any ``x1`` trajectory: the output carries no information on ``x2``
(``x2`` acts on ``y`` only through ``x1``'s dynamics, and ``w`` masks that channel). ``x2`` is
therefore not observable but detectable: its dynamics, given the measured ``x1``, are a
contraction with the state-dependent rate ``a(x1)``.

Any estimator that (i) reproduces ``x1`` from ``y`` and (ii) propagates ``x2`` through the
model from its prior -- which is what the UISEs of the paper do, because no term of their
costs depends on ``x2`` beyond the prior -- has, noise-free,

    e1_k = 0,      e2_{k+1} = a(x1_k) e2_k   =>   e2_k = (prod_{j=0}^{k-1} a(x1_j)) e2_0,

for every unknown input sequence, however large. With noise and the estimate
``x1_hat_k = y_k`` (noise prior ``v_bar = 0``) the first error is ``e1_k = -v_k`` and the second
follows ``e2_{k+1} = a(x1_k) x2_k - a(y_k - v_hat_k) x2_hat_k`` with the estimator's noise
estimate ``v_hat_k``.

The reduced-order model of the paper (``T = id``, ``z_flat = x1 = psi(y, v) = y - v``,
``z_sharp = x2``) is ``z_sharp+ = a(y - v) z_sharp + u``: contractive with rate
``max a = a0 + |a1|``, so its exponential i-IOSS holds with ``mu = (a0 + |a1|)^2`` and the
strong detectability of the full model with the same discount.
"""

from __future__ import annotations

from typing import Any

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike

from uiest.box import FloatArray
from uiest.errors import ModelError
from uiest.reduction import ReducedModel
from uiest.system import System

__all__ = ["NAME", "contraction_rate", "jacobian_parameters", "noise_free_error", "reduction", "system"]

NAME = "closed-form"


def system(
    a0: float = 0.5,
    a1: float = 0.3,
    beta: float = 0.5,
    *,
    x_bounds: Any = ((-10.0, -10.0), (10.0, 10.0)),
    v_bound: float = 1e-2,
    name: str = NAME,
) -> System:
    """The closed-form system (see the module docstring) with contraction rates in ``[a0-|a1|, a0+|a1|]``."""
    if not (a0 - abs(a1) >= 0.0 and a0 + abs(a1) < 1.0):
        raise ModelError(f"a0, a1: expected 0 <= a0 - |a1| and a0 + |a1| < 1, got a0={a0}, a1={a1}")
    x, u, w, v = ca.SX.sym("x", 2), ca.SX.sym("u", 1), ca.SX.sym("w", 1), ca.SX.sym("v", 1)
    x_next = ca.vertcat(x[0] + beta * ca.sin(x[1]) + w[0], (a0 + a1 * ca.tanh(x[0])) * x[1] + u[0])
    return System.from_expressions(
        x,
        u,
        w,
        v,
        x_next,
        x[0] + v,
        x_bounds=x_bounds,
        v_bounds=(-v_bound, v_bound),
        x_names=("x1", "x2"),
        u_names=("u",),
        w_names=("w",),
        v_names=("v",),
        y_names=("y",),
        name=name,
    )


def jacobian_parameters() -> Any:
    """``theta(x, u) = (x2 (1 - tanh(x1)^2), tanh(x1))``, the functions the state Jacobian is affine in.

    With the unknown input's direction (x1) projected out, ``df/dx = [[0, 0], [a1 theta_1,
    a0 + a1 theta_2]]``, written as the model's derivative writes it (``1 - tanh^2``, not
    ``1 / cosh^2``): the box of theta over X is an exact certificate cover.
    """
    return lambda x, u: [x[1] * (1.0 - np.tanh(x[0]) ** 2), np.tanh(x[0])]


def reduction(**kwargs: Any) -> ReducedModel:
    """The reduction of the module docstring: ``T = id``, ``z_flat = x1 = psi(y, v) = y - v``.

    Keywords as in :func:`system`.
    """
    return ReducedModel.from_maps(
        system(**kwargs), lambda x: x, lambda z: z, lambda y, z_sharp, v: [y[0] - v[0]], n_flat=1
    )


def contraction_rate(x1: ArrayLike, a0: float = 0.5, a1: float = 0.3) -> FloatArray:
    """``a(x1) = a0 + a1 tanh(x1)`` elementwise."""
    return a0 + a1 * np.tanh(np.asarray(x1, dtype=float))


def noise_free_error(x1: ArrayLike, e2_0: float, a0: float = 0.5, a1: float = 0.3) -> FloatArray:
    """Closed-form noise-free error of x2: ``e2_k = prod_{j<k} a(x1_j) e2_0`` for k = 0..K.

    Parameters
    ----------
    x1 : array_like, shape (K+1,)
        The true first state x1_0..x1_K (only x1_0..x1_{K-1} enter).
    e2_0 : float
        Initial error ``x2_0 - x2_hat_0``.

    Returns
    -------
    ndarray, shape (K+1,)

    """
    rates = contraction_rate(np.asarray(x1, dtype=float)[:-1], a0, a1)
    return e2_0 * np.concatenate([[1.0], np.cumprod(rates)])
