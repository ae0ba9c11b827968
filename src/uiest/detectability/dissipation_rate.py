"""Stage 1 of the dissipation LMI (:mod:`uiest.detectability.dissipation_lmi`): the rate on the kernels.

The margin problem on the states the current output does not see, in coordinates re-balanced at the
storages found, bisected over mu; a storage within the bound on cond(P) at the chosen rate.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from uiest.box import FloatArray
from uiest.detectability import lmi
from uiest.detectability.dissipation_lmi import CONDITION_RTOL, Vertices, balancing

if TYPE_CHECKING:
    import cvxpy as cp
else:
    from uiest.detectability.lmi import cp  # cvxpy, imported when first used

__all__ = ["RateProblem", "RateStage"]

MARGIN_FLOOR = 1e-9
"""Smallest margin ``t*`` of the rate problem (relative to the storage on the kernels) that counts as feasible."""

REBALANCE_CONDITION = 1e3
"""A storage whose condition number in the current coordinates exceeds this re-balances them."""

MAX_REBALANCE = 4
"""Re-balancings per rate probe."""

MARGIN_CAP = 0.5
"""The margin problem maximises t only up to ``MARGIN_CAP * mu``: beyond that every storage decides the probe, and
an interior-point solver returns a central one instead of one pushed to the bound on cond(P)."""

DECISIVE_MARGIN = 1e-6
"""A margin solved to optimality beyond this size decides a probe without re-solving in re-balanced coordinates."""


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
        self.problem = cp.Problem(cp.Maximize(self.t), [*constraints, self.t <= MARGIN_CAP * self.mu])
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
        P, low = self._storage()
        return status, (P / low if low > 0.0 else P), float(self.t.value)

    def conditioned(self, mu: float, t_req: float) -> tuple[str, FloatArray | None, float]:
        """At mu, the storage of least ``lambda_max`` (kernels normalised) with a margin of at least ``t_req``.

        Returns (status, P with ``lambda_min(P) = 1`` or None, t). The margin problem saturates the bound
        on cond(P) whenever a larger condition number buys any margin; the design starts better from this one.
        """
        self.mu.value, self.t_req.value = mu, t_req
        status = lmi.solve(self.conditioning)
        if status not in lmi.SOLVED or self.P.value is None or self.t.value is None:
            return status, None, float("nan")
        P, low = self._storage()
        return (status, P / low, float(self.t.value)) if low > 0.0 else ("singular storage", None, float("nan"))

    def _storage(self) -> tuple[FloatArray, float]:
        """The solved P in the original coordinates (symmetrised) and its smallest eigenvalue."""
        assert self.P.value is not None
        if self.structure == "full":
            P = self.T_inv.T @ (0.5 * (self.P.value + self.P.value.T)) @ self.T_inv
        else:
            P = float(self.P.value) * np.eye(self.n)
        P = 0.5 * (P + P.T)
        return P, float(np.linalg.eigvalsh(P)[0])


class RateStage:
    """Bisection on the rate with cutting planes over the vertices, in coordinates re-balanced as it goes.

    Each probe solves in the current coordinates; where the storage found is ill-conditioned in them
    (``cond(T^T P T) > REBALANCE_CONDITION``), the coordinates are re-balanced at it for the later probes, and,
    while its margin is not decisive (``|t| <= DECISIVE_MARGIN`` or not solved to optimality), the probe is
    solved again in them (at most ``MAX_REBALANCE`` times). A probe still ill-conditioned with
    ``|t| <= MARGIN_FLOOR`` decides nothing.
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
        """Probe mu; where that fails, FEASIBLE if a storage was found feasible at a smaller rate.

        Such a storage holds at mu too, with the margin its kernel blocks have there.
        """
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
        found: dict[str, str | float] = {}

        def solve() -> tuple[str, FloatArray | None, float]:
            status, P, t = self._solve(mu)
            found.update(status=status, t=t)
            return status, P, t

        def recheck(P: FloatArray) -> FloatArray:
            return self.vertices.kernel_margins(P, mu)

        probed = lmi.cutting_plane_probe(solve, recheck, self.active, MARGIN_FLOOR)  # not unpacked here: mypy would
        outcome, P = probed  # infer the solution type from the targets and take None into it
        if outcome == lmi.FEASIBLE and P is not None:
            self.solutions[mu] = (P, float(found["t"]))
        elif (outcome == lmi.FAILED and found.get("status") == "optimal_inaccurate"
              and float(found["t"]) < -MARGIN_FLOOR and mu < 1.0 - 10.0 * lmi.RATE_GAP):  # fmt: skip
            self.inexact.append(mu)
            return lmi.INFEASIBLE
        return outcome
