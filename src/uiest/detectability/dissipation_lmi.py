r"""The incremental dissipation LMI solved in stages: the rate on a kernel, a design, the output weight in closed form.

Scaled increments ``xi = (dz, dd)`` (``n + nd``), the cover's vertices ``J_i = [A_i, B_i]`` (n, n + nd) and
output Jacobians ``G_i`` (p, n + nd). A certificate is ``P >= I``, channel weights ``q >= 0`` and an output
weight ``r >= 0`` with, at every vertex,

    M_i = blkdiag(mu P, q_1 I, ..., q_c I) + r G_i^T G_i - J_i^T P J_i >= 0.

Any finite weights certify, so they are free while the rate is sought, and the solve has four stages:

1. **Rate** (:mod:`uiest.detectability.dissipation_rate`). By Finsler's lemma for the map
   ``xi -> (dd, G_i xi)``, weights with ``M_i > 0`` exist iff ``K_i^T (mu P - A_i^T P A_i) K_i > 0``, K_i an
   orthonormal basis of ``ker G_{z,i}``: the storage must contract along the states the current output
   does not see (dd = 0). The margin problem ``max t`` (up to ``mu / 2``) with these blocks ``>= t I``,
   the storage on the kernels normalised and ``cond(P) <= kappa`` is solved in *balanced* coordinates
   ``dz = T z_hat`` in which a storage found earlier is the identity: where the unmeasured states show in
   the output only through a small one-step coupling, the storage that contracts them has a condition
   number of order ``1 / coupling^2`` (1e12 on slowly sampled models), and in balanced coordinates that
   is a well-scaled problem. Bisection on mu.
2. **Design** (:mod:`uiest.detectability.dissipation_design`) at the chosen mu, in the coordinates
   balanced at a storage within the bound: the full LMI at the rate ``mu - delta`` with the weights
   times ``1 - delta`` (so the certificate at mu keeps a margin ``delta`` relative to P and the weights),
   ``P >= I``, ``cond(P) <= kappa``, minimising the weights relative to a feasible point (one closed-form
   multiplier ``sigma`` for all of them) plus ``1e-3 tr(P_hat) / n``; in the Schur form, else M itself.
3. **Closed form.** With P and q fixed, the smallest r is a generalised eigenvalue
   (:func:`smallest_weight`), times ``1 + 1e-3``.
4. **Re-check** in numpy at every vertex (:func:`~uiest.detectability.dissipation_design.recheck`), which
   alone decides: the block of
   ``Q_i = M_i - r G_i^T G_i`` on ``ker G_i`` positive definite, the Schur complement on ``range G_i^T``
   with r positive semidefinite, and the smallest eigenvalue of ``M_i`` itself within its rounding.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np
import numpy.typing as npt
import scipy.linalg

from uiest.box import FloatArray

__all__ = ["CONDITION_RTOL", "Vertices", "balancing", "smallest_weight"]

KERNEL_RTOL = 1e-10
"""Singular values of the state output map below this fraction of the output map's norm count as zero."""

CONDITION_RTOL = 1e-6
"""A design's cond(P) may exceed max_condition by this fraction (the solver's tolerance); more is a failed solve."""


@dataclass(frozen=True, eq=False, kw_only=True)
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
        return cls(J=J[:, :, keep], G=G[:, :, keep], channel_of=channel_of[used], n_channels=len(channels), n=n)

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
        return Vertices(
            J=self.J[list(index)],
            G=self.G[list(index)],
            channel_of=self.channel_of,
            n_channels=self.n_channels,
            n=self.n,
        )

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
    """``T = U diag(w)^-1/2`` from ``P = U diag(w) U^T`` (``w_min = 1``): ``T^T P T = I`` with ``T^T T`` diagonal.

    The bound on cond(P) then reads ``s W >= P_hat >= s W / kappa`` with W diagonal (its spread is that of P),
    which interior-point solvers resolve where a full W of the same spread defeats them.
    """
    w, U = np.linalg.eigh(0.5 * (P + P.T))
    return U / np.sqrt(w / w[0])
