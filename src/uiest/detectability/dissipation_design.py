"""Stages 2-4 of the dissipation LMI (:mod:`uiest.detectability.dissipation_lmi`): design, output weight, re-check.

At the chosen rate, from a storage of the rate stage: the weights designed in coordinates balanced at
it, the smallest output weight in closed form, and the numpy re-check at every vertex that alone
decides; where the design fails, the rate stage's storage with one closed-form weight for every channel.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import scipy.linalg

from uiest.box import FloatArray
from uiest.detectability import lmi
from uiest.detectability.dissipation_lmi import CONDITION_RTOL, Vertices, balancing, smallest_weight

if TYPE_CHECKING:
    import cvxpy as cp
else:
    from uiest.detectability.lmi import cp  # cvxpy, imported when first used

__all__ = ["ROUNDING", "Finished", "Recheck", "design_and_check", "recheck"]

DESIGN_SLACK = 0.5
"""The design imposes the inequality at ``mu - DESIGN_SLACK * t``, t the rate problem's margin at mu."""

TRACE_WEIGHT = 1e-3
"""Weight of ``tr(P_hat) / n`` beside the weights in the design objective."""

R_SAFETY = 1e-3
"""The closed-form output weight is multiplied by ``1 + R_SAFETY``."""

ROUNDING = 1e-13
"""The direct check of M_i passes within this fraction of its largest entry (double-precision rounding)."""


@dataclass(frozen=True, kw_only=True)
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
    lowest = float(np.linalg.eigvalsh(P_val)[0])
    if not lowest > 0.0:
        return "singular storage", None
    if bounded and np.linalg.cond(P_val) > kappa * (1.0 + CONDITION_RTOL):
        return f"cond(P) {np.linalg.cond(P_val):.6g} above max_condition ({status})", None
    q_val = np.maximum(np.asarray(q.value, dtype=float).reshape(-1), 0.0) * sigma
    return status, Design(P=P_val / lowest, q=q_val / lowest, note="design")


def output_weight(vertices: Vertices, P: FloatArray, q: FloatArray, mu: float) -> float:
    """Stage 3: the smallest r with ``Q_i + r G_i^T G_i >= 0`` at every vertex, times ``1 + R_SAFETY`` (inf if none)."""
    Q = vertices.supply(P, q, mu)
    r = max(smallest_weight(Qi, Gi) for Qi, Gi in zip(Q, vertices.G, strict=True))
    return r * (1.0 + R_SAFETY) if np.isfinite(r) else np.inf


@dataclass(frozen=True, kw_only=True)
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
    return Recheck(kernel=kernel, schur=schur, direct=direct)


@dataclass(frozen=True, kw_only=True)
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
    """Stages 2-4 at mu from the rate problem's storage and margin.

    The design runs on an active set of vertices grown by cutting planes; where it fails, the fallback is
    the rate problem's storage with one closed-form weight for every channel. None when even the fallback
    has no finite weights (the rate problem's storage does not contract the kernel).
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
            return Finished(P=designed.P, q=designed.q, r=r, check=check, note="design")
        if not active.add_worst(check.per_vertex):
            status = f"re-check failed at an imposed vertex (margin {check.margin:.2e})"
            break
    q = np.full(vertices.n_channels, sigma * (1.0 + R_SAFETY))
    r = output_weight(vertices, P_rate, q, mu)
    note = f"the rate problem's storage with one closed-form weight for every channel (design: {status})"
    return Finished(P=P_rate, q=q, r=r, check=recheck(vertices, P_rate, q, r, mu), note=note)
