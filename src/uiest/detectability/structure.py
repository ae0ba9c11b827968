r"""The form ``x+ = f1(x, u) + B d``, ``y = C x + g(v)`` that the strong-detectability LMI needs.

The unknown input must act through a constant input matrix B (Eq. (19) of Guo et al. after
its change of input ``d = f2(w, x, u)``): then d is as free as w, and the LMI eliminates it
exactly. :func:`input_structure` reads the form off a :class:`~uiest.system.System`:

- ``C = dh/dx`` must be constant and ``dh/dv`` independent of x (checked structurally; a
  nonlinear output needs the paper's change of state phi first);
- B is an orthonormal basis of a space that provably holds ``df/dw`` over X x U x W: its
  columns when ``df/dw`` is constant, and otherwise the columns of the constant matrices of its
  exact form ``df/dw = sum_m C_m m(x, u, w)`` (:mod:`uiest.detectability.affine`: monomials m of
  the model's nonlinear functions, exact rational coefficients), so a direction that appears only
  at large w or in a corner of X is never missed. Samples (w up to 1e6 of its scale) give the
  rank of ``df/dw`` at a single point for the messages. If the span is larger than that, the
  input's direction varies with the state: B is the whole span, which is sound but adds
  directions the output must see;
- matching ``rank(C B) = rank(B)`` is required (the unknown input must show in the next output).

Everything is in scaled coordinates ``x / x.scale`` etc.; the LMI's state Jacobian is
``A(x, u) = (I - B B^T) S_x^-1 df/dx(x, u, w0) S_x`` (the part along B is cancelled by the
elimination anyway, and removing it makes A independent of w).
"""

from __future__ import annotations

from dataclasses import dataclass
from fractions import Fraction
from typing import NoReturn

import casadi as ca
import numpy as np

from uiest.box import Box, FloatArray
from uiest.detectability.affine import Forms
from uiest.detectability.lmi import batched, finite_box
from uiest.errors import ModelError
from uiest.system import System

__all__ = ["RANK_RTOL", "InputStructure", "input_structure"]

RANK_RTOL = 1e-8
"""Singular values below this fraction of the largest one count as zero (ranks of df/dw and C B)."""

DIRECTION_RTOL = 1e-12
"""Directions of sampled ``df/dw`` columns below this fraction count as rounding: the unknown input is
unbounded, so a direction dropped that is not rounding would make the elimination inexact without bound."""


@dataclass(frozen=True, eq=False, kw_only=True)
class InputStructure:
    """Scaled data of ``x+ = f1(x, u) + B d``, ``y = C x + g(v)`` for one system.

    Attributes
    ----------
    B : ndarray, shape (nx, r)
        Orthonormal basis of the unknown input's directions (scaled coordinates).
    C : ndarray, shape (ny, nx)
        Scaled output matrix ``S_y^-1 dh/dx S_x``.
    D_norm : float
        Largest spectral norm of the scaled ``S_y^-1 dh/dv S_v`` over V (exact when constant).
    D : ndarray, shape (ny, nv)
        Scaled ``dh/dv`` at the centre of V.
    noise_constant : bool
        Whether ``dh/dv`` is constant (``y = C x + D v``), so D is exact everywhere.
    rank_B, rank_CB : int
        Numerical ranks (``rank_B`` is also the number of columns of B).
    pointwise_rank : int
        Largest rank of ``df/dw`` at a single point (< rank_B: the direction varies).
    evidence : str
        How B was found ("structural": df/dw is constant; "exact forms": the span of its form's
        constant matrices); either way the span of B provably holds every input direction.
    state_jacobian : casadi.Function
        ``z = (x, u) -> A (nx, nx)``, the scaled, projected Jacobian of f in x at ``w0``.
    box : Box
        The domain of ``z = (x, u)`` (U's infinite sides replaced by centre +- scale when A
        does not depend on them).
    names : tuple of str
        Names of the entries of z.

    """

    B: FloatArray
    C: FloatArray
    D_norm: float
    D: FloatArray
    noise_constant: bool
    rank_B: int  # noqa: N815
    rank_CB: int  # noqa: N815
    pointwise_rank: int
    evidence: str
    state_jacobian: ca.Function
    box: Box
    names: tuple[str, ...]


def _rank(M: FloatArray, scale: float | np.floating) -> int:
    s = np.linalg.svd(M, compute_uv=False) if M.size else np.zeros(0)
    return int(np.sum(s > RANK_RTOL * scale)) if scale > 0 else 0


def _depends(expr: ca.SX, symbols: list[ca.SX]) -> bool:
    return any(ca.depends_on(expr, s) for s in symbols if s.numel())


def input_structure(system: System, *, samples: int = 2000, seed: int = 0, matching: bool = True) -> InputStructure:
    """Read ``x+ = f1(x, u) + B d``, ``y = C x + g(v)`` off ``system`` (see the module docstring).

    ``matching=False`` skips the matching condition (for :mod:`uiest.delay`, which handles its failure).

    Raises
    ------
    ModelError
        X unbounded, no output, an output that is not affine in x, or a failed matching
        condition (naming the property and the measured ranks).

    """
    if not system.x.bounds.is_bounded:
        raise ModelError(f"X: a certificate needs a bounded state domain, got {system.x.bounds}")
    if system.ny == 0:
        raise ModelError("h: a certificate needs at least one output")
    nx, nu, nw, nv = system.nx, system.nu, system.nw, system.nv
    x, u, w, v = (ca.SX.sym(s, n) for s, n in (("x", nx), ("u", nu), ("w", nw), ("v", nv)))
    C, D_all, noise_constant = _output_map(system, x, v, seed)
    D_norm = float(max(np.linalg.norm(Di, 2) for Di in D_all)) if nv else 0.0
    U = finite_box(system.u.bounds, system.u.bounds.center, system.u.scale)
    B, pointwise, evidence = _input_directions(system, x, u, w, U, samples, seed)
    rank_B = B.shape[1]
    rank_CB = _rank(C @ B, np.linalg.norm(C, 2)) if rank_B else 0
    if matching and rank_CB < rank_B:
        _fail_matching(rank_B, rank_CB, pointwise)
    projector = np.eye(nx) - B @ B.T
    A_expr = ca.jacobian(system.f(x, u, ca.DM(system.nominal_w)), x)
    A_scaled = ca.mtimes([ca.DM(projector @ np.diag(1.0 / system.x.scale)), A_expr, ca.DM(np.diag(system.x.scale))])
    state_jacobian = ca.Function("A", [ca.vertcat(x, u)], [A_scaled])
    box = Box(np.concatenate([system.x.bounds.lower, U.lower]), np.concatenate([system.x.bounds.upper, U.upper]))
    if not np.all(np.isfinite(system.u.bounds.lower) & np.isfinite(system.u.bounds.upper)) and _depends(A_expr, [u]):
        raise ModelError(
            f"U: the state Jacobian depends on the known input, whose domain is unbounded ({system.u.bounds}); "
            "give finite u_bounds"
        )
    return InputStructure(
        B=B,
        C=C,
        D_norm=D_norm,
        D=D_all[0],
        noise_constant=noise_constant,
        rank_B=rank_B,
        rank_CB=rank_CB,
        pointwise_rank=pointwise,
        evidence=evidence,
        state_jacobian=state_jacobian,
        box=box,
        names=tuple(system.x.names) + tuple(system.u.names),
    )


def _output_map(system: System, x: ca.SX, v: ca.SX, seed: int) -> tuple[FloatArray, FloatArray, bool]:
    """``C`` (ny, nx), ``D = dg/dv`` (m, ny, nv) and whether D is constant, all scaled.

    D at V's centre, then (where g is nonlinear) at V's corners and sampled points. ModelError when h is not
    ``C x + g(v)``.
    """
    nx, nv = system.nx, system.nv
    hx = system.h(x, v)
    C_expr, D_expr = ca.jacobian(hx, x), ca.jacobian(hx, v)
    if _depends(C_expr, [x, v]):
        raise ModelError(
            "h: the output must be affine in the state, y = C x + g(v) (dh/dx varies over the domain); bring the "
            "model to this form by a change of state (the paper's phi) first"
        )
    if _depends(D_expr, [x]):
        raise ModelError("h: the noise must enter the output independently of the state, y = C x + g(v)")
    sx, sy, sv = system.x.scale, system.y.scale, system.v.scale
    C = np.asarray(ca.DM(ca.substitute(C_expr, ca.vertcat(x, v), ca.DM.zeros(nx + nv))), dtype=float)
    C = C * sx[None, :] / sy[:, None]
    V = finite_box(system.v.bounds, system.v.bounds.center, sv)
    v_points = V.center[None]
    noise_constant = not _depends(D_expr, [v])
    if not noise_constant:  # g(v) nonlinear: the largest gain over V, sampled
        v_points = np.vstack(
            [v_points, V.corners() if nv <= 10 else v_points, V.sample(np.random.default_rng(seed), 256)]
        )
    D_all = batched(ca.Function("D", [v], [D_expr]), [v_points])[0] * sv[None, None, :] / sy[None, :, None]
    return C, D_all, noise_constant


def _input_directions(
    system: System, x: ca.SX, u: ca.SX, w: ca.SX, U: Box, samples: int, seed: int
) -> tuple[FloatArray, int, str]:
    """An orthonormal basis B (nx, r) of the span of df/dw's columns (scaled), and how it was found.

    Returns ``(B, pointwise, evidence)``: the largest rank of df/dw at a sampled point, and the evidence
    (structural: constant; exact forms).
    """
    nx, nu, nw = system.nx, system.nu, system.nw
    sx, sw = system.x.scale, system.w.scale
    B_expr = ca.jacobian(system.f(x, u, w), w)
    rng = np.random.default_rng(seed)
    if not _depends(B_expr, [x, u, w]):
        B_samples = np.asarray(ca.DM(ca.substitute(B_expr, ca.vertcat(x, u, w), ca.DM.zeros(nx + nu + nw))))[None]
        evidence = "structural (df/dw is constant)"
    else:
        xs, us = system.x.bounds.sample(rng, samples), U.sample(rng, samples)
        magnitude = 10.0 ** rng.uniform(-3.0, 6.0, (samples, nw)) * rng.choice([-1.0, 1.0], (samples, nw))
        ws = system.nominal_w + sw * magnitude
        B_samples = batched(ca.Function("Bw", [x, u, w], [B_expr]), [xs, us, ws])[0]
        finite = np.all(np.isfinite(B_samples), axis=(1, 2))
        if not finite.any():
            raise ModelError("f: df/dw is not finite at any sampled point of X x U x W")
        B_samples = B_samples[finite]
        evidence = "sampled"
    B_scaled = B_samples * sw[None, None, :] / sx[None, :, None]
    biggest = float(np.abs(B_scaled).max()) if B_scaled.size else 0.0
    pointwise = max((_rank(Bi, np.linalg.norm(Bi, 2)) for Bi in B_scaled), default=0) if biggest > 0 else 0
    if evidence.startswith("structural"):
        return _orthonormal(list(B_scaled[0].T), nx, None), pointwise, evidence
    directions, terms = _form_directions(ca.Function("Bw", [ca.vertcat(x, u, w)], [B_expr]), nx, nw)
    evidence = (f"exact forms (df/dw is a combination of {terms} constant matrices; {pointwise} direction(s) "
                f"at a sampled point)")  # fmt: skip
    return _orthonormal([d / sx for d in directions], nx, len(directions)), pointwise, evidence


def _fail_matching(rank_B: int, rank_CB: int, pointwise: int) -> NoReturn:
    """ModelError: the outputs do not see every direction of the span B the certificate eliminates; why, and what to do.

    Where the next output sees as many directions as ``df/dw`` has at a point (``rank_CB >= pointwise``) but that
    direction varies over the domain (``pointwise < rank_B``), the matching condition may hold at each point; the span
    over the domain is what the outputs miss. Otherwise matching fails.
    """
    if pointwise <= rank_CB < rank_B:
        raise ModelError(
            f"the unknown input's direction varies over the domain: df/dw has rank {pointwise} at a point, but its "
            f"directions over the domain span {rank_B} dimensions, of which the next output sees {rank_CB} "
            f"(rank(C B) = {rank_CB} < {rank_B} for that span B), so w cannot be eliminated through a constant "
            "input matrix; this happens where w does not enter through one, e.g. an RK4 step of an ODE. Keep the "
            "input's direction constant: System.from_ode does where dx/dt = F(x, u) + G w with a constant G (its "
            "input channel 'integral'); where G varies with the state, take G(x) w's varying factor into the "
            "unknown input (w' = g(x) w)"
        )
    raise ModelError(
        f"matching fails: rank(C B) = {rank_CB} < rank(B) = {rank_B}: the unknown input can move the state without "
        "changing the next output, so the system is not strongly detectable (x[k] cannot be estimated from y[..k]; "
        "a delayed estimate may exist)"
    )


def _form_directions(fun: ca.Function, nx: int, nw: int) -> tuple[list[FloatArray], int]:
    """Independent columns (exact elimination) of the constant matrices of ``fun``'s form, and their count.

    ``fun(z) = df/dw (nx, nw) = sum_m C_m m(z)``: every column of ``df/dw`` at any z lies in the span
    of the columns of the ``C_m``.
    """
    entries = Forms().of(fun)
    monomials = sorted({m for form in entries for m in form})
    columns = [[form.get(m, Fraction(0)) for form in entries[j * nx : (j + 1) * nx]] for m in monomials
               for j in range(nw)]  # fmt: skip
    pivots: list[tuple[int, list[Fraction]]] = []
    kept = []
    for column in columns:
        v = list(column)
        for i, p in pivots:
            if v[i]:
                factor = v[i] / p[i]
                v = [a - factor * b for a, b in zip(v, p, strict=True)]
        nonzero = [i for i, a in enumerate(v) if a]
        if nonzero:
            pivots.append((nonzero[0], v))
            kept.append(np.array([float(a) for a in column]))
    return kept, len(monomials)


def _orthonormal(directions: list[FloatArray], nx: int, rank: int | None) -> FloatArray:
    """An orthonormal basis (nx, r) of the span of ``directions``: r = ``rank`` (known exactly), or numerical.

    The numerical rank keeps directions down to ``DIRECTION_RTOL`` of the largest (only rounding is dropped:
    the unknown input is unbounded).
    """
    columns = [d / np.linalg.norm(d) for d in directions if np.all(np.isfinite(d)) and np.linalg.norm(d) > 0]
    if not columns:
        return np.zeros((nx, 0))
    basis, s, _ = np.linalg.svd(np.stack(columns, axis=1), full_matrices=False)
    if rank is None:
        rank = int(np.sum(s > DIRECTION_RTOL * s[0]))
    return basis[:, :rank]
