r"""The incremental dissipation LMI solved in stages: the rate on a kernel, a design, the output weight in closed form.

Scaled increments ``xi = (dz, dd)`` (``n + nd``), the cover's vertices ``J_i = [A_i, B_i]`` (n, n + nd) and
output Jacobians ``G_i`` (p, n + nd). A certificate is ``P >= I``, channel weights ``q >= 0`` and an output
weight ``r >= 0`` with, at every vertex,

    M_i = blkdiag(mu P, q_1 I, ..., q_c I) + r G_i^T G_i - J_i^T P J_i >= 0.

Any finite weights certify, so they are free while the rate is sought, and the solve has four stages:

1. **Rate.** By Finsler's lemma for the map ``xi -> (dd, G_i xi)``, weights with ``M_i > 0`` exist iff
   ``K_i^T (mu P - A_i^T P A_i) K_i > 0``, K_i an orthonormal basis of ``ker G_{z,i}``: the storage must
   contract along the states the current output does not see (dd = 0). The margin problem ``max t``
   with these blocks ``>= t I``, ``cond(P) <= kappa`` (``s W >= P_hat >= s W / kappa``) and ``P_hat <= I``
   is solved in *balanced* coordinates ``dz = T z_hat`` (``W = T^T T``) in which the last feasible storage
   is the identity: where the unmeasured states show in the output only through a small one-step
   coupling, the storage that contracts them has a condition number of order ``1 / coupling^2`` (1e12
   on slowly sampled models), and in balanced coordinates that is a well-scaled problem. Bisection on mu.
2. **Design** at the chosen mu, in the coordinates balanced at that rate: the full LMI at the rate
   ``mu - delta`` with the weights times ``1 - delta`` (so the certificate at mu keeps a margin ``delta``
   relative to P and the weights), ``P >= I``, ``cond(P) <= kappa``, minimising the weights relative to
   a feasible point (one closed-form multiplier ``sigma`` for all of them) plus ``1e-3 tr(P_hat) / n``.
3. **Closed form.** With P and q fixed, the smallest r is a generalised eigenvalue
   (:func:`smallest_weight`), times ``1 + 1e-3``.
4. **Re-check** in numpy at every vertex (:func:`recheck`), which alone decides: the block of
   ``Q_i = M_i - r G_i^T G_i`` on ``ker G_i`` positive definite, the Schur complement on ``range G_i^T``
   with r positive semidefinite, and the smallest eigenvalue of ``M_i`` itself within its rounding.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt
import scipy.linalg

from uiest.box import FloatArray
from uiest.detectability import lmi

if TYPE_CHECKING:
    import cvxpy as cp
else:
    from uiest.detectability.lmi import cp  # cvxpy, imported when first used

MARGIN_FLOOR = 1e-9
"""Smallest margin ``t*`` of the rate problem (relative to the storage on the kernels) that counts as feasible."""

REBALANCE_CONDITION = 30.0
"""A storage whose condition number in the current coordinates exceeds this re-balances them."""

MAX_REBALANCE = 4
"""Re-balancings per rate probe."""

DECISIVE_MARGIN = 1e-6
"""A margin solved to optimality beyond this size decides a probe without re-solving in re-balanced coordinates."""

DESIGN_SLACK = 0.5
"""The design imposes the inequality at ``mu - DESIGN_SLACK * t``, t the rate problem's margin at mu."""

TRACE_WEIGHT = 1e-3
"""Weight of ``tr(P_hat) / n`` beside the weights in the design objective."""

CONDITION_RTOL = 1e-6
"""A design's cond(P) may exceed max_condition by this fraction (the solver's tolerance); more is a failed solve."""

R_SAFETY = 1e-3
"""The closed-form output weight is multiplied by ``1 + R_SAFETY``."""

KERNEL_RTOL = 1e-10
"""Singular values of the state output map below this fraction of the output map's norm count as zero."""

ROUNDING = 1e-13
"""The direct check of M_i passes within this fraction of its largest entry (double-precision rounding)."""


@dataclass(frozen=True, eq=False)
class Vertices:
    """The matrices of the LMI at the cover's vertices (scaled), with the kernels of the state output maps.

    Disturbance components that enter neither J nor G at any vertex are left out (their rows of M are
    ``q_c`` on the diagonal and nothing else, so M >= 0 holds with them iff it holds without them).

    Attributes
    ----------
    J : ndarray (m, n, n + nd')
    G : ndarray (m, p, n + nd')
        The nd' disturbance components kept.
    channel_of : ndarray of int (nd',)
        The channel of each kept component.
    n_channels : int
        Number of channels (weights).
    n : int
        State dimension.

    """

    J: FloatArray
    G: FloatArray
    channel_of: npt.NDArray[np.intp]
    n_channels: int
    n: int

    @classmethod
    def build(cls, J: FloatArray, G: FloatArray, channels: Sequence[int], n: int) -> Vertices:
        """From J (m, n, n + nd), G (m, p, n + nd) and the channel sizes (summing to nd)."""
        channel_of = np.repeat(np.arange(len(channels)), channels).astype(np.intp)
        used = np.any(J[:, :, n:] != 0.0, axis=(0, 1)) | np.any(G[:, :, n:] != 0.0, axis=(0, 1))
        keep = np.concatenate([np.ones(n, dtype=bool), used])
        return cls(J[:, :, keep], G[:, :, keep], channel_of[used], len(channels), n)

    @property
    def nd(self) -> int:
        """Disturbance components kept."""
        return self.J.shape[2] - self.n

    @cached_property
    def kernels(self) -> list[FloatArray]:
        """Orthonormal bases K_i (n, k_i) of ``ker G_{z,i}``: the states the current output does not see.

        Singular values of ``G_{z,i}`` below ``KERNEL_RTOL ||G_i||`` count as zero (a state seen by the
        output only to rounding is not seen; treating it so asks more of the storage, never less).
        """
        out = []
        for G in self.G:
            scale = float(np.linalg.norm(G, 2))
            out.append(scipy.linalg.null_space(G[:, : self.n], rcond=KERNEL_RTOL * scale / max(
                float(np.linalg.norm(G[:, : self.n], 2)), 1e-300)) if scale > 0.0 else np.eye(self.n))  # fmt: skip
        return out

    def subset(self, index: Sequence[int]) -> Vertices:
        """The vertices ``index``."""
        return Vertices(self.J[list(index)], self.G[list(index)], self.channel_of, self.n_channels, self.n)

    @property
    def A(self) -> FloatArray:
        """State parts of J (m, n, n)."""
        return self.J[:, :, : self.n]

    @property
    def measured_everything(self) -> bool:
        """Whether the current output sees every state at every vertex (every kernel is empty)."""
        return all(K.shape[1] == 0 for K in self.kernels)

    def supply(self, P: FloatArray, q: FloatArray, mu: float) -> FloatArray:
        """``Q_i = blkdiag(mu P, q I) - J_i^T P J_i`` for every vertex (m, n + nd, n + nd)."""
        n = self.n
        size = self.J.shape[2]
        D = np.zeros((size, size))
        D[:n, :n] = mu * P
        D[n:, n:] = np.diag(np.asarray(q, dtype=float)[self.channel_of])
        Q = D[None] - np.einsum("mji,jk,mkl->mil", self.J, P, self.J)
        return 0.5 * (Q + np.swapaxes(Q, 1, 2))

    def kernel_margins(self, P: FloatArray, mu: float) -> FloatArray:
        """Per vertex: smallest eigenvalue of ``K_i^T (mu P - A_i^T P A_i) K_i`` over that of ``K_i^T P K_i``; (m,).

        +inf where the kernel is empty.
        """
        out = np.full(len(self.J), np.inf)
        for i, (A, K) in enumerate(zip(self.A, self.kernels, strict=True)):
            if K.shape[1]:
                AK = A @ K
                block = mu * K.T @ P @ K - AK.T @ P @ AK
                out[i] = np.linalg.eigvalsh(0.5 * (block + block.T))[0] / np.linalg.eigvalsh(K.T @ P @ K)[-1]
        return out


def smallest_weight(Q: FloatArray, B: FloatArray) -> float:
    """Smallest ``s >= 0`` with ``Q + s B^T B >= 0`` (symmetric Q (k, k), B (l, k)); +inf when none exists.

    Splits ``R^k`` into ``ker B`` (basis N) and ``range B^T`` (basis R): ``N^T Q N`` must be positive
    definite, and then s is the largest generalised eigenvalue of ``(Q_NR^T Q_NN^-1 Q_NR - Q_RR, R^T B^T B R)``.
    """
    N = scipy.linalg.null_space(B) if B.size else np.eye(Q.shape[0])
    R = scipy.linalg.orth(B.T) if B.size else np.zeros((Q.shape[0], 0))
    if R.shape[1] == 0:
        return 0.0 if np.linalg.eigvalsh(Q)[0] >= 0.0 else np.inf
    QR = Q @ R
    need = -R.T @ QR
    if N.shape[1]:
        try:
            factor = scipy.linalg.cho_factor(N.T @ Q @ N)
        except np.linalg.LinAlgError:  # not positive definite
            return np.inf
        QNR = N.T @ QR
        need = need + QNR.T @ scipy.linalg.cho_solve(factor, QNR)
    gram = (B @ R).T @ (B @ R)
    top = float(scipy.linalg.eigh(0.5 * (need + need.T), 0.5 * (gram + gram.T), eigvals_only=True)[-1])
    return max(top, 0.0)


def balancing(P: FloatArray) -> FloatArray:
    """``T = U diag(w)^-1/2`` from ``P = U diag(w) U^T`` (``lambda_min`` normalised to 1): ``T^T P T = I``, ``T^T T`` diagonal.

    The bound on cond(P) then reads ``s W >= P_hat >= s W / kappa`` with W diagonal (its spread is that of P),
    which interior-point solvers resolve where a full W of the same spread defeats them.
    """
    w, U = np.linalg.eigh(0.5 * (P + P.T))
    return U / np.sqrt(w / w[0])


class RateProblem:
    """Stage 1 on a subset of vertices in coordinates T: ``max t`` with the kernel blocks ``>= t I``; mu a Parameter.

    ``dz = T z_hat``, ``P_hat = T^T P T``, normalised on the kernels: ``tr(Pi P_hat) = 1`` with Pi the mean
    of the vertices' kernel projectors (in hat coordinates), so that t is a margin relative to the storage
    of the states the output does not see, and ``t* < 0`` by a margin of that size where no P works. With
    ``W = T^T T / lambda_min(T^T T)`` (diagonal, from :func:`balancing`) the bound ``cond(P) <= kappa`` is
    ``s W >= P_hat >= (s / kappa) W``.
    """

    def __init__(
        self, A: FloatArray, kernels: Sequence[FloatArray], T: FloatArray, kappa: float, structure: str
    ) -> None:
        n = A.shape[1]
        T_inv = np.linalg.inv(T)
        W = T.T @ T
        W = 0.5 * (W + W.T) / float(np.linalg.eigvalsh(W)[0])
        self.T, self.T_inv, self.structure, self.n = T, T_inv, structure, n
        self.mu = cp.Parameter(nonneg=True, value=0.5)
        self.t = cp.Variable()
        bases = [np.linalg.qr(T_inv @ K)[0] for K in kernels if K.shape[1]]
        Pi = sum(K_hat @ K_hat.T for K_hat in bases) / max(len(bases), 1)
        self.s = cp.Variable(nonneg=True)
        if structure == "full":
            self.P = cp.Variable((n, n), symmetric=True)
            P_hat = self.P
            constraints = [P_hat >> (self.s / kappa) * W, self.s * W >> P_hat]
        else:  # P = p I (T = I)
            self.P = cp.Variable(nonneg=True)
            P_hat = self.P * np.eye(n)
            constraints = [self.s == 1.0]
        constraints.append(cp.trace(Pi @ P_hat) == 1.0)
        for Ai, K in zip(A, kernels, strict=True):
            if not K.shape[1]:
                continue
            K_hat = np.linalg.qr(T_inv @ K)[0]
            AK = T_inv @ Ai @ T @ K_hat
            block = self.mu * (K_hat.T @ P_hat @ K_hat) - AK.T @ P_hat @ AK
            constraints.append(lmi.symmetric(block) >> self.t * np.eye(K_hat.shape[1]))
        self.problem = cp.Problem(cp.Maximize(self.t), constraints)
        self.t_req = cp.Parameter(nonneg=True, value=0.0)
        self.conditioning = cp.Problem(cp.Minimize(self.s), [*constraints, self.t >= self.t_req])

    def solve(self, mu: float) -> tuple[str, FloatArray | None, float]:
        """(status, P in the original coordinates or None, t); P normalised to ``lambda_min(P) = 1`` when definite.

        P is returned also when ``t <= 0`` (the probe is then decided by t), possibly not definite.
        """
        self.mu.value = mu
        status = lmi.solve(self.problem)
        if status not in lmi.SOLVED or self.P.value is None or self.t.value is None:
            return status, None, float("nan")
        if self.structure == "full":
            P = self.T_inv.T @ (0.5 * (self.P.value + self.P.value.T)) @ self.T_inv
        else:
            P = float(self.P.value) * np.eye(self.n)
        P = 0.5 * (P + P.T)
        low = float(np.linalg.eigvalsh(P)[0])
        return status, (P / low if low > 0.0 else P), float(self.t.value)

    def conditioned(self, mu: float, t_req: float) -> tuple[str, FloatArray | None, float]:
        """At mu, the storage with the smallest ``lambda_max`` (relative to the kernels') whose margin is at least
        ``t_req``: (status, P with ``lambda_min(P) = 1`` or None, t). The margin problem saturates the bound
        on cond(P) whenever a larger condition number buys any margin; the design starts better from this one.
        """
        self.mu.value, self.t_req.value = mu, t_req
        status = lmi.solve(self.conditioning)
        if status not in lmi.SOLVED or self.P.value is None or self.t.value is None:
            return status, None, float("nan")
        if self.structure == "full":
            P = self.T_inv.T @ (0.5 * (self.P.value + self.P.value.T)) @ self.T_inv
        else:
            P = float(self.P.value) * np.eye(self.n)
        P = 0.5 * (P + P.T)
        low = float(np.linalg.eigvalsh(P)[0])
        return (status, P / low, float(self.t.value)) if low > 0.0 else ("singular storage", None, float("nan"))


class RateStage:
    """Bisection on the rate with cutting planes over the vertices, in coordinates re-balanced as it goes.

    Each probe solves in the current coordinates; while the storage found is ill-conditioned in them
    (``cond(T^T P T) > REBALANCE_CONDITION``), the coordinates are re-balanced at it, and the probe solved
    again unless its margin was decisive (at most ``MAX_REBALANCE`` times). A probe still ill-conditioned
    with ``|t| <= MARGIN_FLOOR`` decides nothing.
    """

    def __init__(self, vertices: Vertices, structure: str, kappa: float) -> None:
        self.vertices, self.structure, self.kappa = vertices, structure, kappa
        self.T = np.eye(vertices.n)
        self.active = lmi.ActiveSet(np.concatenate([vertices.J, vertices.G], axis=1))
        self._problem: RateProblem | None = None
        self._key: tuple[int, int] = (-1, -1)
        self._version = 0
        self.solutions: dict[float, tuple[FloatArray, float]] = {}
        self.inexact: list[float] = []

    def _rate_problem(self) -> RateProblem:
        key = (len(self.active.index), self._version)
        if self._problem is None or key != self._key:
            index = self.active.index
            kernels = [self.vertices.kernels[i] for i in index]
            self._problem = RateProblem(self.vertices.A[index], kernels, self.T, self.kappa, self.structure)
            self._key = key
        return self._problem

    def _balanced(self, P: FloatArray) -> bool:
        """Whether P is well-conditioned in the current coordinates (or cannot balance them: not definite)."""
        if self.structure != "full" or not np.linalg.eigvalsh(P)[0] > 0.0:
            return True
        return float(np.linalg.cond(self.T.T @ P @ self.T)) <= REBALANCE_CONDITION

    def _within(self, P: FloatArray) -> bool:
        """Whether P is positive definite with ``cond(P) <= kappa`` (to ``CONDITION_RTOL``)."""
        w = np.linalg.eigvalsh(P)
        return bool(w[0] > 0.0 and w[-1] <= self.kappa * (1.0 + CONDITION_RTOL) * w[0])

    def _solve(self, mu: float) -> tuple[str, FloatArray | None, float]:
        """The margin problem at mu on the active vertices, re-balanced until the storage is well-conditioned."""
        status, P, t = self._rate_problem().solve(mu)
        for _ in range(MAX_REBALANCE):
            if P is None or self._balanced(P):
                break
            self.T = balancing(P)  # the next probe starts from these coordinates
            self._version += 1
            if abs(t) > DECISIVE_MARGIN and status == "optimal":
                break
            status, P, t = self._rate_problem().solve(mu)
        if P is not None and not self._balanced(P) and not abs(t) > MARGIN_FLOOR:
            return "ill-conditioned in every balancing tried", None, t
        return status, P, t

    def settle(self, mu: float) -> str:
        """:meth:`probe` at mu; where that fails, FEASIBLE if a storage was found feasible at a smaller rate (it
        holds at mu too, with the margin its kernel blocks have there)."""
        outcome = lmi.FEASIBLE if mu in self.solutions else self.probe(mu)
        if outcome == lmi.FAILED:
            for rate in sorted((r for r in self.solutions if r < mu), reverse=True):
                P = self.solutions[rate][0]
                margin = float(self.vertices.kernel_margins(P, mu).min())
                if margin > MARGIN_FLOOR:
                    self.solutions[mu] = (P, min(margin, mu))
                    return lmi.FEASIBLE
        return outcome

    def storage(self, mu: float) -> tuple[FloatArray, float] | None:
        """(P, t) at mu, a rate probed FEASIBLE, with P positive definite and ``cond(P) <= kappa``; None if none found.

        The margin problem saturates the bound on cond(P) wherever that buys any margin, and there its P can
        leave the bound by the solver's tolerance (relative 1e-8 in balanced coordinates, which near 1e12 is
        the whole smallest eigenvalue). So: the storage of least ``lambda_max`` keeping a quarter of the margin
        (re-balanced at each one found), else
        the margin problem's, else one found feasible at a smaller rate (it holds at mu too), each only if
        within the bound and re-checked on the kernels at mu.
        """
        P_rate, t = self.solutions[mu]
        if self.vertices.measured_everything:
            return P_rate, t
        candidates = []
        for _ in range(MAX_REBALANCE + 1):  # re-balanced at each storage found, as a probe is
            _, P, t_cond = self._rate_problem().conditioned(mu, 0.25 * t)
            if P is None:
                break
            candidates.append((P, t_cond))
            if self._balanced(P):
                break
            self.T = balancing(P)
            self._version += 1
        candidates.reverse()
        candidates.append((P_rate, t))
        candidates += [(self.solutions[rate][0], np.nan) for rate in sorted(self.solutions, reverse=True) if rate < mu]
        for P, t_found in candidates:
            if not self._within(P):
                continue
            margin = float(self.vertices.kernel_margins(P, mu).min())
            if margin > MARGIN_FLOOR:
                return P, (min(margin, mu) if np.isnan(t_found) else t_found)
        return None

    def probe(self, mu: float) -> str:
        """FEASIBLE when the margin problem has ``t* > MARGIN_FLOOR`` and every vertex passes the kernel re-check.

        INFEASIBLE when it was solved with ``t* <= 0``: to optimality, or, below the top of the bisection's
        range (where "infeasible" would be the certificate's verdict), also to reduced accuracy with
        ``t* < -MARGIN_FLOOR`` (a storage of condition number near 1e12 often ends there): such a rate only
        bounds mu_min from below in the bisection, and is listed in :attr:`inexact`.
        """
        if self.vertices.measured_everything:
            self.solutions[mu] = (np.eye(self.vertices.n), mu)
            return lmi.FEASIBLE
        found: dict[str, object] = {}

        def solve() -> tuple[str, object, float]:
            status, P, t = self._solve(mu)
            found.update(status=status, t=t)
            return status, P, t

        def recheck(P: object) -> FloatArray:
            return self.vertices.kernel_margins(P, mu)  # type: ignore[arg-type]

        outcome, P = lmi.cutting_plane_probe(solve, recheck, self.active, MARGIN_FLOOR)
        if outcome == lmi.FEASIBLE:
            self.solutions[mu] = (P, float(found["t"]))  # type: ignore[arg-type]
        elif (outcome == lmi.FAILED and found.get("status") == "optimal_inaccurate"
              and float(found["t"]) < -MARGIN_FLOOR and mu < 1.0 - 10.0 * lmi.RATE_GAP):  # type: ignore[arg-type]  # fmt: skip
            self.inexact.append(mu)
            return lmi.INFEASIBLE
        return outcome


@dataclass(frozen=True)
class Design:
    """(P, q) of stage 2 or of a fallback, and how it was found."""

    P: FloatArray
    q: FloatArray
    note: str


def multiplier(vertices: Vertices, P: FloatArray, mu: float) -> float:
    """The smallest common weight sigma (``q_c = r = sigma``) certifying P at mu: one Finsler multiplier."""
    Q = vertices.supply(P, np.zeros(vertices.n_channels), mu)
    n, nd = vertices.n, vertices.nd
    E = np.hstack([np.zeros((nd, n)), np.eye(nd)])
    return max(smallest_weight(Qi, np.vstack([E, Gi])) for Qi, Gi in zip(Q, vertices.G, strict=True))


def design_once(
    vertices: Vertices, P_rate: FloatArray, sigma: float, mu: float, delta: float, kappa: float, structure: str
) -> tuple[str, Design | None]:
    """Stage 2 on ``vertices``: the Schur form, else M itself; cond(P) free, then bounded if it exceeds kappa.

    A bound far above the solution's condition number only hurts the solver, so it is imposed where it binds.
    In balanced coordinates the Schur form ``[[D + r G^T G, J^T P], [P J, P]] >= 0`` is the better-conditioned
    one on slowly sampled models, whose M carries only a margin of order ``1 - mu``.
    """
    status = ""
    for schur in (True, False):
        status, designed = design_solve(vertices, P_rate, sigma, mu, delta, kappa, structure, bounded=False,
                                        schur=schur)  # fmt: skip
        if designed is not None and np.linalg.cond(designed.P) > kappa:
            status, designed = design_solve(vertices, P_rate, sigma, mu, delta, kappa, structure, bounded=True,
                                            schur=schur)  # fmt: skip
        if designed is not None:
            return status, designed
    return status, None


def design_solve(
    vertices: Vertices,
    P_rate: FloatArray,
    sigma: float,
    mu: float,
    delta: float,
    kappa: float,
    structure: str,
    *,
    bounded: bool,
    schur: bool,
) -> tuple[str, Design | None]:
    """Stage 2 on ``vertices`` in the coordinates balanced at ``P_rate``, weights per unit of sigma."""
    n, nd = vertices.n, vertices.nd
    T = balancing(P_rate) if structure == "full" else np.eye(n)
    T_inv = np.linalg.inv(T)
    W = T.T @ T
    T_full = scipy.linalg.block_diag(T, np.eye(nd) / np.sqrt(sigma))
    if structure == "full":
        P = cp.Variable((n, n), symmetric=True)
        P_hat = P
        constraints = [P_hat >> W]
        if bounded:  # lambda_min(P) >= low >= 1, lambda_max(P) <= kappa low: cond(P) <= kappa at any scale
            low = cp.Variable()
            constraints += [low >= 1.0, P_hat >> low * W, P_hat << (kappa * low) * W]
    else:
        P = cp.Variable(nonneg=True)
        P_hat = P * np.eye(n)
        constraints = [P >= 1.0]
    q = cp.Variable(vertices.n_channels, nonneg=True)
    r = cp.Variable(nonneg=True)
    Dq = cp.diag(cp.hstack([q[int(c)] for c in vertices.channel_of])) if nd else None
    zero = np.zeros((n, nd))
    for Ji, Gi in zip(vertices.J, vertices.G, strict=True):
        J_hat, G_hat = T_inv @ Ji @ T_full, Gi @ T_full
        rate_part = (mu - delta) * P_hat
        top = rate_part if Dq is None else cp.bmat([[rate_part, zero], [zero.T, (1.0 - delta) * Dq]])
        supply = top + (1.0 - delta) * r * (sigma * G_hat.T @ G_hat)
        if schur:
            block = cp.bmat([[supply, J_hat.T @ P_hat], [P_hat @ J_hat, P_hat]])
        else:
            block = supply - J_hat.T @ P_hat @ J_hat
        constraints.append(lmi.symmetric(block) >> 0)
    problem = cp.Problem(cp.Minimize(cp.sum(q) + r + TRACE_WEIGHT * cp.trace(P_hat) / n), constraints)
    status = lmi.solve(problem)
    if status not in lmi.SOLVED or P.value is None or q.value is None:
        return status, None
    P_val = T_inv.T @ (np.asarray(P.value) if structure == "full" else float(P.value) * np.eye(n)) @ T_inv
    P_val = 0.5 * (P_val + P_val.T)
    low = float(np.linalg.eigvalsh(P_val)[0])
    if not low > 0.0:
        return "singular storage", None
    if bounded and np.linalg.cond(P_val) > kappa * (1.0 + CONDITION_RTOL):
        return f"cond(P) {np.linalg.cond(P_val):.6g} above max_condition ({status})", None
    q_val = np.maximum(np.asarray(q.value, dtype=float).reshape(-1), 0.0) * sigma
    return status, Design(P_val / low, q_val / low, "design")


def output_weight(vertices: Vertices, P: FloatArray, q: FloatArray, mu: float) -> float:
    """Stage 3: the smallest r with ``Q_i + r G_i^T G_i >= 0`` at every vertex, times ``1 + R_SAFETY`` (inf if none)."""
    Q = vertices.supply(P, q, mu)
    r = max(smallest_weight(Qi, Gi) for Qi, Gi in zip(Q, vertices.G, strict=True))
    return r * (1.0 + R_SAFETY) if np.isfinite(r) else np.inf


@dataclass(frozen=True)
class Recheck:
    """Stage 4's margins per vertex, each relative to its own scale (shape (m,) each).

    Attributes
    ----------
    kernel : ndarray
        Smallest eigenvalue of ``N_i^T Q_i N_i`` (N_i a basis of ker G_i) over ``||P||`` (+inf if the kernel is empty).
    schur : ndarray
        Smallest eigenvalue of the Schur complement on ``range G_i^T`` with r, over ``r ||G_i||^2``.
    direct : ndarray
        Smallest eigenvalue of ``M_i`` over its largest entry.

    """

    kernel: FloatArray
    schur: FloatArray
    direct: FloatArray

    @property
    def per_vertex(self) -> FloatArray:
        """Each vertex's worst margin, ``direct`` counted only beyond its rounding (m,)."""
        return np.minimum(np.minimum(self.kernel, self.schur), self.direct + ROUNDING)

    @property
    def passed(self) -> bool:
        """``kernel > 0``, ``schur >= 0`` and ``direct >= -ROUNDING`` at every vertex."""
        return bool(np.all(self.kernel > 0.0) and np.all(self.schur >= 0.0) and np.all(self.direct >= -ROUNDING))

    @property
    def margin(self) -> float:
        """The smallest of the margins over the vertices."""
        return float(min(self.kernel.min(), self.schur.min(), self.direct.min()))


def recheck(vertices: Vertices, P: FloatArray, q: FloatArray, r: float, mu: float) -> Recheck:
    """Stage 4 (see the module docstring), at every vertex."""
    Q = vertices.supply(P, q, mu)
    norm_P = float(np.linalg.eigvalsh(P)[-1])
    m = len(Q)
    kernel, schur, direct = np.full(m, np.inf), np.full(m, np.inf), np.full(m, np.inf)
    for i, (Qi, Gi) in enumerate(zip(Q, vertices.G, strict=True)):
        N, R = scipy.linalg.null_space(Gi), scipy.linalg.orth(Gi.T)
        if N.shape[1]:
            QNN = N.T @ Qi @ N
            kernel[i] = float(np.linalg.eigvalsh(0.5 * (QNN + QNN.T))[0]) / norm_P
        if R.shape[1] and kernel[i] > 0.0:
            GR = Gi @ R
            S = R.T @ Qi @ R + r * GR.T @ GR
            if N.shape[1]:
                QNR = N.T @ Qi @ R
                S = S - QNR.T @ np.linalg.lstsq(N.T @ Qi @ N, QNR, rcond=None)[0]
            scale = r * float(np.linalg.norm(GR, 2)) ** 2
            low = float(np.linalg.eigvalsh(0.5 * (S + S.T))[0])
            schur[i] = low / scale if scale > 0.0 else (np.inf if low >= 0.0 else -np.inf)
        elif R.shape[1]:
            schur[i] = -np.inf
        M = Qi + r * Gi.T @ Gi
        direct[i] = float(np.linalg.eigvalsh(M)[0]) / max(float(np.abs(M).max()), 1e-300)
    return Recheck(kernel, schur, direct)


@dataclass(frozen=True)
class Finished:
    """Stages 2-4 at one rate: the storage, the weights, the re-check and how P was found."""

    P: FloatArray
    q: FloatArray
    r: float
    check: Recheck
    note: str


def design_and_check(
    vertices: Vertices, P_rate: FloatArray, t: float, mu: float, kappa: float, structure: str
) -> Finished | None:
    """Stages 2-4 at mu from the rate problem's storage and margin; the design on an active set of vertices
    grown by cutting planes, else the fallback (the rate problem's storage, one closed-form weight per channel).

    None when even the fallback has no finite weights (the rate problem's storage does not contract the kernel).
    """
    delta = DESIGN_SLACK * min(t, mu)
    sigma = multiplier(vertices, P_rate, mu - delta)
    if not np.isfinite(sigma):
        return None
    sigma = max(sigma, 1e-300)
    active = lmi.ActiveSet(np.concatenate([vertices.J, vertices.G], axis=1))
    status = ""
    for _ in range(len(vertices.J)):
        status, designed = design_once(vertices.subset(active.index), P_rate, sigma, mu, delta, kappa, structure)
        if designed is None:
            break
        r = output_weight(vertices, designed.P, designed.q, mu)
        check = recheck(vertices, designed.P, designed.q, r, mu)
        if check.passed:
            return Finished(designed.P, designed.q, r, check, "design")
        if not active.add_worst(check.per_vertex):
            status = f"re-check failed at an imposed vertex (margin {check.margin:.2e})"
            break
    q = np.full(vertices.n_channels, sigma * (1.0 + R_SAFETY))
    r = output_weight(vertices, P_rate, q, mu)
    return Finished(P_rate, q, r, recheck(vertices, P_rate, q, r, mu),
                    f"the rate problem's storage with one closed-form weight for every channel (design: {status})")  # fmt: skip
