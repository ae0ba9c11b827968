r"""The strong-detectability LMI with the unknown input and the output gain eliminated exactly.

Scaled increments ``dx+ = A dx + B dd`` (A in the hull of the cover's vertices, dd free),
``e = C dx``, ``e+ = C dx+``. With ``K = (C B / eps)^+`` and an orthonormal basis Q of the
complement of ``range(C B)``, every ``Y2 = P B K + Z Q^T`` satisfies ``Y2 (C B / eps) = P B``, so

    P dx+ = (P A - Y2 C A / eps) dx + Y2 (e+ / eps)        (dd has dropped out, for every w, w~)

and the certificate ``|dx+|_P^2 <= mu |dx|_P^2 + s1 |e|^2 + s2 |e+ / eps|^2`` holds when, at
every vertex ``A_i`` (Schur complement; affine in ``A_i``),

    [[mu P + s1 C^T C, 0,    (P G_i)^T],
     [0,               s2 I, Y2^T     ],      >= 0,   P G_i = P A_i - Y2 C A_i / eps.
     [P G_i,           Y2,   P        ]]

No gain on the current output appears: s1 absorbs it (Finsler's lemma). It is solved in stages:

1. **Rate** (bisection on mu): the LMI restricted to ``dx`` in ker C (``dx = N z``), where s1
   drops out, in the margin form ``max t`` with ``I / kappa <= P <= I`` (``kappa = max_condition``): feasible
   iff ``t > 0``.
2. **Design** at the chosen mu: the full LMI in the coordinates ``dx = N z + eps R m`` (R an
   orthonormal basis of ``range(C^T)``; this keeps ``s1 eps^2`` of order one), ``P >= I``,
   minimising ``max(s1 eps^2, s2) + 1e-3 tr(P) / n``, i.e. the output gain sigma_y of the paper
   form, then the condition number of P.
3. **Closed form**: with P, Y2, s2 fixed, the smallest s1 is a generalised eigenvalue
   (``Q = mu P - H^T W^-1 H``, ``W = [[s2 I, Y2^T], [Y2, P]]``, ``H = [0; P G_i]``, partitioned
   into ker C and range C^T), times ``1 + 1e-3``.

The numpy re-check (W > 0, ``N^T Q_i N > 0`` at every vertex, ``Y2 C B / eps = P B``) decides.
Eps is the size of the w-free part of ``C A N`` (the one-step visibility of the unmeasured
states), or ``sigma_min(C B)`` when the unknown input spans every output direction.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, overload

import numpy as np
import scipy.linalg

from uiest.box import FloatArray
from uiest.detectability import lmi
from uiest.detectability.certificate import DEFAULT_MAX_CONDITION

if TYPE_CHECKING:
    import cvxpy as cp
else:
    from uiest.detectability.lmi import cp  # cvxpy, imported when first used

__all__ = ["Geometry", "RateProblem", "StrongLMI", "StrongSolution"]

MARGIN_FLOOR = 1e-8
"""A rate is feasible when the restricted LMI keeps this margin (P normalised to ||P|| <= 1)."""

DESIGN_MARGIN = 1e-2
"""The design keeps this fraction of the rate problem's margin at every vertex."""

RETRY_MARGIN = 1e-2
"""After a solver error in the design, it is solved once more with this fraction of its margin; if that errs too,
once more from the two farthest-apart vertices, grown by cutting planes (nearly equal vertices, as an RK4 model's
exact cover over a small step gives, can make the solver err on the whole set)."""

TRACE_WEIGHT = 1e-3
"""Weight of tr(P) / n beside the output gain in the design objective."""

CONDITION_RTOL = 1e-6
"""A design's cond(P) may exceed max_condition by this fraction (the solver's tolerance); more is a failed solve."""

S1_SAFETY = 1e-3
"""The closed-form s1 is multiplied by 1 + S1_SAFETY, so the measured block keeps a margin."""


@dataclass(frozen=True, kw_only=True)
class StrongSolution:
    """A solution of the LMI of the module docstring, in scaled coordinates.

    Attributes
    ----------
    outcome : str
        ``lmi.FEASIBLE`` (certified), ``lmi.INFEASIBLE``, ``lmi.FAILED``, "below mu_min" or
        "re-check failed".
    reason : str
        One sentence with the numbers.
    mu, mu_min : float
        Design rate and the smallest rate found by bisection (NaN when not found).
    P : ndarray (n, n)
        Storage matrix, ``lambda_min(P) >= 1`` (NaN when not solved).
    Y2 : ndarray (n, p)
        Injection of the next output, ``L2 = P^-1 Y2 / eps`` per unit of ``e+``.
    s1, s2 : float
        Coefficients of ``|e|^2`` and ``|e+|^2`` (s2 is already divided by eps^2).
    eps : float
        The output scaling used.
    margin : float
        The smallest of the re-check's margins over ``||P||``: ``lambda_min(N^T Q_i N)``,
        ``lambda_min(W)`` and the direct check of the core inequality (:meth:`StrongLMI._direct_margin`).
    design : str
        Which solve produced P: "design" or "rate problem (design solve failed: ...)".
    bisection : lmi.Bisection or None

    """

    outcome: str
    reason: str
    mu: float
    mu_min: float
    P: FloatArray
    Y2: FloatArray
    s1: float
    s2: float
    eps: float
    margin: float
    design: str
    bisection: lmi.Bisection | None

    @property
    def sigma_y(self) -> float:
        """Paper-form output gain ``2 max(s1, s2)``: ``s1 |e|^2 + s2 |e+|^2 <= sigma_y/2 (|e|^2 + |e+|^2)``."""
        return 2.0 * max(self.s1, self.s2)


class Geometry:
    """Fixed matrices of the LMI for one (B, C) pair: N, R, K, Q and eps."""

    def __init__(self, vertices: FloatArray, B: FloatArray, C: FloatArray) -> None:
        n, p = C.shape[1], C.shape[0]
        self.n, self.p = n, p
        self.C, self.B = C, B
        self.N = scipy.linalg.null_space(C)
        self.R = scipy.linalg.orth(C.T)
        CB = C @ B
        self.Q = scipy.linalg.null_space(CB.T) if B.shape[1] else np.eye(p)
        free_part = max((np.linalg.norm(self.Q.T @ C @ A @ self.N, 2) for A in vertices), default=0.0)
        scale = np.linalg.norm(C, 2) * max(1.0, max(float(np.linalg.norm(A, 2)) for A in vertices))
        if self.Q.shape[1] and self.N.shape[1] and free_part > 1e-12 * scale:
            self.eps = float(free_part)
        elif B.shape[1]:
            self.eps = float(np.linalg.svd(CB, compute_uv=False)[-1])
        else:
            self.eps = 1.0
        self.K = np.linalg.pinv(CB / self.eps) if B.shape[1] else np.zeros((0, p))
        self.measured_gram = (C @ self.R).T @ (C @ self.R)
        self.k = self.N.shape[1]

    @overload
    def Y2(self, P: FloatArray, Z: FloatArray | None) -> FloatArray: ...
    @overload
    def Y2(self, P: cp.Expression, Z: cp.Expression | None) -> cp.Expression: ...
    def Y2(self, P: FloatArray | cp.Expression, Z: FloatArray | cp.Expression | None) -> FloatArray | cp.Expression:
        """``P B K + Z Q^T`` (the matched injection plus the free part)."""
        parts = []
        if self.B.shape[1]:
            parts.append(P @ (self.B @ self.K))
        if Z is not None and self.Q.shape[1]:
            parts.append(Z @ self.Q.T)
        if not parts:
            return np.zeros((self.n, self.p))
        return parts[0] if len(parts) == 1 else parts[0] + parts[1]

    def free_variable(self) -> cp.Variable | None:
        """Z (n, p - rank(C B)), or None when ``C B`` spans every output direction."""
        return cp.Variable((self.n, self.Q.shape[1])) if self.Q.shape[1] else None

    def restricted(self, A: FloatArray, P: FloatArray, Y2: FloatArray, s2: float, mu: float) -> FloatArray:
        """The restricted block matrix (k + p + n) of stage 1 at one vertex, in numpy."""
        PGN = (P @ A - Y2 @ (self.C @ A) / self.eps) @ self.N
        k, p = self.k, self.p
        return np.block([[mu * self.N.T @ P @ self.N, np.zeros((k, p)), PGN.T],
                         [np.zeros((p, k)), s2 * np.eye(p), Y2.T],
                         [PGN, Y2, P]])  # fmt: skip

    def kernel_blocks(
        self, vertices: FloatArray, P: FloatArray, Y2: FloatArray, s2: float, mu: float
    ) -> list[tuple[FloatArray, FloatArray, FloatArray]]:
        """Per vertex ``(Q_nn, Q_nm, Q_mm)`` of ``Q_i = mu P - H_i^T W^-1 H_i`` in ``[N, R]`` coordinates."""
        W = np.block([[s2 * np.eye(self.p), Y2.T], [Y2, P]])
        T = np.hstack([self.N, self.R])
        k = self.k
        out = []
        for A in vertices:
            H = np.vstack([np.zeros((self.p, self.n)), P @ A - Y2 @ (self.C @ A) / self.eps])
            QT = T.T @ (mu * P - H.T @ np.linalg.solve(W, H)) @ T
            QT = 0.5 * (QT + QT.T)
            out.append((QT[:k, :k], QT[:k, k:], QT[k:, k:]))
        return out


class RateProblem:
    """Stage 1 on a set of vertices: ``max t`` with the restricted LMIs ``>= t I``, ``cond(P) <= kappa``.

    mu is a Parameter: bisection re-solves without recompiling.
    """

    def __init__(self, geometry: Geometry, vertices: FloatArray, kappa: float) -> None:
        g = geometry
        n, p, k = g.n, g.p, g.k
        self.geometry, self.vertices = g, vertices
        self.mu = cp.Parameter(nonneg=True, value=0.5)
        self.P = cp.Variable((n, n), symmetric=True)
        self.Z = g.free_variable()
        self.s2 = cp.Variable(nonneg=True)
        self.t = cp.Variable()
        Y2 = g.Y2(self.P, self.Z)
        s2_cap = 1e6 * max(1.0, float(np.linalg.norm(g.K, 2)) ** 2 if g.K.size else 1.0)
        constraints = [self.P << np.eye(n), self.P >> np.eye(n) / kappa, self.s2 <= s2_cap]
        for A in vertices:
            PGN = (self.P @ A - Y2 @ (g.C @ A) / g.eps) @ g.N
            block = cp.bmat([[self.mu * (g.N.T @ self.P @ g.N), np.zeros((k, p)), PGN.T],
                             [np.zeros((p, k)), self.s2 * np.eye(p), Y2.T],
                             [PGN, Y2, self.P]])  # fmt: skip
            constraints.append(lmi.symmetric(block) >> self.t * np.eye(k + p + n))
        self.problem = cp.Problem(cp.Maximize(self.t), constraints)

    def solve(self, mu: float) -> tuple[str, tuple[FloatArray, FloatArray, float] | None, float]:
        """Solve at ``mu``; returns (status, (P, Y2, s2) or None, t)."""
        self.mu.value = mu
        status = lmi.solve(self.problem)
        if status not in lmi.SOLVED or self.P.value is None or self.s2.value is None or self.t.value is None:
            return status, None, float("nan")
        P = 0.5 * (self.P.value + self.P.value.T)
        Z = None if self.Z is None else self.Z.value
        return status, (P, self.geometry.Y2(P, Z), float(self.s2.value)), float(self.t.value)


def restricted_margins(
    geometry: Geometry, vertices: FloatArray, P: FloatArray, Y2: FloatArray, s2: float, mu: float
) -> FloatArray:
    """Smallest eigenvalue of each vertex's restricted block over ``max(||P||, s2)``, shape (m,)."""
    blocks = np.stack([geometry.restricted(A, P, Y2, s2, mu) for A in vertices])
    return lmi.min_eig(blocks) / max(float(np.linalg.eigvalsh(P)[-1]), s2)


class StrongLMI:
    """Rate bisection, design and closed-form s1 for fixed vertices, B and C (all scaled).

    cond(P) is bounded by ``max_condition`` in the rate problem and the design.
    """

    def __init__(
        self, vertices: FloatArray, B: FloatArray, C: FloatArray, max_condition: float = DEFAULT_MAX_CONDITION
    ) -> None:
        self.geometry = Geometry(vertices, B, C)
        self.kappa = float(max_condition)
        self.vertices = vertices
        self.active = lmi.ActiveSet(vertices)
        self._rate_problem: RateProblem | None = None
        self._rate_size = -1

    def _rate(self) -> RateProblem:
        if self._rate_problem is None or self._rate_size != len(self.active.index):
            self._rate_problem = RateProblem(self.geometry, self.active.vertices, self.kappa)
            self._rate_size = len(self.active.index)
        return self._rate_problem

    def probe(self, mu: float) -> str:
        """Outcome of the rate problem at ``mu`` on all vertices (cutting plane over the active set)."""
        return self._probe(mu)[0]

    def _probe(self, mu: float) -> tuple[str, tuple[FloatArray, FloatArray, float] | None, float]:
        """(outcome, solution, margin t) of the rate problem at ``mu`` on all vertices."""
        found: dict[str, float] = {"t": float("nan")}

        def solve() -> tuple[str, tuple[FloatArray, FloatArray, float] | None, float]:
            status, solution, t = self._rate().solve(mu)
            found["t"] = t
            return status, solution, t

        def recheck(solution: tuple[FloatArray, FloatArray, float]) -> FloatArray:
            return restricted_margins(self.geometry, self.vertices, *solution, mu)

        probed = lmi.cutting_plane_probe(solve, recheck, self.active, MARGIN_FLOOR)  # not unpacked: mypy would infer
        return probed[0], probed[1], found["t"]  # the solution type from the targets and take None into it

    def solve(self, mu: float | None, *, tol: float = 1e-4, mu_min: float | None = None) -> StrongSolution:
        """Bisect for mu_min, design at mu, then the closed-form s1 and the re-check.

        mu_min is not bisected when given or when every state is measured; mu defaults to
        ``mu_min + 0.02 (1 - mu_min)``. cond(P) is bounded by ``max_condition`` in the rate problem and the
        design.
        """
        g = self.geometry
        if g.k == 0:  # every state is measured: any rate works
            bisection = lmi.Bisection(rate=lmi.RATE_FLOOR, outcome=lmi.FEASIBLE, failed_at=(), probes=0)
        elif mu_min is not None:
            bisection = lmi.Bisection(
                rate=max(float(mu_min), lmi.RATE_FLOOR), outcome=lmi.FEASIBLE, failed_at=(), probes=0
            )
        else:
            bisection = lmi.bisect_rate(self.probe, tol=tol)
        if bisection.rate is None:
            what = (f"infeasible for every mu < 1: no quadratic storage with cond(P) <= {self.kappa:g} and an output "
                    "weight within 1e6 of the matched injection's certifies strong detectability"
                    if bisection.outcome == lmi.INFEASIBLE else
                    "the LMI solver failed at every rate tried; nothing was decided")  # fmt: skip
            return self._unsolved(bisection.outcome, what, float("nan"), bisection)
        mu_min = bisection.rate
        mu_used = mu if mu is not None else mu_min + 0.02 * (1.0 - mu_min)
        outcome, rate_solution, t = self._probe(mu_used) if g.k else (lmi.FEASIBLE, None, 1.0)
        if outcome == lmi.INFEASIBLE and mu_used < mu_min:
            return self._unsolved("below mu_min", f"mu={mu_used:.6g} is below the smallest certifiable rate "
                                  f"mu_min={mu_min:.6g} found", mu_min, bisection)  # fmt: skip
        if outcome != lmi.FEASIBLE:  # above a feasible rate, 'infeasible' contradicts monotonicity: a failure
            return self._unsolved(lmi.FAILED, f"the solver failed in the rate problem at mu={mu_used:.6g} "
                                  f"('{outcome}'; mu_min={mu_min:.6g} was feasible)", mu_min, bisection)  # fmt: skip
        status, design = self._design(mu_used, DESIGN_MARGIN * t)
        if design is None and status not in ("infeasible", "infeasible_inaccurate"):  # a solver error: smaller margin
            status, design = self._design(mu_used, RETRY_MARGIN * DESIGN_MARGIN * t)
        if design is None and status not in ("infeasible", "infeasible_inaccurate") and len(self.active.index) > 2:
            self.active = lmi.ActiveSet(self.vertices, size=2)  # nearly equal vertices: grown by cutting planes
            status, design = self._design(mu_used, DESIGN_MARGIN * t)
        note = "design"
        if design is None:
            if rate_solution is None:
                return self._unsolved(lmi.FAILED, f"the design solve failed at mu={mu_used:.6g} ({status})",
                                      mu_min, bisection)  # fmt: skip
            P, Y2, s2 = rate_solution
            low = float(np.linalg.eigvalsh(P)[0])
            design, note = (P / low, Y2 / low, s2 / low), "rate problem (the design solve failed)"
        return self._finish(mu_used, mu_min, *design, note, bisection)

    def _design(self, mu: float, margin: float) -> tuple[str, tuple[FloatArray, FloatArray, float] | None]:
        """Stage 2 on the active vertices, grown until every vertex has ``N^T Q N > 0``: (solver status, solution)."""
        g = self.geometry
        for _ in range(len(self.vertices)):
            status, solution = self._design_once(self.active.vertices, mu, margin)
            if solution is None or not g.k:
                return status, solution
            margins = np.array([np.linalg.eigvalsh(b[0])[0] for b in g.kernel_blocks(self.vertices, *solution, mu)])
            if margins.min() > 0.0:
                return status, solution
            if not self.active.add_worst(margins):
                return "no vertex left to add", None
        return "no vertex left to add", None

    def _design_once(
        self, vertices: FloatArray, mu: float, margin: float
    ) -> tuple[str, tuple[FloatArray, FloatArray, float] | None]:
        """The design with cond(P) free, then, if that exceeds ``max_condition``, with it bounded.

        A bound far above the solution's condition number only hurts the solver, so it is imposed
        where it binds.
        """
        status, solution = self._design_solve(vertices, mu, margin, bounded=False)
        if solution is not None and np.linalg.cond(solution[0]) > self.kappa:
            status, solution = self._design_solve(vertices, mu, margin, bounded=True)
        return status, solution

    def _design_solve(
        self, vertices: FloatArray, mu: float, margin: float, *, bounded: bool
    ) -> tuple[str, tuple[FloatArray, FloatArray, float] | None]:
        g = self.geometry
        n, p, k = g.n, g.p, g.k
        T = np.hstack([g.N, g.eps * g.R])
        P = cp.Variable((n, n), symmetric=True)
        Z = g.free_variable()
        s1_eps2, s2, gain = cp.Variable(nonneg=True), cp.Variable(nonneg=True), cp.Variable()  # s1 eps^2
        Y2 = g.Y2(P, Z)
        rank = g.R.shape[1]
        constraints = [P >> np.eye(n), s1_eps2 <= gain, s2 <= gain]
        if bounded:  # lambda_min(P) >= low >= 1, lambda_max(P) <= kappa low: cond(P) <= kappa at any scale
            low = cp.Variable()
            constraints += [low >= 1.0, P >> low * np.eye(n), P << (self.kappa * low) * np.eye(n)]
        measured = cp.bmat([[np.zeros((k, k)), np.zeros((k, rank))], [np.zeros((rank, k)), s1_eps2 * g.measured_gram]])
        for A in vertices:
            H = (P @ A - Y2 @ (g.C @ A) / g.eps) @ T
            block = cp.bmat([[mu * (T.T @ P @ T) + measured, np.zeros((n, p)), H.T],
                             [np.zeros((p, n)), s2 * np.eye(p), Y2.T],
                             [H, Y2, P]])  # fmt: skip
            constraints.append(lmi.symmetric(block) >> margin * np.eye(2 * n + p))
        problem = cp.Problem(cp.Minimize(gain + TRACE_WEIGHT * cp.trace(P) / n), constraints)
        status = lmi.solve(problem)
        if status not in lmi.SOLVED or P.value is None or s2.value is None:
            return status, None
        Pv = 0.5 * (P.value + P.value.T)
        if bounded and np.linalg.cond(Pv) > self.kappa * (1.0 + CONDITION_RTOL):
            return f"cond(P) {np.linalg.cond(Pv):.6g} above max_condition ({status})", None
        return status, (Pv, g.Y2(Pv, None if Z is None else Z.value), float(s2.value))

    def _finish(
        self, mu: float, mu_min: float, P: FloatArray, Y2: FloatArray, s2: float, note: str, bisection: lmi.Bisection
    ) -> StrongSolution:
        g = self.geometry
        norm_P = float(np.linalg.eigvalsh(P)[-1])
        W_margin = float(np.linalg.eigvalsh(np.block([[s2 * np.eye(g.p), Y2.T], [Y2, P]]))[0]) / max(norm_P, s2)
        matched = float(np.abs(Y2 @ (g.C @ g.B) / g.eps - P @ g.B).max(initial=0.0)) / norm_P
        blocks = g.kernel_blocks(self.vertices, P, Y2, s2, mu)
        kernel = min(float(np.linalg.eigvalsh(b[0])[0]) for b in blocks) / norm_P if g.k else np.inf
        s1 = 0.0
        if kernel > 0.0 and W_margin > 0.0:
            worst = max(float(scipy.linalg.eigh(nm.T @ np.linalg.solve(nn, nm) - mm if g.k else -mm, g.measured_gram,
                                                eigvals_only=True)[-1]) for nn, nm, mm in blocks)  # fmt: skip
            s1 = max(worst, 0.0) * (1.0 + S1_SAFETY) + 1e-12 * norm_P / float(np.linalg.eigvalsh(g.measured_gram)[0])
        direct, tolerance = self._direct_margin(mu, P, s1, s2 / g.eps**2) if kernel > 0.0 < W_margin else (-np.inf, 0.0)
        margin = min(kernel, W_margin, direct)
        ok = kernel > 0.0 and W_margin > 0.0 and direct >= -tolerance and matched <= 1e-9
        reason = (
            f"certified: mu={mu:.6g} (mu_min={mu_min:.6g}), cond(P)={np.linalg.cond(P):.3g}, re-check margin "
            f"{margin:.2e}{f' (within the rounding {tolerance:.1e})' if margin < 0 else ''}, w eliminated to "
            f"{matched:.1e}"
            if ok
            else f"re-check failed at mu={mu:.6g}: kernel margin {kernel:.2e}, W margin {W_margin:.2e}, direct "
            f"margin {direct:.2e} (rounding {tolerance:.1e}), elimination residual {matched:.1e}"
        )
        if bisection.note:
            reason += f" ({bisection.note})"
        if note != "design":  # the rate problem's P: larger gains than a design's
            reason += f"; P from the {note}"
        return StrongSolution(
            outcome=lmi.FEASIBLE if ok else "re-check failed",
            reason=reason,
            mu=float(mu),
            mu_min=float(mu_min),
            P=P,
            Y2=Y2,
            s1=float(s1),
            s2=float(s2 / g.eps**2),
            eps=g.eps,
            margin=float(margin),
            design=note,
            bisection=bisection,
        )

    def _direct_margin(self, mu: float, P: FloatArray, s1: float, s2: float) -> tuple[float, float]:
        """The core inequality checked directly, without Schur complements: (margin, rounding), over ``||P||``.

        At each vertex, ``|A dx + B dd|_P^2 - mu |dx|_P^2 - s1 |C dx|^2 - s2 |C (A dx + B dd)|^2`` is a
        quadratic form in (dx, dd) that must be negative semidefinite; the margin is minus its
        largest eigenvalue, the rounding ``1e-13`` times its largest entry.
        """
        g = self.geometry
        norm_P = float(np.linalg.eigvalsh(P)[-1])
        margin, rounding = np.inf, 0.0
        for A in self.vertices:
            AB = np.hstack([A, g.B])
            M = AB.T @ (P - s2 * g.C.T @ g.C) @ AB
            M[: g.n, : g.n] -= mu * P + s1 * g.C.T @ g.C
            margin = min(margin, -float(np.linalg.eigvalsh(0.5 * (M + M.T))[-1]) / norm_P)
            rounding = max(rounding, 1e-13 * float(np.abs(M).max()) / norm_P)
        return margin, rounding

    def _unsolved(self, outcome: str, reason: str, mu_min: float, bisection: lmi.Bisection | None) -> StrongSolution:
        n, p = self.geometry.n, self.geometry.p
        if bisection is not None and bisection.note:
            reason += f" ({bisection.note})"
        nan = float("nan")
        return StrongSolution(
            outcome=outcome,
            reason=reason,
            mu=nan,
            mu_min=mu_min,
            P=np.full((n, n), nan),
            Y2=np.full((n, p), nan),
            s1=nan,
            s2=nan,
            eps=self.geometry.eps,
            margin=nan,
            design="",
            bisection=bisection,
        )
