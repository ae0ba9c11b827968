"""Strong detectability of LTI systems ``x+ = A x + B w``, ``y = C x + v`` (paper: lemma "UIO_LTI").

The system is strongly detectable iff (ii) rank(CB) = rank(B) (matching) and (i) every invariant
zero of the Rosenbrock pencil ``P(z) = [zI - A, -B; C, 0]`` lies strictly inside the unit disk.
Following the proof, ``B T = (B_tilde, 0)`` with ``B_tilde`` an orthonormal basis of range(B),
``Y = pinv(C B_tilde)`` and the estimation error obeys ``e+ = (A - B_tilde Y C A) e + B_tilde Y dy``.

When it is, the certificate of :mod:`uiest.detectability.strong_lmi` at the single vertex A gives
the quadratic storage and the weights (``mu = mu_min + 0.02 (1 - mu_min)`` unless given), in
the coordinates of (A, B, C) as given (no scaling).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg
from numpy.typing import ArrayLike, NDArray

from uiest.detectability.certificate import (
    CERTIFIED,
    INFEASIBLE,
    SOLVER_FAILED,
    STATUS_OF,
    CertificateStatus,
    StrongDetectabilityBase,
    Verification,
    check_rate,
)
from uiest.detectability.strong import worst_case_ratio
from uiest.detectability.strong_lmi import StrongLMI
from uiest.errors import ModelError, OptionError

__all__ = [
    "UNIT_CIRCLE_TOL",
    "LinearStrongDetectability",
    "invariant_zeros",
    "linear_strong_detectability",
    "observer_gain",
    "off_unit_disk",
]

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]

UNIT_CIRCLE_TOL = 1e-9
"""A zero or eigenvalue whose modulus is within this of 1 lies on the unit circle: computed moduli carry rounding
(a zero exactly at 1 comes out as 0.9999999999999999), and one on the circle is an undamped motion, not a decaying
one."""


def off_unit_disk(modulus: float) -> bool:
    """Whether a zero of modulus ``modulus`` is on or outside the unit circle (within :data:`UNIT_CIRCLE_TOL`)."""
    return modulus >= 1.0 - UNIT_CIRCLE_TOL


_SEED = 20_240_517  # fixed seed of the random pencil compressions: results are deterministic
_MATCH_TOL = 1e-4  # two compressions agree on a candidate z within _MATCH_TOL * (1 + |z|)
_CONFIRM_FACTOR = 100.0  # zero iff sigma_r(P(z)) <= 100 rtol |pencil|: weakly observable modes are no zeros


@dataclass(frozen=True, eq=False, kw_only=True)
class LinearStrongDetectability(StrongDetectabilityBase):
    """Result of :func:`linear_strong_detectability` for ``A (n, n)``, ``B (n, q)``, ``C (p, n)``.

    A :class:`~uiest.detectability.certificate.Certificate` (``certified`` iff strongly
    detectable and the LMI re-check passed; ``rate`` is the design mu, ``rate_min = max |z|^2``)
    with the Hautus test's findings.

    Attributes
    ----------
    matching : bool
        rank(CB) == rank(B).
    rank_B, rank_CB : int
        Numerical ranks (see :func:`linear_strong_detectability` for the tolerances).
    rank_tol : float
        The relative SVD tolerance ``rtol`` used.
    invariant_zeros : ndarray of complex, shape (k,)
        Invariant zeros, sorted by decreasing modulus.
    strongly_detectable : bool
        Matching holds and every zero has modulus < 1.
    B_tilde : ndarray, shape (n, rank_B)
        Orthonormal basis of range(B) (always set).
    Y : ndarray, shape (rank_B, p) or None
        ``pinv(C B_tilde)``, a left inverse of ``C B_tilde``; None when matching fails.
    error_matrix : ndarray, shape (n, n) or None
        ``A - B_tilde Y C A``; None when matching fails.
    observer_gain : ndarray, shape (n, p) or None
        ``K`` with ``error_matrix - K C`` Schur stable; None unless strongly detectable.
    sigma_y : float
        ``sigma_y(r) = sigma_y r^2`` (and ``sigma_v`` the same, for ``y = C x + v``).
    R_y, R_v : ndarray (p, p)
        ``sigma_y I``.
    A, C : ndarray
        The system matrices.

    """

    matching: bool
    rank_B: int  # noqa: N815 (the paper's names)
    rank_CB: int  # noqa: N815
    rank_tol: float
    invariant_zeros: ComplexArray
    strongly_detectable: bool
    B_tilde: FloatArray
    Y: FloatArray | None
    error_matrix: FloatArray | None
    observer_gain: FloatArray | None
    sigma_y: float
    R_y: FloatArray
    R_v: FloatArray
    A: FloatArray = field(repr=False)
    C: FloatArray = field(repr=False)

    kind = "linear_strong_detectability"

    @property
    def spectral_radius(self) -> float | None:
        """Spectral radius of ``error_matrix - observer_gain C``; None when there is no gain."""
        if self.observer_gain is None or self.error_matrix is None:
            return None
        closed = self.error_matrix - self.observer_gain @ self.C
        return float(np.max(np.abs(np.linalg.eigvals(closed)), initial=0.0))

    def _verify(self, n_pairs: int, seed: int) -> Verification:
        """Eq. (5b) on random increments (the system is linear: pairs are increments)."""
        rng = np.random.default_rng(seed)
        n, p = self.A.shape[0], self.C.shape[0]
        dx = rng.standard_normal((n_pairs, n)) * 10.0 ** rng.uniform(-3, 3, (n_pairs, 1))
        noisy = (np.arange(n_pairs) % 2 == 0)[:, None]
        dv, dv_next = (np.where(noisy, rng.uniform(-1.0, 1.0, (n_pairs, p)), 0.0) for _ in range(2))
        return worst_case_ratio(
            a=dx @ self.A.T, dx=dx, dy=dx @ self.C.T + dv, noise_next=dv_next,
            dv2=np.sum(dv**2, axis=1) + np.sum(dv_next**2, axis=1), P=self.P_scaled, C=self.C, B=self.B_tilde,
            mu=self.mu, sigma_y=self.sigma_y, sigma_v=self.sigma_y,
        )  # fmt: skip

    def _details(self) -> dict[str, object]:
        return {
            "matching": self.matching,
            "rank_B": self.rank_B,
            "rank_CB": self.rank_CB,
            "invariant_zeros": [[z.real, z.imag] for z in self.invariant_zeros],
            "strongly_detectable": self.strongly_detectable,
            "mu": self.mu,
            "mu_min": self.mu_min,
            "sigma_y": self.sigma_y,
        }


def _as_matrix(value: ArrayLike, name: str, expected: str) -> FloatArray:
    try:
        arr = np.asarray(value)
        if np.iscomplexobj(arr):
            raise TypeError("complex entries")
        arr = arr.astype(float)
    except (TypeError, ValueError) as exc:
        raise ModelError(f"{name}: expected a real matrix of shape {expected}, got {value!r}") from exc
    if arr.ndim != 2:
        raise ModelError(f"{name}: expected a 2-D array of shape {expected}, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ModelError(f"{name}: expected finite entries in a matrix of shape {expected}, got non-finite values")
    return arr


def _validate(A: ArrayLike, B: ArrayLike, C: ArrayLike, rtol: float) -> tuple[FloatArray, FloatArray, FloatArray]:
    if not (isinstance(rtol, int | float) and math.isfinite(rtol) and 0.0 < rtol < 1.0):
        raise OptionError(f"rtol: expected a number in (0, 1), got {rtol!r}")
    A_ = _as_matrix(A, "A", "(n, n)")
    n = A_.shape[0]
    if A_.shape != (n, n) or n == 0:
        raise ModelError(f"A: expected a square matrix of shape (n, n) with n >= 1, got shape {A_.shape}")
    B_ = _as_matrix(B, "B", f"({n}, q)")
    if B_.shape[0] != n:
        raise ModelError(f"B: expected shape ({n}, q) to match A {A_.shape}, got shape {B_.shape}")
    C_ = _as_matrix(C, "C", f"(p, {n})")
    if C_.shape[1] != n:
        raise ModelError(f"C: expected shape (p, {n}) to match A {A_.shape}, got shape {C_.shape}")
    return A_, B_, C_


def _rank(M: NDArray, rtol: float, scale: float | None = None) -> int:
    """Number of singular values of ``M`` above ``rtol * scale`` (scale: largest singular value)."""
    if M.size == 0:
        return 0
    s = np.linalg.svd(M, compute_uv=False)
    ref = s[0] if scale is None else scale
    return int(np.sum(s > rtol * ref)) if ref > 0 else 0


def _pencil(A: FloatArray, B: FloatArray, C: FloatArray) -> tuple[FloatArray, FloatArray]:
    """``M = [A, B; -C, 0]`` and ``N = blockdiag(I_n, 0)``, both (n+p, n+q), so ``P(z) = z N - M``."""
    n, q, p = A.shape[0], B.shape[1], C.shape[0]
    M = np.zeros((n + p, n + q))
    M[:n, :n], M[:n, n:], M[n:, :n] = A, B, -C
    N = np.zeros_like(M)
    N[:n, :n] = np.eye(n)
    return M, N


def _compressed_eigenvalues(M: FloatArray, N: FloatArray, r: int, rng: np.random.Generator) -> ComplexArray:
    """Finite eigenvalues of ``(U^T M V, U^T N V)`` for random orthonormal ``U``, ``V`` with r columns."""
    U = np.linalg.qr(rng.standard_normal((M.shape[0], r)))[0]
    V = np.linalg.qr(rng.standard_normal((M.shape[1], r)))[0]
    alpha, beta = scipy.linalg.eig(U.T @ M @ V, U.T @ N @ V, right=False, homogeneous_eigvals=True)
    finite = (beta != 0) & np.isfinite(alpha)
    return (alpha[finite] / beta[finite]).astype(complex)


def _orthonormal_range(M: FloatArray, rtol: float) -> FloatArray:
    """Orthonormal columns spanning the range of ``M`` (its rank by ``rtol``), shape (rows, rank)."""
    if M.size == 0:
        return np.zeros((M.shape[0], 0))
    U, s, _ = np.linalg.svd(M, full_matrices=False)
    return U[:, : int(np.sum(s > rtol * s[0]))] if s[0] > 0 else np.zeros((M.shape[0], 0))


def _zeros(A: FloatArray, B: FloatArray, C: FloatArray, rtol: float) -> ComplexArray:
    # The zeros do not change when B's columns or C's rows are recombined: orthonormal bases of their
    # spans, scaled to A's size, keep a small B or C (a sampled high relative degree: CB ~ dt^r) from
    # vanishing below rtol beside A in the pencil's rank tests.
    size = max(1.0, float(np.linalg.norm(A, 2)) if A.size else 1.0)
    M, N = _pencil(A, size * _orthonormal_range(B, rtol), size * _orthonormal_range(C.T, rtol).T)
    rng = np.random.default_rng(_SEED)
    norm_M, norm_N = float(np.linalg.norm(M, 2)), float(np.linalg.norm(N, 2))
    probes = (1.0 + norm_M) * (rng.standard_normal(2) + 1j * rng.standard_normal(2))
    r = max(_rank(z * N - M, rtol) for z in probes)  # normal rank
    if r == 0:
        return np.zeros(0, dtype=complex)
    first, second = (_compressed_eigenvalues(M, N, r, rng) for _ in range(2))
    unused = list(second)
    zeros: list[complex] = []
    for z in first:
        if not unused:
            break
        dist = np.abs(np.asarray(unused) - z)
        j = int(np.argmin(dist))
        if dist[j] > _MATCH_TOL * (1.0 + abs(z)):
            continue
        unused.pop(j)
        sigma_r = np.linalg.svd(z * N - M, compute_uv=False)[r - 1]
        if sigma_r <= _CONFIRM_FACTOR * rtol * (norm_M + abs(z) * norm_N):
            zeros.append(complex(z))
    zeros.sort(key=lambda z: (-abs(z), z.real, z.imag))
    return np.array(zeros, dtype=complex)


def invariant_zeros(A: ArrayLike, B: ArrayLike, C: ArrayLike, *, rtol: float = 1e-9) -> ComplexArray:
    """Invariant zeros of ``[zI - A, -B; C, 0]`` for any shapes ``A (n, n)``, ``B (n, q)``, ``C (p, n)``.

    The finite z where the pencil loses rank below its normal rank r (the rank at a random
    complex point, SVD tolerance ``rtol`` times the largest singular value), with B and C replaced by
    orthonormal bases of range(B) and row(C) scaled to ``max(1, ||A||)`` (same zeros). The pencil is
    compressed to r x r twice with random orthonormal ``U ((n+p), r)``, ``V ((n+q), r)`` (fixed
    seed); finite generalized eigenvalues found by both compressions are candidates, and each is
    kept when the r-th singular value of P(z) is at most ``100 rtol (||M|| + |z| ||N||)``.

    Returns
    -------
    ndarray of complex, shape (k,)
        The zeros with multiplicity, sorted by decreasing modulus.

    """
    return _zeros(*_validate(A, B, C, rtol), rtol)


def linear_strong_detectability(
    A: ArrayLike, B: ArrayLike, C: ArrayLike, *, rtol: float = 1e-9, mu: float | None = None
) -> LinearStrongDetectability:
    """Decide strong detectability of ``x+ = A x + B w``, ``y = C x + v`` (lemma "UIO_LTI").

    Parameters
    ----------
    A : array_like, shape (n, n)
    B : array_like, shape (n, q)
        Unknown-input matrix; need not have full column rank (q = 0 allowed).
    C : array_like, shape (p, n)
    rtol : float
        Relative SVD rank tolerance: rank(B) counts singular values above ``rtol * sigma_max(B)``,
        rank(CB) those above ``rtol * sigma_max(C) * sigma_max(B)`` (so that round-off in a
        product that vanishes exactly does not count), pencil ranks ``rtol * sigma_max(P(z))``.
    mu : float, optional
        Design rate of the quadratic certificate (default ``mu_min + 0.02 (1 - mu_min)``).

    Raises
    ------
    ModelError
        Non-2-D, non-finite or non-real matrices or disagreeing shapes (names the argument).
    OptionError
        ``rtol`` not in (0, 1), ``mu`` not in (0, 1).

    """
    start = time.perf_counter()
    mu = check_rate(mu, "mu")
    A_, B_, C_ = _validate(A, B, C, rtol)
    U, s, _ = np.linalg.svd(B_, full_matrices=False)
    rank_B = _rank(B_, rtol)
    B_tilde = U[:, :rank_B]
    norm_C = float(np.linalg.norm(C_, 2)) if C_.size else 0.0
    rank_CB = _rank(C_ @ B_, rtol, scale=norm_C * (float(s[0]) if s.size else 0.0))
    zeros = _zeros(A_, B_, C_, rtol)
    matching = rank_CB == rank_B
    Y = E = K = None
    if not matching:
        mu_min, ok = math.inf, False
        reason = (
            f"rank(CB) = {rank_CB} < rank(B) = {rank_B}, so the matching condition fails: the unknown input "
            "can move the state without changing the next output, and the system is not strongly detectable."
        )
    else:
        Y = np.linalg.pinv(C_ @ B_tilde)
        E = A_ - B_tilde @ Y @ C_ @ A_
        mu_min, ok, reason = _zeros_verdict(zeros, rank_B)
        if ok:
            try:
                K = observer_gain(E, C_)
            except (np.linalg.LinAlgError, ValueError) as exc:
                reason = reason[:-1] + f", but the Riccati equation for the observer gain failed ({exc})."
    n, p = A_.shape[0], C_.shape[0]
    nan = float("nan")
    P, sigma_y, rate, margin, status = np.full((n, n), nan), nan, nan, nan, INFEASIBLE
    if ok:
        status, found, why = _quadratic_certificate(A_, B_tilde, C_, mu, mu_min)
        if found is not None:
            P, sigma_y, rate, margin = found
        reason += why
    return LinearStrongDetectability(
        certified=status == CERTIFIED,
        status=status,
        reason=reason,
        rate=rate,
        rate_min=mu_min,
        P_scaled=P,
        scale=np.ones(n),
        solve_time=time.perf_counter() - start,
        coverage="exact: a linear system has one Jacobian",
        cover_kind="exact",
        sound=True,
        margin=margin,
        matching=matching,
        rank_B=rank_B,
        rank_CB=rank_CB,
        rank_tol=float(rtol),
        invariant_zeros=zeros,
        strongly_detectable=ok,
        B_tilde=B_tilde,
        Y=Y,
        error_matrix=E,
        observer_gain=K,
        sigma_y=sigma_y,
        R_y=sigma_y * np.eye(p),
        R_v=sigma_y * np.eye(p),
        A=A_,
        C=C_,
    )


def _zeros_verdict(zeros: np.ndarray, rank_B: int) -> tuple[float, bool, str]:
    """With matching: ``(mu_min, strongly_detectable, reason)`` from the invariant zeros' largest modulus."""
    radius = float(np.max(np.abs(zeros), initial=0.0))
    mu_min, ok = radius**2, not off_unit_disk(radius)
    head = f"rank(CB) = rank(B) = {rank_B} (matching holds)"
    if not zeros.size:
        return (
            mu_min,
            ok,
            f"{head} and there are no invariant zeros, so the system is strongly detectable with mu_min = 0.",
        )
    if ok:
        return (
            mu_min,
            ok,
            (
                f"{head} and all {zeros.size} invariant zeros lie inside the unit disk (largest modulus "
                f"{radius:.6g}), so the system is strongly detectable with mu_min = {mu_min:.6g}."
            ),
        )
    where = (f"has modulus {radius:.6g} >= 1" if radius >= 1.0
             else f"lies on the unit circle (modulus 1 to within {UNIT_CIRCLE_TOL:g})")  # fmt: skip
    return (
        mu_min,
        ok,
        (
            f"{head} but the invariant zero {_fmt(zeros[0])} {where}, so the system is not strongly detectable "
            f"(mu_min = {mu_min:.6g})."
        ),
    )


def _quadratic_certificate(
    A: FloatArray, B_tilde: FloatArray, C: FloatArray, mu: float | None, mu_min: float
) -> tuple[CertificateStatus, tuple[FloatArray, float, float, float] | None, str]:
    """The LMI certificate of a strongly detectable system.

    Returns ``(status, (P, sigma_y, rate, margin) or None, note)``, the note to append to the reason when none
    was found.
    """
    if C.shape[0] == 0:
        return SOLVER_FAILED, None, " No output: the quadratic certificate needs at least one."
    solution = StrongLMI(A[None], B_tilde, C).solve(mu, mu_min=mu_min)
    status = STATUS_OF.get(solution.outcome, SOLVER_FAILED)
    if status == CERTIFIED:
        return status, (solution.P, solution.sigma_y, solution.mu, solution.margin), ""
    return status, None, f" The quadratic certificate was not found ({status}): {solution.reason}."


def _fmt(z: complex) -> str:
    return f"{z.real:.6g}" if z.imag == 0 else f"{z.real:.6g}{z.imag:+.6g}j"


def observer_gain(E: FloatArray, C: FloatArray) -> FloatArray:
    """``K = E P C^T (C P C^T + I)^-1`` with P from the DARE of the dual pair ``(E^T, C^T)``, Q = R = I."""
    n, p = E.shape[0], C.shape[0]
    if p == 0:
        return np.zeros((n, 0))
    P = scipy.linalg.solve_discrete_are(E.T, C.T, np.eye(n), np.eye(p))
    return E @ P @ C.T @ np.linalg.inv(C @ P @ C.T + np.eye(p))
