r"""Reduced-order models (Section 4): the map T, the function psi and the decoupled model.

Section, assumption and equation numbers are those of Guo et al. (see the theory map).

Given a diffeomorphism ``T(x) = (T_flat(x), T_sharp(x))`` with ``n_flat`` flat coordinates and
a function ``psi`` with ``z_flat = psi(y, z_sharp, v)`` (Assumption 4.2, Eq. (17)), the reduced-order model
Eq. (21) is

    z_sharp+ = f_sharp(z_sharp, gamma, u, v) = T_sharp(f(T^-1(psi(gamma, z_sharp, v), z_sharp), u, w)),
    y        = h_sharp(z_sharp, gamma, v)    = h(T^-1(psi(gamma, z_sharp, v), z_sharp), v),

which must not depend on w (Eq. (18); checked symbolically). The full state is recovered by
Eq. (26), ``x = T^-1(psi(y, z_sharp, v), z_sharp)``.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import casadi as ca
import numpy as np

from uiest.box import Box, FloatArray, as_vector
from uiest.checks import check_int, check_samples, check_seed, shown
from uiest.detectability import lmi
from uiest.detectability.interval import range_box
from uiest.errors import ModelError
from uiest.system import System, as_function
from uiest.theory import PSI_RECOVERY, QUASI_STATE_AFFINE_REDUCTION, W_FREE_REDUCED_DYNAMICS
from uiest.window.model import box_scale
from uiest.window.problem import working_center

__all__ = ["ASSUMPTION_TOL", "AssumptionReport", "ReducedModel", "reduce_quasi_state_affine"]

ASSUMPTION_TOL = 1e-8
"""Largest relative violation of Eq. (17), Eq. (18) and T_inv o T = id that :meth:`ReducedModel.from_maps` accepts."""


@dataclass(frozen=True, kw_only=True)
class AssumptionReport:
    """Largest violations of Assumption ass found on sampled points of X x U x W x V.

    Attributes
    ----------
    inverse_error : float
        ``max |T_inv(T(x)) - x| / (|x| + scale_x)`` (relative to ``|x|``, so a wide X with a small scale is fine).
    psi_error : float
        Eq. (17): ``max |psi(h(x, v), T_sharp(x), v) - T_flat(x)| / |T_flat|``.
    w_sensitivity : float
        Eq. (18): ``max |d z_sharp+ / dw| scale_w / |z_sharp|`` (w up to 1e6 scales).
    dominance_margin : float
        The remark after ass: ``d = min (|dh^i/dz_flat^i| - sum_(j != i) |dh^i/dz_flat^j|)`` over
        the samples for the best choice of distinct outputs; ``d > 0`` on all of the domain is the
        sufficient condition (global implicit function theorem) for a psi to exist. NaN if
        ``n_flat > ny``; inf if ``n_flat = 0``.
    dominance_outputs : tuple of int
        The outputs ``i_1, ..., i_n_flat`` paired with the flat coordinates.
    points : int
        Number of sampled points.

    """

    inverse_error: float
    psi_error: float
    w_sensitivity: float
    dominance_margin: float
    dominance_outputs: tuple[int, ...]
    points: int

    @property
    def holds(self) -> bool:
        """All three violations within ``ASSUMPTION_TOL``."""
        return max(self.inverse_error, self.psi_error, self.w_sensitivity) <= ASSUMPTION_TOL


@dataclass(frozen=True, eq=False)
class ReducedModel:
    """A system with its reduction (T, psi) and the reduced-order model Eq. (21).

    Attributes
    ----------
    system : System
        The full model.
    n_flat : int
        Number of flat coordinates (recovered from the output by psi); ``n_sharp = nx - n_flat``.
    T, T_inv : casadi.Function
        ``x (nx,) -> z (nx,)`` with ``z = (z_flat, z_sharp)``, and its inverse.
    psi : casadi.Function
        ``(y (ny,), z_sharp (n_sharp,), v (nv,)) -> z_flat (n_flat,)``.
    f_sharp : casadi.Function
        ``(z_sharp, gamma (ny,), u (nu,), v (nv,)) -> z_sharp+``.
    h_sharp : casadi.Function
        ``(z_sharp, gamma (ny,), v (nv,)) -> y (ny,)``.
    z_bounds : Box
        Box containing ``T_sharp(X)`` (the projection of T(X) onto z_sharp).
    z_bounds_note : str
        Empty when ``z_bounds`` is proved (interval arithmetic, or given); else how it was found (a grid of
        X: a certificate on it is "holds at the samples, not proved").

    """

    system: System = field(repr=False)
    n_flat: int
    T: ca.Function = field(repr=False)
    T_inv: ca.Function = field(repr=False)
    psi: ca.Function = field(repr=False)
    f_sharp: ca.Function = field(repr=False)
    h_sharp: ca.Function = field(repr=False)
    z_bounds: Box
    z_bounds_note: str = ""

    @property
    def n_sharp(self) -> int:
        """Dimension of the reduced state."""
        return self.system.nx - self.n_flat

    @cached_property
    def z_scale(self) -> FloatArray:
        """Nominal magnitudes of ``z_sharp``: ``|dT_sharp/dx| s_x`` at X's working centre, capped by T(X)'s widths.

        From the state scales, not from T(X)'s widths alone, so that a wide X with small state
        scales gives small z scales (for a linear T and ``s_x`` = X's widths both are the same).
        """
        s = self.system
        x = ca.SX.sym("x", s.nx)
        jac = ca.Function("dT_sharp", [x], [ca.jacobian(self.T(x)[self.n_flat :], x)])
        spread = np.abs(np.asarray(jac(working_center(s.x.bounds, s.x.scale)), dtype=float))
        spread = spread.reshape(self.n_sharp, s.nx) @ s.x.scale
        width = box_scale(self.z_bounds)
        usable = np.isfinite(spread) & (spread > 0)
        return np.where(usable, np.minimum(np.where(usable, spread, 1.0), width), width)

    @classmethod
    def from_maps(
        cls,
        system: System,
        T: Any,
        T_inv: Any,
        psi: Any,
        *,
        n_flat: int,
        z_bounds: Box | tuple[Any, Any] | None = None,
        check_points: int = 200,
        seed: int = 0,
    ) -> ReducedModel:
        """Build the reduced-order model from T, its inverse and psi (callables or casadi Functions).

        Checks (see :meth:`check_assumptions`), raising ModelError naming the violated condition
        and the largest violation when it exceeds ``ASSUMPTION_TOL``: Eq. (18) (f_sharp
        independent of w), ``T_inv(T(x)) = x`` and Eq. (17) on ``check_points`` random points.
        ``z_bounds`` defaults to the min/max of ``T_sharp`` over a 5-point grid of X (exact for
        linear T, whose extremes lie at the corners).
        """
        if not isinstance(system, System):
            raise ModelError(f"system: expected a uiest.System, got {shown(system)}")
        nx, nu, nw, nv, ny = system.nx, system.nu, system.nw, system.nv, system.ny
        n_flat = check_int(n_flat, "n_flat", high=nx, error=ModelError)
        check_points, seed = check_samples(check_points, "check_points"), check_seed(seed)
        n_sharp = nx - n_flat
        T_fun = as_function(T, "T", [("x", nx)], nx)
        T_inv_fun = as_function(T_inv, "T_inv", [("z", nx)], nx)
        psi_fun = as_function(psi, "psi", [("y", ny), ("z_sharp", n_sharp), ("v", nv)], n_flat)
        z, g, u, w, v = (ca.SX.sym(s, k) for s, k in (("z", n_sharp), ("gamma", ny), ("u", nu), ("w", nw), ("v", nv)))
        x = T_inv_fun(ca.vertcat(psi_fun(g, z, v), z))
        z_next = T_fun(system.f(x, u, w))[n_flat:]
        dz_dw = ca.Function("dz_dw", [z, g, u, w, v], [ca.jacobian(z_next, w)])
        report = _assumption_report(system, T_fun, T_inv_fun, psi_fun, dz_dw, n_flat, check_points, seed)
        for label, value, condition in (
            ("T: the reduced dynamics T_sharp(f(x, u, w)) depend on w", report.w_sensitivity, W_FREE_REDUCED_DYNAMICS),
            ("T_inv: T_inv(T(x)) differs from x", report.inverse_error, "T_inv o T = id"),
            ("psi: psi(h(x, v), T_sharp(x), v) differs from T_flat(x)", report.psi_error, PSI_RECOVERY),
        ):
            if value > ASSUMPTION_TOL:
                raise ModelError(
                    f"{label} (largest relative violation {value:.2e} on sampled points), violating {condition}"
                )
        z_next = ca.substitute(z_next, w, ca.DM(system.nominal_w))
        f_sharp = ca.Function("f_sharp", [z, g, u, v], [z_next], ["z_sharp", "gamma", "u", "v"], ["z_sharp_next"])
        h_sharp = ca.Function("h_sharp", [z, g, v], [system.h(x, v)], ["z_sharp", "gamma", "v"], ["y"])
        note = ""
        if z_bounds is None and n_sharp == 0:
            box = Box(np.zeros(0), np.zeros(0))
        elif z_bounds is None:
            x_sym = ca.SX.sym("x", nx)
            T_sharp = ca.Function("T_sharp", [x_sym], [T_fun(x_sym)[n_flat:]])
            box, note = range_box(T_sharp, system.x.bounds, "T_sharp(X)", seed)
        else:
            box = Box.coerce(z_bounds, n_sharp, "z_bounds")
        return cls(system, int(n_flat), T_fun, T_inv_fun, psi_fun, f_sharp, h_sharp, box, note)

    def check_assumptions(self, n_points: int = 1000, seed: int = 0) -> AssumptionReport:
        """Largest violations of Assumption ass on random points, and the remark's dominance margin d."""
        n_points, seed = check_samples(n_points, "n_points"), check_seed(seed)
        z, g, u, w, v = (ca.SX.sym(s, k) for s, k in (("z", self.n_sharp), ("gamma", self.system.ny),
                         ("u", self.system.nu), ("w", self.system.nw), ("v", self.system.nv)))  # fmt: skip
        x = self.T_inv(ca.vertcat(self.psi(g, z, v), z))
        dz_dw = ca.Function("dz_dw", [z, g, u, w, v], [ca.jacobian(self.T(self.system.f(x, u, w))[self.n_flat :], w)])
        return _assumption_report(self.system, self.T, self.T_inv, self.psi, dz_dw, self.n_flat, n_points, seed)

    def full_state(self, y: FloatArray, z_sharp: FloatArray, v: FloatArray | None = None) -> FloatArray:
        """Eq. (26): ``x = T^-1(psi(y, z_sharp, v), z_sharp)`` (v defaults to the centre of V)."""
        system = self.system
        y, z_sharp = as_vector(y, system.ny, "y"), as_vector(z_sharp, self.n_sharp, "z_sharp")
        v = system.v.bounds.center if v is None else as_vector(v, system.nv, "v")
        z_flat = np.asarray(self.psi(y, z_sharp, v), dtype=float).reshape(-1)
        return np.asarray(self.T_inv(np.concatenate([z_flat, z_sharp])), dtype=float).reshape(-1)


def _assumption_report(
    system: System,
    T: ca.Function,
    T_inv: ca.Function,
    psi: ca.Function,
    dz_dw: ca.Function,
    n_flat: int,
    count: int,
    seed: int,
) -> AssumptionReport:
    rng = np.random.default_rng(seed)
    x = system.x.bounds.sample(rng, count) if system.x.bounds.is_bounded else rng.standard_normal((count, system.nx))
    v = lmi.finite_box(system.v.bounds, system.v.bounds.center, system.v.scale).sample(rng, count)
    u = lmi.finite_box(system.u.bounds, system.u.bounds.center, system.u.scale).sample(rng, count)
    w = system.nominal_w + system.w.scale * 10.0 ** rng.uniform(-3, 6, (count, system.nw)) * rng.choice(
        [-1, 1], (count, system.nw)
    )

    def run(fun: ca.Function, *cols: FloatArray) -> FloatArray:
        return np.asarray(fun.map(count)(*[c.T for c in cols]), dtype=float).reshape(-1, count).T

    z = run(T, x)
    inverse = float((np.abs(run(T_inv, z) - x) / (np.abs(x) + system.x.scale)).max())  # relative to |x|
    y = system.output(x, v)
    z_flat, z_sharp = z[:, :n_flat], z[:, n_flat:]
    flat_scale = np.maximum(np.abs(z_flat).max(axis=0), 1e-300) if n_flat else np.ones(0)
    psi_error = float((np.abs(run(psi, y, z_sharp, v) - z_flat) / flat_scale).max(initial=0.0))
    sharp_scale = np.maximum(np.abs(z_sharp).max(axis=0), 1e-300) if z_sharp.size else np.ones(0)
    jac = lmi.batched(dz_dw, [z_sharp, y, u, w, v])[0]
    w_sens = float((np.abs(jac) * system.w.scale[None, None, :] / sharp_scale[None, :, None]).max(initial=0.0))
    margin, outputs = _dominance(system, T_inv, z, v, n_flat)
    return AssumptionReport(
        inverse_error=inverse,
        psi_error=psi_error,
        w_sensitivity=w_sens,
        dominance_margin=margin,
        dominance_outputs=outputs,
        points=count,
    )


def _dominance(
    system: System, T_inv: ca.Function, z: FloatArray, v: FloatArray, n_flat: int
) -> tuple[float, tuple[int, ...]]:
    """The remark's diagonal-dominance margin d of ``dh_T / dz_flat`` for the best output choice."""
    if n_flat == 0:
        return float("inf"), ()
    if n_flat > system.ny:
        return float("nan"), ()
    zs, vs = ca.SX.sym("z", system.nx), ca.SX.sym("v", system.nv)
    jac = ca.Function("dhT", [zs, vs], [ca.jacobian(system.h(T_inv(zs), vs), zs[:n_flat])])
    H = lmi.batched(jac, [z, v])[0]  # (m, ny, n_flat)
    best: tuple[float, tuple[int, ...]] = (-np.inf, ())
    for outputs in itertools.permutations(range(system.ny), n_flat):
        rows = np.abs(H[:, list(outputs), :])  # (m, n_flat, n_flat)
        diagonal = np.diagonal(rows, axis1=1, axis2=2)
        margin = float((2.0 * diagonal - rows.sum(axis=2)).min())
        if margin > best[0]:
            best = (margin, tuple(outputs))
    return best


def reduce_quasi_state_affine(
    system: System,
    *,
    B: Any = None,
    C: Any = None,
    phi: Any = None,
    phi_inv: Any = None,
    rtol: float = 1e-9,
    w_spread: float = 100.0,
    **options: Any,
) -> ReducedModel:
    """The reduction of Proposition 4.4 of Guo et al. for systems of the form Eq. (19).

    ``x_bar = phi(x)`` with ``x_bar+ = f_1(x_bar, u) + B f_2(w, x_bar, u)`` and
    ``y = C x_bar + g(v)``. With ``r = rank(C B) = rank(B)``: ``S_flat`` selects the first r
    outputs (in their order) whose rows of ``C B`` are independent, so ``S_flat C B`` has full
    row rank r and z_flat are measured quantities (for the crop model ``z_flat = x^c``, the
    paper's choice; any S of the proof is valid, a selection keeps psi interpretable and makes
    gamma enter the reduced model only through the selected outputs), M the orthonormal basis of
    the orthogonal complement of im(B) as rows (``ker M = im B``), ``L = col(S_flat C, M)``
    (nonsingular), ``T(x) = L phi(x)``, ``T^-1(z) = phi^-1(L^-1 z)`` and
    ``psi(y, z_sharp, v) = S_flat (y - g(v))`` with ``g(v) = h(x_0, v) - C phi(x_0)`` at the
    centre x_0 of X (the checks of :meth:`ReducedModel.from_maps` confirm that h has this form).

    Parameters
    ----------
    system : System
        The model.
    B : array_like (nx, s), optional
        Default (only with phi = identity): an orthonormal basis of the span of ``df/dw``
        sampled over X x U x (nominal w +- w_spread scales).
    C : array_like (ny, nx), optional
        Default (only with phi = identity): the output Jacobian ``dh/dx``, which must be constant.
    phi, phi_inv : callable or casadi.Function, optional
        The diffeomorphism to quasi-state-affine coordinates and its inverse (default: identity).
    rtol : float
        Relative tolerance of the SVD ranks.
    w_spread : float
        Range of the w samples for the default B.
    **options
        Passed to :meth:`ReducedModel.from_maps`.

    Raises
    ------
    ModelError
        When ``rank(C B) != rank(B)``, or defaults are asked for in non-identity coordinates.

    """
    nx = system.nx
    if (phi is None) != (phi_inv is None):
        raise ModelError("phi, phi_inv: give both or neither")
    identity = phi is None
    phi_f = as_function(phi if phi is not None else (lambda x: x), "phi", [("x", nx)], nx)
    phi_inv_f = as_function(phi_inv if phi_inv is not None else (lambda z: z), "phi_inv", [("x_bar", nx)], nx)
    if (B is None or C is None) and not identity:
        raise ModelError("B, C: give both when phi is not the identity (the defaults are read from f and h)")
    if C is None:
        if not lmi.is_constant(system.jacobian_function, 3, [0, 1, 2, 3]):
            raise ModelError("C: dh/dx varies over the domain, so h is not C x + g(v); pass C and phi")
        C = np.asarray(system.linearize(system.x.bounds.center).C, dtype=float)
    C = np.asarray(C, dtype=float)
    if C.shape != (system.ny, nx):
        raise ModelError(f"C: expected shape ({system.ny}, {nx}), got {C.shape}")
    B = _default_B(system, w_spread, rtol) if B is None else np.asarray(B, dtype=float).reshape(nx, -1)
    rank_B = _rank(B, rtol)
    rank_CB = _rank(C @ B, rtol)
    if rank_CB != rank_B:
        raise ModelError(
            f"rank(C B) = {rank_CB} != rank(B) = {rank_B}: {QUASI_STATE_AFFINE_REDUCTION} needs the unknown "
            "input to reach the output within one step (matching condition); no reduction of this form exists"
        )
    r = rank_B
    S_flat = np.eye(system.ny)[_independent_rows(C @ B, r, rtol)]
    U_B = np.linalg.svd(B)[0] if B.size else np.eye(nx)
    M = U_B[:, r:].T
    L = np.vstack([S_flat @ C, M])
    L_inv = np.linalg.inv(L)
    x0 = system.x.bounds.center if system.x.bounds.is_bounded else np.zeros(nx)
    v = ca.SX.sym("v", system.nv)
    g = system.h(ca.DM(x0), v) - ca.DM(C @ np.asarray(phi_f(x0), dtype=float).reshape(-1))
    g_fun = ca.Function("g", [v], [g])
    x, z, y, zs = ca.SX.sym("x", nx), ca.SX.sym("z", nx), ca.SX.sym("y", system.ny), ca.SX.sym("zs", nx - r)
    T = ca.Function("T", [x], [ca.DM(L) @ phi_f(x)])
    T_inv = ca.Function("T_inv", [z], [phi_inv_f(ca.DM(L_inv) @ z)])
    psi = ca.Function("psi", [y, zs, v], [ca.DM(S_flat) @ (y - g_fun(v))])
    return ReducedModel.from_maps(system, T, T_inv, psi, n_flat=r, **options)


def _independent_rows(M: FloatArray, r: int, rtol: float) -> list[int]:
    """The first r row indices of M, in order, whose rows are linearly independent (greedy)."""
    chosen: list[int] = []
    threshold = rtol * max(float(np.linalg.norm(M, 2)), 1e-300)
    for i in range(M.shape[0]):
        if len(chosen) == r:
            break
        s = np.linalg.svd(M[[*chosen, i]], compute_uv=False)
        if int((s > threshold).sum()) > len(chosen):
            chosen.append(i)
    return chosen


def _rank(M: FloatArray, rtol: float) -> int:
    if M.size == 0:
        return 0
    s = np.linalg.svd(M, compute_uv=False)
    return int((s > rtol * max(s[0], 1e-300)).sum()) if s[0] > 0 else 0


def _default_B(system: System, w_spread: float, rtol: float) -> FloatArray:
    """Orthonormal basis (nx, s) of the span of df/dw over sampled X x U x W."""
    rng = np.random.default_rng(0)
    x = system.x.bounds.sample(rng, 200) if system.x.bounds.is_bounded else rng.standard_normal((200, system.nx))
    u = lmi.finite_box(system.u.bounds, system.u.bounds.center, system.u.scale).sample(rng, 200)
    w_box = lmi.finite_box(Box.unbounded(system.nw), system.nominal_w, w_spread * system.w.scale)
    w = w_box.sample(rng, 200)
    v = np.broadcast_to(system.v.bounds.center if system.v.bounds.is_bounded else np.zeros(system.nv), (200, system.nv))
    B_w = lmi.batched(system.jacobian_function, [x, u, w, v])[2]
    stacked = np.concatenate(list(B_w), axis=1)
    U, s, _ = np.linalg.svd(stacked, full_matrices=False)
    rank = int((s > rtol * s[0]).sum()) if s.size and s[0] > 0 else 0
    return U[:, :rank]
