r"""Quadratic incremental dissipation inequalities by LMIs: the engine of the i-IOSS certificates.

A one-step model ``z+ = F(z, u, d)``, ``y = H(z, d)`` with a known input ``u`` (equal in both
trajectories) and a disturbance ``d`` made of named channels ``d = (d_1, ..., d_c)``. In scaled
coordinates (``z = S_z z~`` and so on) find ``P >= I`` (full, or ``p I``), channel weights
``q_c >= 0`` and an output weight ``r >= 0`` such that, for all pairs in the domain,

    |F(z,u,d) - F(z~,u,d~)|_P^2 <= mu |z - z~|_P^2 + sum_c q_c |d_c - d~_c|^2 + r |H(z,d) - H(z~,d~)|^2.

With ``J = dF/d(z, d)`` and ``G = dH/d(z, d)`` the pointwise condition is

    M(J, G) = blkdiag(mu P, q_1 I, ..., q_c I) + r G^T G - J^T P J >= 0,

linear in the decision variables (J and G are data). It is equivalent to the Schur form
``[blkdiag(mu P, q I) + r G^T G, J^T P; P J, P] >= 0`` of Schiller et al.'s Corollary 3, which is
affine in J; so the set of J where it holds is convex and where it holds at the sampled
Jacobians it holds on their convex hull, which contains the mean-value Jacobians of the
incremental argument (``F(a) - F(b) = (int_0^1 J(b + s(a - b)) ds) (a - b)``, the segment lying
in the convex domain). If G is constant the same argument covers the output term; if G varies,
``r G^T G`` is convex in G and the pointwise LMI is a sampled check only. The form ``M`` (rather
than the Schur form) is what the solver sees: for slow sampled systems (``J ~ I``, ``mu ~ 1``)
the Schur block is nearly singular and interior-point solvers lose the margin ``(1 - mu) P`` in
their tolerances, while ``M`` carries it directly. That the sampled Jacobians represent the
whole domain is a sampled check either way (grid with corners over the axes the Jacobians
depend on, cutting plane on a dense pool), not a proof. This is the LMI of Schiller et al. 2023,
Corollary 3, eq. (33), and the quadratic form of the paper's ass:e-ioss.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import casadi as ca
import cvxpy as cp
import numpy as np

from uiest.box import Box, FloatArray
from uiest.detectability import lmi
from uiest.errors import OptionError

MU_FLOOR = 1e-4
"""Lower end of the discount bisection."""

STRUCTURES = ("full", "identity")

ACCEPTED = ("optimal", "optimal_inaccurate")
"""Statuses whose solution is passed to the eigenvalue re-check, which alone decides certification."""

MARGIN_FLOOR = 1e-9
"""Smallest margin ``t*`` of the margin problem that counts as feasible (P >= I normalises it)."""

GAIN_REGULARISATION = 1e-6
"""Weight of ``sum q + r`` while minimising the condition number: without it the optimal face is
unbounded in the gains and interior-point solvers end 'inaccurate'."""


@dataclass(frozen=True, eq=False)
class IncrementalModel:
    """``z+ = step(z, u, d)``, ``y = output(z, d)`` with finite sampling boxes and scales.

    Attributes
    ----------
    step : casadi.Function
        ``(z (n,), u (nu,), d (nd,)) -> z+ (n,)``.
    output : casadi.Function
        ``(z (n,), d (nd,)) -> y (p,)``.
    z_box, u_box, d_box : Box
        Finite boxes over which the Jacobians are sampled (the domain of the certificate).
    z_scale, d_scale, y_scale : ndarray
        Positive nominal magnitudes; the LMI is solved in ``z / z_scale`` etc.
    channels : tuple of (str, int)
        Names and sizes partitioning ``d``; each channel gets one scalar weight.

    """

    step: ca.Function
    output: ca.Function
    z_box: Box
    u_box: Box
    d_box: Box
    z_scale: FloatArray
    d_scale: FloatArray
    y_scale: FloatArray
    channels: tuple[tuple[str, int], ...]

    @property
    def n(self) -> int:
        """State dimension."""
        return self.z_box.size

    @property
    def nd(self) -> int:
        """Disturbance dimension."""
        return self.d_box.size

    @property
    def domain(self) -> Box:
        """The product box ``Z x U x D`` of sample points, columns ordered (z, u, d)."""
        return Box(
            np.concatenate([self.z_box.lower, self.u_box.lower, self.d_box.lower]),
            np.concatenate([self.z_box.upper, self.u_box.upper, self.d_box.upper]),
        )

    def jacobian_function(self) -> ca.Function:
        """``(z, u, d) -> (J, G)``, both in scaled coordinates: J (n, n + nd), G (p, n + nd)."""
        z, u, d = (ca.SX.sym(s, k) for s, k in (("z", self.n), ("u", self.u_box.size), ("d", self.nd)))
        zd = ca.vertcat(z, d)
        col_scale = np.concatenate([self.z_scale, self.d_scale])
        J = ca.diag(1.0 / self.z_scale) @ ca.jacobian(self.step(z, u, d), zd) @ ca.diag(col_scale)
        G = ca.diag(1.0 / self.y_scale) @ ca.jacobian(self.output(z, d), zd) @ ca.diag(col_scale)
        return ca.Function("scaled_jacobians", [z, u, d], [J, G])

    def jacobians(self, points: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Scaled Jacobians at points (m, n + nu + nd): J (m, n, n + nd), G (m, p, n + nd)."""
        n, nu = self.n, self.u_box.size
        J, G = lmi.batched(self.jacobian_function(), [points[:, :n], points[:, n : n + nu], points[:, n + nu :]])
        return J, G


@dataclass(frozen=True, eq=False)
class Solution:
    """Outcome of :func:`solve`, in scaled coordinates.

    Attributes
    ----------
    certified : bool
        LMIs solved to optimality and the eigenvalue re-check holds on every active and pool point.
    reason : str
        Why (not) certified, with the numbers.
    mu, mu_min : float
        Discount used, and the smallest feasible discount found by bisection.
    P : ndarray (n, n)
        Scaled storage matrix (``P >= I``); NaN when not solved.
    q : ndarray (c,)
        Scaled channel weights.
    r : float
        Scaled output weight.
    status : str
        Final solver status.
    margin : float
        Smallest eigenvalue of the Schur complement over all checked points, divided by |P|.
    n_active, n_pool : int
        Points in the LMI and in the re-check pool.
    argument : str
        Which argument makes the pointwise LMIs cover the domain.

    """

    certified: bool
    reason: str
    mu: float
    mu_min: float
    P: FloatArray
    q: FloatArray
    r: float
    status: str
    margin: float
    n_active: int
    n_pool: int
    argument: str

    @property
    def condition(self) -> float:
        """Condition number of P (NaN when not solved)."""
        if not np.all(np.isfinite(self.P)):
            return float("nan")
        eig = np.linalg.eigvalsh(self.P)
        return float(eig[-1] / eig[0])


class SolvedCertificate:
    """The accessors every certificate built on a :class:`Solution` shares (it holds ``solution``)."""

    solution: Solution

    @property
    def certified(self) -> bool:
        """Whether the certificate holds (solved and re-checked)."""
        return self.solution.certified

    @property
    def reason(self) -> str:
        """Why (not) certified."""
        return self.solution.reason


class _Problem:
    """The LMI ``M(J_i, G_i) >= t I`` on a fixed set of points, normalised by ``P <= I``.

    The LMI is homogeneous in ``(P, q, r)``; normalising the largest eigenvalue of P (rather than
    the smallest) keeps every variable of order one, which interior-point solvers need to
    resolve margins of order ``(1 - mu)`` (about 1e-5 for the crop model). Three problems share
    the variables; mu, the required margin, the lower bound on P and the weight are Parameters
    (bisection re-solves without recompiling):

    - ``margin``: maximise t with ``I / kappa_max <= P`` and the gains at most ``gain_max``;
      feasible at mu iff ``t* > 0``.
    - ``conditioning``: with ``t >= t_req``, maximise s with ``P >= s I`` (minimises the condition
      number ``1 / s``).
    - ``gains``: with ``t >= t_req`` and ``P >= s_req I``, minimise ``sum q + r``.
    """

    def __init__(
        self, J: FloatArray, G: FloatArray, channels: Sequence[int], structure: str, kappa_max: float, gain_max: float
    ) -> None:
        n = J.shape[1]
        self.mu = cp.Parameter(nonneg=True, value=0.5)
        self.t_req = cp.Parameter(nonneg=True, value=0.0)
        self.s_req = cp.Parameter(nonneg=True, value=1.0 / kappa_max)
        if structure == "full":
            self.P = cp.Variable((n, n), symmetric=True)
            P = self.P
        else:
            self.P = cp.Variable(nonneg=True)
            P = self.P * np.eye(n)
        self.q = cp.Variable(len(channels), nonneg=True)
        self.r = cp.Variable(nonneg=True)
        self.t = cp.Variable()
        self.s = cp.Variable()
        weights = [self.q[i] * np.ones(size) for i, size in enumerate(channels) if size]
        D = cp.diag(cp.hstack(weights)) if weights else None
        common = [P << np.eye(n), P >> np.eye(n) / kappa_max, self.q <= gain_max, self.r <= gain_max]
        nd = J.shape[2] - n
        zero = np.zeros((n, nd))
        for Ji, Gi in zip(J, G, strict=True):
            top = self.mu * P if D is None else cp.bmat([[self.mu * P, zero], [zero.T, D]])
            M = top + self.r * (Gi.T @ Gi) - Ji.T @ P @ Ji
            common.append(lmi.symmetric(M) >> self.t * np.eye(n + nd))
        self.margin_problem = cp.Problem(cp.Maximize(self.t), common)
        designed = [*common, self.t >= self.t_req, P >> self.s * np.eye(n)]
        self.conditioning_problem = cp.Problem(
            cp.Maximize(self.s - GAIN_REGULARISATION * (cp.sum(self.q) + self.r)), designed
        )
        self.gains_problem = cp.Problem(cp.Minimize(cp.sum(self.q) + self.r), [*designed, self.s >= self.s_req])
        self.n = n

    def feasible(self, mu: float) -> bool:
        """Whether the LMI is strictly feasible at discount ``mu`` (margin problem, ``t* > 0``)."""
        self.mu.value = mu
        status = lmi.solve(self.margin_problem)
        return status in ACCEPTED and self.t.value is not None and float(self.t.value) > MARGIN_FLOOR

    def values(self) -> tuple[FloatArray, FloatArray, float]:
        """(P, q, r) of the last solution rescaled to ``lambda_min(P) = 1``, P as an (n, n) matrix."""
        P = self.P.value if self.P.ndim == 2 else float(self.P.value) * np.eye(self.n)
        P = np.asarray(P, dtype=float)
        low = float(np.linalg.eigvalsh(0.5 * (P + P.T))[0])
        q = np.asarray(self.q.value, dtype=float).reshape(-1)
        return P / low, q / low, float(self.r.value) / low


def margins(
    J: FloatArray, G: FloatArray, P: FloatArray, q: FloatArray, r: float, channels: Sequence[int], mu: float
) -> FloatArray:
    """Independent re-check: min eig of ``blkdiag(mu P, q I) + r G^T G - J^T P J`` per point, over |P|.

    Shapes: J (m, n, n + nd), G (m, p, n + nd); returns (m,).
    """
    n = P.shape[0]
    top = np.zeros((J.shape[2], J.shape[2]))
    top[:n, :n] = mu * P
    top[n:, n:] = np.diag(np.repeat(q, channels)) if len(channels) else np.zeros((0, 0))
    M = top[None] + r * np.einsum("mji,mjk->mik", G, G) - np.einsum("mji,jk,mkl->mil", J, P, J)
    return lmi.min_eig(M) / np.linalg.eigvalsh(P)[-1]


def relevant_axes(model: IncrementalModel) -> FloatArray:
    """Boolean mask over the (z, u, d) columns: the axes the scaled Jacobians depend on (structurally)."""
    fun = model.jacobian_function()
    syms = [ca.SX.sym(f"a{i}", fun.size_in(i)) for i in range(3)]
    outs = ca.vertcat(*[ca.vec(o) for o in fun(*syms)])
    mask = []
    for sym in syms:
        mask.extend(bool(ca.depends_on(outs, sym[j])) for j in range(sym.numel()))
    return np.array(mask, dtype=bool)


def _restricted(box: Box, mask: FloatArray) -> Box:
    """``box`` collapsed to its centre on the axes outside ``mask``."""
    center = box.center
    return Box(np.where(mask, box.lower, center), np.where(mask, box.upper, center))


def solve(
    model: IncrementalModel,
    *,
    mu: float | None,
    structure: str = "full",
    grid: int = 3,
    pool_grid: int = 7,
    pool_random: int = 2000,
    max_pool_grid: int = 5000,
    kappa_max: float = 1e6,
    gain_max: float = 1e4,
    kappa_slack: float = 1.1,
    tol: float = 1e-4,
    max_rounds: int = 6,
    seed: int = 0,
) -> Solution:
    """Find (P, q, r) of the module docstring by bisection on mu and a cutting plane.

    The active set starts as a ``grid``-point grid (corners included) over the axes the
    Jacobians depend on; the pool is a ``pool_grid``-point grid (coarsened so that it has at
    most ``max_pool_grid`` points) plus ``pool_random`` uniform samples of the whole domain.
    The discount is the given ``mu`` or ``min(2 mu_min, (1 + mu_min) / 2)``; at that discount
    the condition number ``kappa`` of P is minimised, then the gains ``sum q + r`` subject to
    ``kappa <= kappa_slack * kappa_min``.
    """
    if structure not in STRUCTURES:
        raise OptionError(f"structure: expected one of {STRUCTURES}, got {structure!r}")
    if mu is not None and not 0.0 < mu < 1.0:
        raise OptionError(f"mu: expected a number in (0, 1), got {mu!r}")
    channels = [size for _, size in model.channels]
    mask = relevant_axes(model)
    box = _restricted(model.domain, mask)
    dims = max(1, int(np.count_nonzero(mask & (box.width > 0))))
    fine = max(2, min(pool_grid, math.floor(max_pool_grid ** (1.0 / dims))))
    active_pts, pool_pts = lmi.point_sets(box, grid, fine, 0, seed)
    rng = np.random.default_rng(seed)
    pool_values = np.vstack([pool_pts.values, model.domain.sample(rng, pool_random)])
    J_pool, G_pool = model.jacobians(pool_values)
    constant_output = bool(np.ptp(G_pool, axis=0).max(initial=0.0) <= 1e-12 * max(1.0, np.abs(G_pool).max()))
    argument = (
        ("Schur form affine in the Jacobians with a constant output Jacobian: " if constant_output else
         "the output Jacobian varies, so r G'G is not affine in it: pointwise LMIs are a sampled check only; ")
        + f"domain coverage is a sampled check (active: {active_pts.description}, over the "
        f"{int(mask.sum())} axes the Jacobians depend on, + cutting plane; pool: {fine}-point grid + "
        f"{pool_random} uniform samples, {len(pool_values)} points)"
    )  # fmt: skip
    active = active_pts.values

    def fail(reason: str, mu_min: float = float("nan"), status: str = "not solved") -> Solution:
        n = model.n
        return Solution(False, reason, float("nan"), mu_min, np.full((n, n), np.nan), np.full(len(channels), np.nan),
                        float("nan"), status, float("nan"), len(active), len(pool_values), argument)  # fmt: skip

    for _round in range(max_rounds):
        J, G = model.jacobians(active)
        problem = _Problem(J, G, channels, structure, kappa_max, gain_max)
        mu_min = lmi.bisect_discount(problem.feasible, MU_FLOOR, tol)
        if mu_min is None:
            return fail("infeasible for every discount < 1: no quadratic storage certifies the inequality",
                        status="infeasible")  # fmt: skip
        mu_used = mu if mu is not None else min(2.0 * mu_min, 0.5 * (1.0 + mu_min))
        if mu_used < mu_min:
            return fail(f"mu={mu_used} is below the smallest certifiable discount mu_min={mu_min:.4g}", mu_min,
                        "infeasible")  # fmt: skip
        status, (P, q, r) = _design(problem, mu_used, kappa_slack, J, G, channels)
        if status not in ACCEPTED:
            return fail(f"final solve at mu={mu_used:.4g} returned {status}", mu_min, status)
        pool_margin = margins(J_pool, G_pool, P, q, r, channels, mu_used)
        if pool_margin.min() >= 0.0:
            break
        worst = np.argsort(pool_margin)[:10]
        active = np.vstack([active, pool_values[worst]])
    margin = float(min(margins(J, G, P, q, r, channels, mu_used).min(), pool_margin.min()))
    certified = margin >= 0.0
    reason = (
        f"certified: mu={mu_used:.6g} (mu_min={mu_min:.6g}), condition of P {np.linalg.cond(P):.3g}, "
        f"re-check margin {margin:.2e}"
        if certified
        else f"re-check failed: worst eigenvalue margin {margin:.2e} after {max_rounds} cutting-plane rounds"
    )
    return Solution(certified, reason, float(mu_used), float(mu_min), P, q, r, status, margin, len(active),
                    len(pool_values), argument)  # fmt: skip


def _design(
    problem: _Problem, mu: float, kappa_slack: float, J: FloatArray, G: FloatArray, channels: Sequence[int]
) -> tuple[str, tuple[FloatArray, FloatArray, float]]:
    """Design at discount mu: condition number of P first, then the gains.

    Keeps a tenth of the best margin, minimises the condition number of P, then the gains under
    ``kappa <= kappa_slack kappa_min``.

    Falls back to the margin problem's (strictly feasible) solution when a design solve fails or
    its solution does not pass the re-check on the active points.
    """
    if not problem.feasible(mu):
        return str(problem.margin_problem.status), problem.values()
    fallback = problem.values()
    problem.t_req.value = 0.1 * float(problem.t.value)
    status = lmi.solve(problem.conditioning_problem)
    if status in ACCEPTED:
        problem.s_req.value = float(problem.s.value) / kappa_slack
        status = lmi.solve(problem.gains_problem)
    if status in ACCEPTED and margins(J, G, *problem.values(), channels, mu).min() >= 0.0:
        return "optimal", problem.values()
    return "optimal", fallback


@dataclass(frozen=True)
class PairCheck:
    """Worst ratio of the dissipation inequality over sampled pairs (see :func:`check_pairs`)."""

    worst_ratio: float
    pairs: int


def check_pairs(
    model: IncrementalModel,
    P: FloatArray,
    mu: float,
    weights: Sequence[FloatArray],
    R: FloatArray,
    n_pairs: int,
    seed: int,
) -> PairCheck:
    """Test the inequality in original units on random pairs with the nonlinear F and H.

    ``weights[c]`` is the (size_c, size_c) weight matrix of channel c, ``R`` the output weight.
    Half of the pairs are close (relative distance 1e-3), where the inequality is tightest.
    """
    rng = np.random.default_rng(seed)
    n = model.n
    z, zt = model.z_box.sample(rng, n_pairs), model.z_box.sample(rng, n_pairs)
    d, dt = model.d_box.sample(rng, n_pairs), model.d_box.sample(rng, n_pairs)
    close = rng.random(n_pairs) < 0.5
    zt[close] = model.z_box.clip(z[close] + 1e-3 * model.z_scale * rng.standard_normal((close.sum(), n)))
    dt[close] = model.d_box.clip(d[close] + 1e-3 * model.d_scale * rng.standard_normal((close.sum(), model.nd)))
    u = model.u_box.sample(rng, n_pairs)

    def run(fun: ca.Function, *cols: FloatArray) -> FloatArray:
        return np.asarray(fun.map(n_pairs)(*[c.T for c in cols]), dtype=float).T

    dz_next = run(model.step, z, u, d) - run(model.step, zt, u, dt)
    dy = run(model.output, z, d) - run(model.output, zt, dt)
    W = np.zeros((model.nd, model.nd))
    start = 0
    for (_, size), weight in zip(model.channels, weights, strict=True):
        W[start : start + size, start : start + size] = weight
        start += size

    def quad(v: FloatArray, M: FloatArray) -> FloatArray:
        return np.einsum("mi,ij,mj->m", v, M, v)

    lhs = quad(dz_next, P)
    rhs = mu * quad(z - zt, P) + quad(d - dt, W) + quad(dy, R)
    return PairCheck(float((lhs / np.maximum(rhs, 1e-300)).max()), n_pairs)
