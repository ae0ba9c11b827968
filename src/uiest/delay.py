r"""Unknown inputs the next output does not see: the matching test and the delayed system.

Matching, ``rank(C B) = rank(B)`` for the input matrix ``B = df/dw`` and ``C = dh/dx``, means
that every unknown input shows in the next output (relative degree 1): the UISE estimates x[k]
from y[..k]. When it fails, some directions of the input move the state without changing the
next output, and x[k] is not determined by y[..k]; the UISE would return an arbitrary point of
a flat valley. :func:`matching_ranks` measures the ranks pointwise (scaled coordinates).

**The delayed system.** For ``x+ = f1(x, u) + B d`` with a constant B and ``y = C x + g(v)``
(the form of :func:`~uiest.detectability.structure.input_structure`), let ``B0 = B ker(C B)``
be the input directions the next output does not see (scaled coordinates ``x / s_x``) and Q an
orthonormal complement of B0. Write ::

    x = M_a a + M_b b,   a = T_a x,  b = T_b x     (x / s_x = B0 a' + Q b', a and b rescaled to state units)

Because d moves ``a`` freely, ``a[k]`` is as free as an unknown input, while ``b`` obeys ::

    b+ = T_b f(M_a a + M_b b, u, w),   y = h(M_b b + M_a a_c, v)   (C B0 = 0: y does not see a)

a system with state b and unknown input ``(w, a)``. If *it* satisfies matching, a[k] moves
b[k+1] and shows in y[k+1] (so w[k-1], which moved a[k], shows in y[k+1]: relative degree 2), a
UISE on it estimates b[k] from y[..k], and the same window holds a[k-1] as its newest unknown
input, so ``x[k-1] = M_a a[k-1] + M_b b[k-1]`` is a delayed estimate
(:class:`~uiest.estimators.DelayedUISE`). When B0 is spanned by coordinate axes (an input that
acts on some states only), b and a are those states, in their own units.

Not covered: relative degree 3 or more (the delayed system fails matching again; a chain of
reductions would also have to invert the inner levels' inputs) and inputs that never reach the
output (a does not move b). Both raise :class:`~uiest.errors.ModelError` naming the ranks.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np
import scipy.linalg

from uiest.box import Box, FloatArray
from uiest.detectability.lmi import batched, finite_box
from uiest.detectability.structure import RANK_RTOL, input_structure
from uiest.errors import ModelError
from uiest.system import System

__all__ = ["DelayedSystem", "delayed_system", "matching_ranks"]

MATCHING_SAMPLES = 32
"""Points of X x U (and w around its nominal value) at which :func:`matching_ranks` compares ranks."""


def _rank(M: FloatArray, reference: float | np.floating) -> int:
    s = np.linalg.svd(M, compute_uv=False) if M.size else np.zeros(0)
    return int(np.sum(s > RANK_RTOL * reference)) if reference > 0 else 0


def matching_ranks(system: System, *, samples: int = MATCHING_SAMPLES, seed: int = 0) -> tuple[int, int]:
    """The smallest ``rank(C B) - rank(B)`` gap over sampled points: returns ``(rank(C B), rank(B))`` there.

    ``B = S_x^-1 df/dw S_w`` and ``C = S_y^-1 dh/dx S_x`` at points of X x U (infinite sides
    replaced by centre +- scale) with w within one scale of its nominal value. Matching holds
    when the two ranks are equal at every point.
    """
    if system.nw == 0:
        return 0, 0
    rng = np.random.default_rng(seed)
    X = finite_box(system.x.bounds, system.x.bounds.center, system.x.scale)
    U = finite_box(system.u.bounds, system.u.bounds.center, system.u.scale)
    x = np.vstack([X.center, X.sample(rng, samples - 1)])
    u = np.vstack([U.center, U.sample(rng, samples - 1)])
    w = system.nominal_w + system.w.scale * rng.uniform(-1.0, 1.0, (samples, system.nw))
    w[0] = system.nominal_w
    v = np.zeros((samples, system.nv))
    _, _, Bw, C, _ = batched(system.jacobian_function, [x, u, w, v])
    sx, sw, sy = system.x.scale, system.w.scale, system.y.scale
    worst = (system.nw, system.nw)
    B_scaled, C_scaled = Bw * sw[None, None, :] / sx[None, :, None], C * sx[None, None, :] / sy[None, :, None]
    for Bi, Ci in zip(B_scaled, C_scaled, strict=True):
        if not (np.all(np.isfinite(Bi)) and np.all(np.isfinite(Ci))):
            continue
        rank_B = _rank(Bi, np.linalg.norm(Bi, 2))
        rank_CB = _rank(Ci @ Bi, np.linalg.norm(Ci, 2) * np.linalg.norm(Bi, 2))
        if rank_CB - rank_B < worst[0] - worst[1]:
            worst = (rank_CB, rank_B)
    return worst


@dataclass(frozen=True, eq=False, kw_only=True)
class DelayedSystem:
    """The delayed system of a relative-degree-2 unknown input (module docstring).

    Attributes
    ----------
    system : System
        State b (nb = nx - r0), unknown input ``(w, a)`` (nw + r0), the original u, v and y.
    original : System
    T_a : ndarray (r0, nx)
        ``a = T_a x``.
    T_b : ndarray (nb, nx)
        ``b = T_b x``.
    M_a, M_b : ndarray (nx, r0), (nx, nb)
        ``x = M_a a + M_b b``.
    a_bounds : Box
        The range of a over X (a bounding box).
    nominal_w : ndarray (nw + r0,)
        The original nominal w and the centre of the range of a.

    """

    system: System
    original: System
    T_a: FloatArray
    T_b: FloatArray
    M_a: FloatArray
    M_b: FloatArray
    a_bounds: Box
    nominal_w: FloatArray

    @property
    def r0(self) -> int:
        """Number of input directions the next output does not see (the size of a)."""
        return self.T_a.shape[0]

    def state(self, b: FloatArray, a: FloatArray) -> FloatArray:
        """``x = M_a a + M_b b`` (shapes (nb,), (r0,) -> (nx,))."""
        return self.M_a @ a + self.M_b @ b


def _basis(span: FloatArray, n: int) -> FloatArray:
    """Orthonormal basis of ``span``'s columns, as coordinate axes when the span is spanned by axes."""
    projector = span @ span.T
    diagonal = np.diag(projector)
    axes = np.flatnonzero(diagonal > 0.5)
    if np.allclose(projector, np.diag(np.round(diagonal)), atol=1e-12) and len(axes) == span.shape[1]:
        return np.eye(n)[:, axes]
    basis = scipy.linalg.orth(span)
    return basis * np.where(basis[np.argmax(np.abs(basis), axis=0), range(basis.shape[1])] < 0, -1.0, 1.0)


def _range(T: FloatArray, box: Box) -> Box:
    center, half = T @ box.center, np.abs(T) @ (0.5 * box.width)
    return Box(center - half, center + half)


def delayed_system(system: System) -> DelayedSystem:
    """The delayed system of ``system`` when its unknown input has relative degree 2 (module docstring).

    Raises
    ------
    ModelError
        Matching holds (no delay needed), the model is not of the form ``x+ = f1 + B d``,
        ``y = C x + g(v)`` over a bounded X, the invisible input never reaches the output, or the
        relative degree is 3 or more; each names the ranks measured.

    """
    if not system.x.bounds.is_bounded:
        raise ModelError(f"X: delayed_system needs a bounded state domain (to find the input's directions), got "
                         f"{system.x.bounds}")  # fmt: skip
    structure = input_structure(system, matching=False)
    n, B, C = system.nx, structure.B, structure.C
    if structure.rank_CB == structure.rank_B:
        raise ModelError(
            f"delayed_system: matching holds (rank(C B) = rank(B) = {structure.rank_B}); the UISE estimates x[k] "
            "without delay"
        )
    if structure.pointwise_rank < structure.rank_B:
        raise ModelError(
            "delayed_system: the direction of df/dw varies over the domain (rank "
            f"{structure.pointwise_rank} at a point, span {structure.rank_B}); a constant input matrix is needed"
        )
    Vt = np.linalg.svd(C @ B)[2]
    kernel = Vt[structure.rank_CB :].T  # (r, r0): the input combinations C B does not see
    B0 = _basis(B @ kernel, n)
    Q = _basis(scipy.linalg.null_space(B0.T), n)
    sx = system.x.scale
    s_a, s_b = np.linalg.norm(sx[:, None] * B0, axis=0), np.linalg.norm(sx[:, None] * Q, axis=0)
    T_a, T_b = s_a[:, None] * B0.T / sx[None, :], s_b[:, None] * Q.T / sx[None, :]
    M_a, M_b = sx[:, None] * B0 / s_a[None, :], sx[:, None] * Q / s_b[None, :]
    a_bounds, b_bounds = _range(T_a, system.x.bounds), _range(T_b, system.x.bounds)
    nominal = np.concatenate([system.nominal_w, a_bounds.center])

    r0, nb = B0.shape[1], Q.shape[1]
    b, a = ca.SX.sym("b", nb), ca.SX.sym("a", r0)
    u, w, v = ca.SX.sym("u", system.nu), ca.SX.sym("w", system.nw), ca.SX.sym("v", system.nv)
    x = ca.mtimes(ca.DM(M_a), a) + ca.mtimes(ca.DM(M_b), b)
    b_next = ca.mtimes(ca.DM(T_b), system.f(x, u, w))
    G = ca.jacobian(b_next, w)
    if system.nw and not ca.depends_on(G, ca.vertcat(b, a, u, w)):
        # f affine in w: T_b df/dw kills the invisible directions exactly, not up to rounding (which a
        # certificate would read as another input direction)
        G_num = np.asarray(ca.Function("G", [b, a, u, w], [G])(np.zeros(nb), np.zeros(r0), np.zeros(system.nu),
                                                              system.nominal_w))  # fmt: skip
        Bw = system.linearize(system.x.bounds.center).B_w
        G_num[np.abs(G_num) <= 1e-12 * (np.abs(T_b) @ np.abs(Bw))] = 0.0  # cancellation down to rounding
        w0 = ca.DM(system.nominal_w)
        b_next = ca.mtimes(ca.DM(T_b), system.f(x, u, w0)) + ca.mtimes(ca.DM(G_num), w - w0)
    y = system.h(ca.mtimes(ca.DM(M_b), b) + ca.DM(M_a @ a_bounds.center), v)

    def names(basis: FloatArray, prefix: str) -> list[str]:
        """The state's name for a coordinate axis, else ``prefix + index``."""
        axis = np.isclose(basis.sum(axis=0), 1.0) & np.isclose(np.abs(basis).max(axis=0), 1.0)
        return [system.x.names[int(np.argmax(c))] if axis[i] else f"{prefix}{i}" for i, c in enumerate(basis.T)]

    inner = System.from_expressions(
        b, u, ca.vertcat(w, a), v, b_next, y,
        x_bounds=b_bounds, u_bounds=system.u.bounds, v_bounds=system.v.bounds, y_bounds=system.y.bounds,
        x_names=names(Q, "b"),
        u_names=system.u.names, v_names=system.v.names, y_names=system.y.names,
        w_names=[*system.w.names, *names(B0, "a")],
        x_scale=s_b, u_scale=system.u.scale, v_scale=system.v.scale, y_scale=system.y.scale,
        w_scale=np.concatenate([system.w.scale, s_a]), dt=system.dt, time_unit=system.time_unit,
        name=f"{system.name} (delayed)",
    )  # fmt: skip
    delayed = DelayedSystem(
        system=inner, original=system, T_a=T_a, T_b=T_b, M_a=M_a, M_b=M_b, a_bounds=a_bounds, nominal_w=nominal
    )
    _check_relative_degree_two(delayed, structure.rank_B)
    return delayed


def _check_relative_degree_two(delayed: DelayedSystem, rank_B: int) -> None:
    """The delayed system's input must have rank rank(B) (a reaches b) and satisfy matching (a shows in y)."""
    rng = np.random.default_rng(0)
    inner = delayed.system
    points = np.vstack([inner.x.bounds.center, inner.x.bounds.sample(rng, MATCHING_SAMPLES - 1)])
    u = np.tile(finite_box(inner.u.bounds, inner.u.bounds.center, inner.u.scale).center, (len(points), 1))
    w = np.tile(delayed.nominal_w, (len(points), 1))
    _, _, Bw, _, _ = batched(inner.jacobian_function, [points, u, w, np.zeros((len(points), inner.nv))])
    scaled = Bw * inner.w.scale[None, None, :] / inner.x.scale[None, :, None]
    reached = min(_rank(Bi, np.linalg.norm(Bi, 2)) for Bi in scaled)
    if reached < rank_B:
        raise ModelError(
            f"delayed_system: the unknown input's directions the next output does not see do not all reach the "
            f"rest of the state within one step (rank {reached} < rank(B) = {rank_B} somewhere in X): it shows in "
            "the output later or never; only relative degree 2 is supported"
        )
    rank_CB, rank_B2 = matching_ranks(inner)
    if rank_CB < rank_B2:
        raise ModelError(
            f"delayed_system: matching fails for the delayed system too (rank(C B) = {rank_CB} < rank(B) = {rank_B2}): "
            "the unknown input's relative degree is 3 or more, which is not supported"
        )
