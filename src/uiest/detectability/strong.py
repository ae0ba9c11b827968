r"""Strong nonlinear detectability certificates (theo:Lyapunov, eq:Lyapunov) by LMIs.

Storage ``V(x, x~) = |x - x~|_P^2`` and quadratic ``sigma_v``, ``sigma_y``. The condition
eq:Lyapunov_2 is

    |f(x,u,w) - f(x~,u,w~)|_P^2 <= mu |x - x~|_P^2 + sigma_v(|dv|) + sigma_v(|dv+|)
                                   + sigma_y(|dy|) + sigma_y(|dy+|)

for all w, w~ (unbounded). The LMI follows the paper's proof of lem:UIO_LTI: the unknown input
is eliminated with the next output. With increments ``dx+ = A dx + B dw``, ``dy = C dx + D dv``,
``dy+ = C dx+ + D dv+`` (the output Jacobians C, D must be constant: ``h(x, v) = C x + g(v)``
to first order everywhere), find ``P >= I`` and ``Y = [Y1, Y2]`` with

    P B = Y2 C B          (for every B in the domain; matching: rank(C B) = rank(B))
    [mu' P, (P A - Y1 C - Y2 C A)^T; P A - Y1 C - Y2 C A, P] >= 0   at every point.

Then ``dx+ = F dx + L1 (dy - D dv) + L2 (dy+ - D dv+)`` with ``L = P^-1 Y``,
``F = A - L1 C - L2 C A``, ``F^T P F <= mu' P``, and with ``(a+b)^2 <= (1+tau) a^2 + (1+1/tau) b^2``
and ``Y_j^T P^-1 Y_j <= t I``::

    V+ <= (1+tau) mu' V + 4 (1+1/tau) t (|dy|^2 + |dy+|^2 + |D dv|^2 + |D dv+|^2),

so ``mu = (1+tau) mu'``, ``sigma_y(r) = s_y r^2`` and ``sigma_v(r) = s_y |D|^2 r^2`` with
``s_y = 4 (1+1/tau) t`` (all in scaled coordinates). The equality is imposed exactly by the
parametrisation ``Y2 = P U (C U)^+ + Z (I - C U (C U)^+)`` with U an orthonormal basis of the span
of all sampled B. The LMI is affine in the Jacobian A for fixed (P, Y), so where it holds at
sampled Jacobians it holds on their convex hull, which contains the mean-value Jacobians of the
incremental argument; that the sampled Jacobians represent the whole domain is a sampled check
(grid with corners, cutting plane on a dense pool), not a proof.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import cvxpy as cp
import numpy as np

from uiest.box import Box, FloatArray
from uiest.detectability import lmi
from uiest.detectability.report import Verification
from uiest.errors import CertificationError, OptionError
from uiest.system import System

DESIGN_MARGIN = 1e-7
"""Smallest eigenvalue the solver must keep in each pointwise LMI, so that its tolerances do not
turn into a negative margin in the independent re-check (which must be >= 0 to certify)."""

MU_FLOOR = 1e-4
"""Lower end of the mu bisection: 'no invariant zeros' shows up as mu_min at this floor."""


@dataclass(frozen=True, eq=False)
class StrongDetectability:
    """A strong-detectability certificate (theo:Lyapunov) with quadratic storage.

    Norms are the scaled norms ``|S^-1 z|`` of each signal (``S = diag(signal.scale)``); the
    matrices in original units are given as well.

    Attributes
    ----------
    certified : bool
        True only when the LMIs were solved and the independent eigenvalue re-check holds on
        every active and pool point.
    reason : str
        Why (not) certified, with the numbers.
    mu : float
        Discount of eq:Lyapunov_2.
    mu_min : float
        Smallest feasible ``mu'`` found by bisection (the infimum of certifiable discounts).
    P : ndarray (nx, nx)
        Storage matrix in original units, ``V = |x - x~|_P^2``.
    P_scaled : ndarray (nx, nx)
        The same in scaled coordinates (``P_scaled >= I``).
    sigma_y, sigma_v : float
        ``sigma_y(r) = sigma_y r^2``, ``sigma_v(r) = sigma_v r^2`` in scaled norms.
    R_y, R_v : ndarray
        The same as weight matrices in original units: ``sigma_y(dy) = |dy|_{R_y}^2``.
    alpha_1, alpha_2 : float
        ``lambda_min(P)``, ``lambda_max(P)`` in original units.
    alpha_1_scaled, alpha_2_scaled : float
        The same for ``P_scaled`` (used by :meth:`min_horizon`).

    """

    system: System = field(repr=False)
    certified: bool
    reason: str
    mu: float
    mu_min: float
    P: FloatArray
    P_scaled: FloatArray
    sigma_y: float
    sigma_v: float
    R_y: FloatArray
    R_v: FloatArray
    tau: float
    solver_status: str
    solve_time: float
    margin: float
    n_active: int
    n_pool: int
    argument: str
    w_sampled: Box

    @property
    def alpha_1(self) -> float:
        """``lambda_min(P)`` (original units; NaN when not certified)."""
        return _eig(self.P, 0)

    @property
    def alpha_2(self) -> float:
        """``lambda_max(P)`` (original units; NaN when not certified)."""
        return _eig(self.P, -1)

    @property
    def alpha_1_scaled(self) -> float:
        """``lambda_min(P_scaled)``."""
        return _eig(self.P_scaled, 0)

    @property
    def alpha_2_scaled(self) -> float:
        """``lambda_max(P_scaled)``."""
        return _eig(self.P_scaled, -1)

    @property
    def condition(self) -> float:
        """Condition number of ``P_scaled``."""
        return self.alpha_2_scaled / self.alpha_1_scaled

    def min_horizon(self) -> int:
        r"""Smallest N satisfying eq:MHE_full_horizon for the quadratic alphas.

        With ``alpha_1(r) = a1 r^2`` and ``alpha_2(r) = a2 r^2`` (scaled norm),
        ``alpha_1^-1(s) = sqrt(s / a1)`` and
        ``(2 mu^N alpha_2 o 2 alpha_1^-1)(r) = 2 mu^N a2 (2 sqrt(r / a1))^2 = 8 mu^N (a2 / a1) r``.
        This is ``< rho r`` for some ``rho < 1`` iff ``8 mu^N a2 / a1 < 1``, i.e.
        ``N > log(8 a2 / a1) / log(1 / mu)``.
        """
        if not self.certified:
            raise CertificationError(f"min_horizon: the certificate does not hold ({self.reason})")
        bound = np.log(8.0 * self.condition) / np.log(1.0 / self.mu)
        return int(np.floor(bound)) + 1

    def verify(self, n_pairs: int = 20_000, seed: int = 0, w_spread: float = 1e3) -> Verification:
        """Test eq:Lyapunov_2 on random pairs of one-step data (nonlinear f and h, not Jacobians).

        Pairs ``(x, x~)`` in X, ``u`` in U, ``w, w~ = nominal_w +- scale * 10^U(-3, log10(w_spread))``,
        ``v, v~, v+, v~+`` in V; pairs whose successors leave X are discarded. Reports the worst
        ratio ``LHS / RHS`` (<= 1 means the inequality held on every pair).
        """
        return _verify(self, n_pairs, seed, w_spread)

    def to_dict(self) -> dict[str, object]:
        """Plain-data form for JSON."""
        return {
            "kind": "strong_detectability",
            "system": self.system.name,
            "certified": self.certified,
            "reason": self.reason,
            "mu": self.mu,
            "mu_min": self.mu_min,
            "tau": self.tau,
            "P": self.P.tolist(),
            "P_scaled": self.P_scaled.tolist(),
            "sigma_y": self.sigma_y,
            "sigma_v": self.sigma_v,
            "R_y": self.R_y.tolist(),
            "R_v": self.R_v.tolist(),
            "alpha_1": self.alpha_1,
            "alpha_2": self.alpha_2,
            "condition_scaled": self.condition,
            "min_horizon": self.min_horizon() if self.certified else None,
            "solver_status": self.solver_status,
            "solve_time_s": self.solve_time,
            "margin": self.margin,
            "n_active": self.n_active,
            "n_pool": self.n_pool,
            "argument": self.argument,
            "w_sampled": self.w_sampled.to_dict(),
        }


def _eig(matrix: FloatArray, index: int) -> float:
    if not np.all(np.isfinite(matrix)):
        return float("nan")
    return float(np.linalg.eigvalsh(matrix)[index])


@dataclass
class _Data:
    """Scaled Jacobians at m points: A (m, n, n), B (m, n, q); C (p, n), D (p, r) constant."""

    A: FloatArray
    B: FloatArray
    C: FloatArray
    D: FloatArray


def _scaled_jacobians(system: System, points: FloatArray) -> _Data:
    nx, nu = system.nx, system.nu
    x, u, w = points[:, :nx], points[:, nx : nx + nu], points[:, nx + nu :]
    v = np.broadcast_to(system.v.bounds.center, (len(points), system.nv))
    A, _, B, C, D = lmi.batched(system.jacobian_function, [x, u, w, v])
    sx, sw, sv, sy = (s.scale for s in (system.x, system.w, system.v, system.y))
    return _Data(
        A=A * sx[None, None, :] / sx[None, :, None],
        B=B * sw[None, None, :] / sx[None, :, None],
        C=C[0] * sx[None, :] / sy[:, None],
        D=D[0] * sv[None, :] / sy[:, None],
    )


class _Problem:
    """The LMI of the module docstring on a fixed set of points, with mu' as a Parameter.

    Conditioning: with ``Y1' = Y1 + Y2`` the LMI reads ``P A - Y1' C - Y2 C (A - I)``. Slow
    sampled systems have a tiny ``C (A - I)`` (the crop model: ~1e-5), so ``Y2`` must be huge;
    ``Y2 = P U (C U)^+ + gamma Z~ Pi`` with ``gamma = 1 / max |C (A_i - I)|`` keeps every
    decision variable of order one. The gain LMI bounds the scaled variables ``(Y1', Z~)``
    (a regulariser); the true gains are recomputed from ``(Y1, Y2)`` afterwards.
    """

    def __init__(self, data: _Data, basis: FloatArray, kappa_max: float) -> None:
        n, p = data.A.shape[1], data.C.shape[0]
        C = data.C
        CU = C @ basis
        CU_pinv = np.linalg.pinv(CU)
        projector = np.eye(p) - CU @ CU_pinv
        increments = np.einsum("ij,mjk->mik", C, data.A - np.eye(n)[None])
        self.gamma = 1.0 / max(float(np.abs(increments).max()), 1e-12)
        self.mu = cp.Parameter(nonneg=True, value=0.5)
        self.kappa_cap = cp.Parameter(nonneg=True, value=kappa_max)
        self.weight_t = cp.Parameter(nonneg=True, value=0.0)
        self.P = cp.Variable((n, n), symmetric=True)
        self.Y1_shifted = cp.Variable((n, p))
        self.Z = cp.Variable((n, p))
        self.kappa = cp.Variable(nonneg=True)
        self.t = cp.Variable(nonneg=True)
        matched = self.P @ basis @ CU_pinv
        constraints = [self.P >> np.eye(n), self.P << self.kappa * np.eye(n), self.kappa <= self.kappa_cap]
        for A, inc in zip(data.A, increments, strict=True):
            PF = self.P @ A - self.Y1_shifted @ C - matched @ inc - self.Z @ (projector @ (self.gamma * inc))
            constraints.append(
                lmi.symmetric(cp.bmat([[self.mu * self.P, PF.T], [PF, self.P]])) >> DESIGN_MARGIN * np.eye(2 * n)
            )
        Y = cp.hstack([self.Y1_shifted, self.Z])
        constraints.append(lmi.symmetric(cp.bmat([[self.t * np.eye(2 * p), Y.T], [Y, self.P]])) >> 0)
        self.problem = cp.Problem(cp.Minimize(self.kappa + self.weight_t * self.t), constraints)
        self.C = C
        self._basis_term = basis @ CU_pinv
        self._projector = projector

    @property
    def Y2(self) -> FloatArray:
        """``Y2 = P U (C U)^+ + gamma Z~ Pi`` from the solution."""
        return self.P.value @ self._basis_term + self.gamma * self.Z.value @ self._projector

    @property
    def Y1(self) -> FloatArray:
        """``Y1 = Y1' - Y2`` from the solution."""
        return self.Y1_shifted.value - self.Y2

    def solve(self, mu: float, weight_t: float = 0.0, kappa_cap: float | None = None) -> str:
        self.mu.value = mu
        self.weight_t.value = weight_t
        if kappa_cap is not None:
            self.kappa_cap.value = kappa_cap
        return lmi.solve(self.problem)

    def feasible(self, mu: float) -> bool:
        """Whether the LMI is solved to optimality at discount ``mu``."""
        return self.solve(mu) in lmi.OK_STATUSES

    def margins(self, data: _Data, mu: float) -> FloatArray:
        """Independent re-check: min eig of ``mu P - PF^T P^-1 PF`` per point (scaled by 1/|P|)."""
        P, Y1, Y2 = self.P.value, self.Y1, self.Y2
        G = P - Y2 @ self.C
        PF = np.einsum("ij,mjk->mik", G, data.A) - (Y1 @ self.C)[None]
        P_inv = np.linalg.inv(P)
        M = mu * P[None] - np.einsum("mji,jk,mkl->mil", PF, P_inv, PF)
        return lmi.min_eig(M) / np.linalg.eigvalsh(P)[-1]

    def gain(self) -> float:
        """``max_j lambda_max(Y_j^T P^-1 Y_j)`` recomputed from the solution."""
        P_inv = np.linalg.inv(self.P.value)
        return max(float(np.linalg.eigvalsh(Y.T @ P_inv @ Y)[-1]) for Y in (self.Y1, self.Y2))


def certify_strong_detectability(
    system: System,
    *,
    mu: float | None = None,
    grid: int = 3,
    pool_grid: int = 7,
    pool_random: int = 2000,
    w_spread: float = 100.0,
    kappa_max: float = 1e6,
    tol: float = 1e-4,
    max_rounds: int = 6,
    seed: int = 0,
) -> StrongDetectability:
    """Certify strong nonlinear detectability of ``system`` (theo:Lyapunov) by LMIs.

    Parameters
    ----------
    system : System
        Needs a bounded X and an output whose Jacobians in x and v are constant.
    mu : float, optional
        Discount to certify. None: minimise ``mu'`` by bisection and use
        ``mu = min(2 mu', (1 + mu') / 2)`` (``tau = 1`` where possible).
    grid, pool_grid, pool_random : int
        Points per axis of the active grid (corners included), of the dense re-check grid, and
        the number of uniform pool samples over X x U x W.
    w_spread : float
        The Jacobians are sampled for ``w`` in ``nominal_w +- w_spread * w.scale`` (w itself is
        unbounded; the pool adds points at ``+-1e6`` scales to expose any w-dependence).
    kappa_max : float
        Cap on the condition number of ``P_scaled``.
    tol : float
        Bisection tolerance on ``mu'``.
    max_rounds : int
        Cutting-plane rounds.
    seed : int
        Seed of the pool samples.

    """
    start = time.perf_counter()
    if mu is not None and not 0.0 < mu < 1.0:
        raise OptionError(f"mu: expected a number in (0, 1), got {mu!r}")
    w_box = lmi.sampling_box(Box.unbounded(system.nw), system.nominal_w, w_spread * system.w.scale)
    fail = _failure(system, w_box, start)
    if not system.x.bounds.is_bounded:
        return fail(f"X must be bounded to grid the Jacobians, got {system.x.bounds}")
    if not lmi.is_constant(system.jacobian_function, 3, [0, 1, 2, 3]) or not lmi.is_constant(
        system.jacobian_function, 4, [0, 1, 2, 3]
    ):
        return fail("the output Jacobians dh/dx, dh/dv vary over the domain; only h(x, v) = C x + g(v) is supported")
    u_box = lmi.sampling_box(system.u.bounds, system.u.bounds.center, system.u.scale)
    domain = Box(np.concatenate([system.x.bounds.lower, u_box.lower, w_box.lower]),
                 np.concatenate([system.x.bounds.upper, u_box.upper, w_box.upper]))  # fmt: skip
    active_pts, pool_pts = lmi.point_sets(domain, grid, pool_grid, pool_random, seed)
    extreme = pool_pts.values[:: max(1, len(pool_pts.values) // 200)].copy()
    extreme[:, system.nx + system.nu :] = system.nominal_w + 1e6 * system.w.scale * np.sign(
        np.random.default_rng(seed).standard_normal((len(extreme), system.nw))
    )
    pool = _scaled_jacobians(system, np.vstack([pool_pts.values, extreme]))
    active = active_pts.values
    basis = _range_basis(np.concatenate([_scaled_jacobians(system, active).B, pool.B], axis=0))
    if (
        basis.shape[1]
        and np.linalg.matrix_rank(pool.C @ basis, tol=1e-9 * max(1.0, np.abs(pool.C).max())) < basis.shape[1]
    ):
        return fail(f"matching fails: rank(C B) < rank(B) = {basis.shape[1]} on the sampled domain")

    for _round in range(max_rounds):
        data = _scaled_jacobians(system, active)
        problem = _Problem(data, basis, kappa_max)
        mu_min = lmi.bisect_discount(problem.feasible, MU_FLOOR, tol)
        if mu_min is None:
            return fail("infeasible for every mu < 1: no quadratic storage certifies strong detectability")
        mu_used = mu if mu is not None else min(2.0 * mu_min, 0.5 * (1.0 + mu_min))
        if mu_used <= mu_min:
            return fail(f"mu={mu_used} is below the smallest certifiable discount mu_min={mu_min:.4g}", mu_min)
        status, mu_prime = _best_split(problem, mu_used, mu_min)
        if status not in lmi.OK_STATUSES:
            return fail(f"final solve at mu={mu_used:.6g} (mu_min={mu_min:.6g}) returned {status}", mu_min)
        pool_margin = problem.margins(pool, mu_prime)
        if pool_margin.min() >= 0.0:
            break
        worst = np.argsort(pool_margin)[:10]
        active = np.vstack([active, np.vstack([pool_pts.values, extreme])[worst]])
    active_margin = problem.margins(data, mu_prime).min()
    margin = float(min(active_margin, pool_margin.min()))
    tau = mu_used / mu_prime - 1.0
    s_y = 4.0 * (1.0 + 1.0 / tau) * problem.gain()
    certified = margin >= 0.0
    sx, sy, sv = system.x.scale, system.y.scale, system.v.scale
    D = pool.D
    P_scaled = problem.P.value
    return StrongDetectability(
        system=system,
        certified=certified,
        reason=(
            f"certified: mu={mu_used:.4g} (mu'={mu_prime:.4g}, tau={tau:.3g}), re-check margin {margin:.2e}"
            if certified
            else f"re-check failed: worst eigenvalue margin {margin:.2e} after {max_rounds} cutting-plane rounds"
        ),
        mu=float(mu_used),
        mu_min=float(mu_min),
        P=P_scaled / np.outer(sx, sx),
        P_scaled=P_scaled,
        sigma_y=float(s_y),
        sigma_v=float(s_y * np.linalg.norm(D, 2) ** 2),
        R_y=s_y * np.diag(1.0 / sy**2),
        R_v=s_y * (D.T @ D) / np.outer(sv, sv),
        tau=float(tau),
        solver_status=status,
        solve_time=time.perf_counter() - start,
        margin=margin,
        n_active=len(active),
        n_pool=len(pool.A),
        argument=(
            "Schur form affine in the Jacobian A with constant output Jacobians: the pointwise LMIs "
            "hold on the convex hull of the checked Jacobians; domain coverage is a sampled check "
            f"({active_pts.description} + cutting plane; pool: {pool_pts.description} "
            f"+ {len(extreme)} points at w = +-1e6 scales)"
        ),
        w_sampled=w_box,
    )


def _best_split(problem: _Problem, mu: float, mu_min: float) -> tuple[str, float]:
    """Choose mu' in (mu_min, mu) minimising s_y = 4 (1 + 1/tau) t; leaves the best solution loaded."""
    best: tuple[float, float] | None = None
    for frac in (0.2, 0.4, 0.6, 0.8):
        mu_prime = mu_min + frac * (mu - mu_min)
        if problem.solve(mu_prime) not in lmi.OK_STATUSES:
            continue
        kappa = float(problem.kappa.value)
        if problem.solve(mu_prime, weight_t=1.0, kappa_cap=2.0 * kappa) not in lmi.OK_STATUSES:
            continue
        score = (1.0 + 1.0 / (mu / mu_prime - 1.0)) * problem.gain()
        if best is None or score < best[0]:
            best = (score, mu_prime)
    if best is None:
        return "infeasible", mu
    mu_prime = best[1]
    problem.solve(mu_prime)
    status = problem.solve(mu_prime, weight_t=1.0, kappa_cap=2.0 * float(problem.kappa.value))
    return status, mu_prime


def _range_basis(B: FloatArray) -> FloatArray:
    """Orthonormal basis (n, l) of the span of all B_i (m, n, q), SVD rank with tolerance 1e-9."""
    stacked = np.concatenate(list(B), axis=1) if B.size else np.zeros((B.shape[1], 0))
    if stacked.size == 0:
        return np.zeros((B.shape[1], 0))
    U, s, _ = np.linalg.svd(stacked, full_matrices=False)
    rank = int((s > 1e-9 * s[0]).sum()) if s.size and s[0] > 0 else 0
    return U[:, :rank]


def _failure(system: System, w_box: Box, start: float):  # type: ignore[no-untyped-def]
    """A factory of uncertified results carrying the reason."""

    def fail(reason: str, mu_min: float = float("nan")) -> StrongDetectability:
        n = system.nx
        return StrongDetectability(
            system=system,
            certified=False,
            reason=reason,
            mu=float("nan"),
            mu_min=mu_min,
            P=np.full((n, n), np.nan),
            P_scaled=np.full((n, n), np.nan),
            sigma_y=float("nan"),
            sigma_v=float("nan"),
            R_y=np.full((system.ny, system.ny), np.nan),
            R_v=np.full((system.nv, system.nv), np.nan),
            tau=float("nan"),
            solver_status="not solved" if np.isnan(mu_min) else "infeasible",
            solve_time=time.perf_counter() - start,
            margin=float("nan"),
            n_active=0,
            n_pool=0,
            argument="",
            w_sampled=w_box,
        )

    return fail


def _spread_samples(
    rng: np.random.Generator, center: FloatArray, scale: FloatArray, spread: float, count: int
) -> FloatArray:
    """``center + scale * s * 10^U(-3, log10(spread))`` with random signs s: small and huge values."""
    size = (count, center.size)
    magnitude = 10.0 ** rng.uniform(-3.0, np.log10(spread), size=size)
    return center + scale * magnitude * rng.choice([-1.0, 1.0], size=size)


def _verify(cert: StrongDetectability, n_pairs: int, seed: int, w_spread: float) -> Verification:
    system = cert.system
    if not cert.certified:
        return Verification(worst_ratio=float("nan"), pairs_used=0, pairs_drawn=0, note=cert.reason)
    rng = np.random.default_rng(seed)
    X, V = system.x.bounds, system.v.bounds
    u_box = lmi.sampling_box(system.u.bounds, system.u.bounds.center, system.u.scale)
    v_box = lmi.sampling_box(V, V.center, system.v.scale)
    x, xt = X.sample(rng, n_pairs), X.sample(rng, n_pairs)
    # half the pairs close together: the incremental inequality is tightest for small increments
    close = rng.random(n_pairs) < 0.5
    xt[close] = X.clip(x[close] + 1e-3 * system.x.scale * rng.standard_normal((close.sum(), system.nx)))
    u = u_box.sample(rng, n_pairs)
    w, wt = (_spread_samples(rng, system.nominal_w, system.w.scale, w_spread, n_pairs) for _ in range(2))
    v, vt, vp, vtp = (v_box.sample(rng, n_pairs) for _ in range(4))
    xp, xtp = system.step(x, u, w), system.step(xt, u, wt)
    keep = X.contains(xp) & X.contains(xtp)
    if not keep.any():
        return Verification(float("nan"), 0, n_pairs, "no sampled pair stayed in X")
    sel = [a[keep] for a in (x, xt, xp, xtp, v, vt, vp, vtp)]
    x, xt, xp, xtp, v, vt, vp, vtp = sel
    dy = system.output(x, v) - system.output(xt, vt)
    dyp = system.output(xp, vp) - system.output(xtp, vtp)

    def quad(d: FloatArray, W: FloatArray) -> FloatArray:
        return np.einsum("mi,ij,mj->m", d, W, d)

    lhs = quad(xp - xtp, cert.P)
    rhs = cert.mu * quad(x - xt, cert.P)
    rhs += quad(v - vt, cert.R_v) + quad(vp - vtp, cert.R_v) + quad(dy, cert.R_y) + quad(dyp, cert.R_y)
    ratio = lhs / np.maximum(rhs, 1e-300)
    return Verification(float(ratio.max()), int(keep.sum()), n_pairs, "ratio = LHS / RHS of eq:Lyapunov_2")
