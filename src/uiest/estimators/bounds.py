r"""Worst-case error bounds of the estimators' theorems, per state in the state's units.

Every bound is for noise within V (around the estimator's noise prior ``v_bar``), written as
what holds for ``k >= settling``, starting from an initial error as large as X allows (each
state's error up to X's width). It is :data:`SETTLED` times the theorem's bound as
``k -> infinity``; ``settling`` is the first step from which the initial error's share has
decayed enough for that (:func:`quadratic_bound`, :func:`impulse_bound`).

**Quadratic storage** ``V = |s - s~|_P^2`` of a state ``s = T x`` (``T = I`` but for the
delayed UISE), read back through ``x = M s`` (rows of M). The theorems give
``V_k <= c lam^k V_0 + S`` and so ``|e_i| <= sqrt(V_k (M P^-1 M^T)_ii)`` (the largest ``e_i``
on the ellipsoid):

- Theorem 3.6 of Guo et al. (see the theory map) (UISE, P-norm prior, :mod:`uiest.estimators.uise`): ``rho = 8 mu^N``,
  ``lam = 8^{1/N} mu``, ``c = rho / mu^N = 8`` and, from the proof's last line with the current
  sample's term kept, ``S = sum_{i>=0} 8 lam^{i-1} sigma_v(2 |dv|) = 32 s_v / (lam (1 - lam))``;
- Lemma 3.3 with the comparison functions of :mod:`uiest.estimators.fie`: ``lam = mu``, ``c = 8``,
  ``S = 16 s_v / (mu (1 - mu))``;
- Schiller et al. 2023 (standard MHE, P1 = P2 = P): with ``(a + b)^2 <= 2 a^2 + 2 b^2`` and
  optimality, ``W_k <= 4 eta^N W_{k-N} + 4 sum_{j=1}^{N} eta^{j-1} d``, so ``lam = 4^{1/N} eta``,
  ``c = 4``, ``S = 4 d / (1 - lam)``; with the current output in the cost (the smooth-input MHE: node k
  weighted ``eta^-1 (2 |v - v_bar|_{Q_v}^2 + |h - y|_R^2)``), the estimate's extra term is >= 0 and the true
  trajectory's is at most ``2 s_q / eta``, so ``S = 4 d / (1 - lam) + 2 s_q / (eta (1 - lam^N))``,

with ``s_v = max_{v in V} |v - v_bar|_{R_v}^2``, ``s_q = max_{v in V} |v - v_bar|_{Q_v}^2`` and
``d = max |w - w_bar|_{Q_w}^2 + s_q``
(:func:`box_quadratic_max`).

**Linear forms** (the two-stage UISE's map to x, the linear UIO): ``|e_i| <= a_i lam^k E_0 + b_i``
or an impulse response summed over the worst noise sequence (:func:`impulse_bound`).
"""

from __future__ import annotations

import itertools
from collections import deque

import numpy as np

from uiest.box import Box, FloatArray

__all__ = [
    "SETTLED",
    "box_quadratic_max",
    "impulse_bound",
    "mhe_bound",
    "noise_quadratic",
    "reduction_bound",
    "strong_bound",
    "two_stage_rate",
    "two_stage_z_bound",
]

SETTLED = 1.1
"""A guarantee's bound is this times its theorem's bound as k -> infinity; it holds once the initial error's share
has decayed below the difference."""

VERTEX_LIMIT = 12
"""Boxes of at most this dimension are maximised over by their 2^n vertices; larger ones by the triangle inequality."""

MAX_SETTLING = 1_000_000
"""Steps :func:`impulse_bound` sums at most (then the bound is reported as infinite)."""


def box_quadratic_max(W: FloatArray, lower: FloatArray, upper: FloatArray) -> float:
    """``max e^T W e`` over ``lower <= e <= upper`` (W symmetric PSD; the maximum of a convex function is at a vertex).

    Exact over the vertices up to :data:`VERTEX_LIMIT` dimensions, else the upper bound
    ``(sum_i r_i sqrt(W_ii))^2`` with ``r_i = max(|lower_i|, |upper_i|)``. inf when a side the
    quadratic grows along is infinite.
    """
    W = np.asarray(W, dtype=float)
    n = W.shape[0]
    if n == 0:
        return 0.0
    lower, upper = np.asarray(lower, dtype=float), np.asarray(upper, dtype=float)
    infinite = ~(np.isfinite(lower) & np.isfinite(upper))
    if np.any(infinite & (np.diag(W) > 0)):
        return float("inf")
    lower, upper = np.where(infinite, 0.0, lower), np.where(infinite, 0.0, upper)  # a zero diagonal: a zero row
    if n <= VERTEX_LIMIT:
        corners = np.array(list(itertools.product(*zip(lower, upper, strict=True))))
        return float(np.max(np.einsum("mi,ij,mj->m", corners, W, corners)))
    radius = np.maximum(np.abs(lower), np.abs(upper))
    return float(np.sum(radius * np.sqrt(np.maximum(np.diag(W), 0.0))) ** 2)


def noise_quadratic(R: FloatArray, box: Box | None, center: FloatArray) -> float:
    """``max_{v in box} |v - center|_R^2`` (inf without a box: the range is unknown)."""
    if box is None:
        return float("inf") if np.any(np.asarray(R) != 0) else 0.0
    return box_quadratic_max(R, box.lower - center, box.upper - center)


def inverse_spd(P: FloatArray) -> FloatArray:
    """``P^-1`` of a symmetric positive definite matrix, by its diagonal scaling (P may mix magnitudes)."""
    d = 1.0 / np.sqrt(np.diag(P))
    return d[:, None] * np.linalg.inv(d[:, None] * P * d[None, :]) * d[None, :]


def quadratic_bound(
    P: FloatArray, M: FloatArray, settled: float, initial: float, gain: float, rate: float
) -> tuple[FloatArray, int | None]:
    """Per row of ``M``: :data:`SETTLED` ``* sqrt(settled (M P^-1 M^T)_ii)``, and from which step it holds.

    ``V_k <= gain rate^k initial + settled`` (V the P-norm squared of the storage state s,
    ``x = M s``). The bound holds from the first k with ``gain rate^k initial <= (SETTLED^2 - 1)
    settled``; None when settled is 0 or not finite, or initial is not finite. inf per row
    when ``rate >= 1`` or ``settled`` is inf.
    """
    spread = np.einsum("ij,jk,ik->i", M, inverse_spd(P), M)
    if not rate < 1.0 or not np.isfinite(settled):
        return np.where(spread > 0, np.inf, 0.0), None
    bound = SETTLED * np.sqrt(settled * spread)
    return bound, _steps(gain * initial, (SETTLED**2 - 1.0) * settled, rate)


def linear_bound(
    transient: FloatArray, settled: FloatArray, initial: float, rate: float
) -> tuple[FloatArray, int | None]:
    """``|e_i| <= transient_i rate^k initial + settled_i``: :data:`SETTLED` ``* settled``, and from which step."""
    bound = SETTLED * settled
    finite = np.isfinite(settled)
    if not finite.any():
        return bound, None
    start = [0.0 if t == 0 else t * initial for t in transient[finite]]
    need = [_steps(a, (SETTLED - 1.0) * s, rate) for a, s in zip(start, settled[finite], strict=True)]
    return bound, None if any(n is None for n in need) else max(n for n in need if n is not None)


def _steps(start: float, target: float, rate: float) -> int | None:
    """The smallest k >= 0 with ``start rate^k <= target`` (None when it never happens)."""
    if start <= target:
        return 0
    if not (np.isfinite(start) and target > 0.0 and 0.0 < rate < 1.0):
        return None
    return max(0, int(np.ceil(np.log(start / target) / np.log(1.0 / rate) - 1e-12)))


def strong_bound(
    P: FloatArray,
    R_v: FloatArray,
    mu: float,
    N: int | None,
    v_box: Box,
    v_bar: FloatArray,
    x_width: FloatArray,
    T: FloatArray | None = None,
    M: FloatArray | None = None,
) -> tuple[FloatArray, int | None]:
    """Theorem 3.6's bound with horizon N (None: Lemma 3.3's), per row of M (module docstring).

    ``P`` and ``R_v`` are the certificate's (original units) of the storage state ``s = T x``
    (default ``T = M = I``); the initial error is any ``T e0`` with ``|e0_i| <= x_width_i``.
    """
    n = P.shape[0]
    T = np.eye(n) if T is None else T
    M = np.eye(n) if M is None else M
    s_v = noise_quadratic(R_v, v_box, v_bar)
    if N is None:
        rate, settled = mu, 16.0 * s_v / (mu * (1.0 - mu))
    else:
        rate = 8.0 ** (1.0 / N) * mu
        settled = 32.0 * s_v / (rate * (1.0 - rate)) if rate < 1.0 else float("inf")
    initial = box_quadratic_max(T.T @ P @ T, -x_width, x_width)
    return quadratic_bound(P, M, settled, initial, 8.0, rate)


def mhe_bound(
    P: FloatArray,
    Q_w: FloatArray,
    Q_v: FloatArray,
    eta: float,
    N: int,
    w_box: Box | None,
    w_bar: FloatArray,
    v_box: Box,
    v_bar: FloatArray,
    x_width: FloatArray,
    *,
    current: bool = False,
) -> tuple[FloatArray, int | None]:
    """Schiller et al. 2023's bound (module docstring); ``w_box`` None: w's range is unknown.

    ``current``: the window also measures node k (weighted ``eta^-1``), as the smooth-input MHE's does.
    """
    s_q = noise_quadratic(Q_v, v_box, v_bar)
    d = noise_quadratic(Q_w, w_box, w_bar) + s_q
    rate = 4.0 ** (1.0 / N) * eta
    settled = 4.0 * d / (1.0 - rate) if rate < 1.0 else float("inf")
    if current and rate < 1.0:
        settled += 2.0 * s_q / (eta * (1.0 - rate**N))
    return quadratic_bound(P, np.eye(P.shape[0]), settled, box_quadratic_max(P, -x_width, x_width), 4.0, rate)


def two_stage_rate(mu: float, c_x: float, N: int) -> float:
    """Theorem 4.8's contraction ``lambda = max(sqrt(mu) (2 sqrt(c_x))^{1/N}, sqrt(mu))`` (Eq. (33))."""
    eta = float(np.sqrt(mu))
    return max(eta * (2.0 * float(np.sqrt(c_x))) ** (1.0 / N), eta)


def two_stage_z_bound(mu: float, c_x: float, N: int, noise: float) -> float:
    """Theorem 4.8's settled error of ``z_sharp`` in the certificate's scaled norm (Eq. (33)).

    ``2 sqrt(noise) lambda / (1 - lambda)`` with ``noise = max_{v in V} |v - v_bar|_{R_v}^2``
    (``c_v`` times the scaled noise's square); inf when ``lambda >= 1``.
    """
    rate = two_stage_rate(mu, c_x, N)
    return 2.0 * float(np.sqrt(noise)) * rate / (1.0 - rate) if rate < 1.0 else float("inf")


def reduction_bound(
    J_z: FloatArray,
    J_v: FloatArray,
    z_scale: FloatArray,
    z_width: FloatArray,
    v_box: Box,
    v_bar: FloatArray,
    c_x: float,
    rate: float,
    z_settled: float,
) -> tuple[FloatArray, int | None]:
    """Theorem 4.8 through ``x = T^-1(psi(y, z_sharp, v), z_sharp)`` with Jacobians ``J_z``, ``J_v`` (rows NaN: none).

    ``|e_i| <= |J_z,i diag(z_scale)| |dz|_scaled + max_{v in V} |J_v,i (v_bar - v)|``, with
    ``|dz|_scaled <= 2 sqrt(c_x) rate^k |z_width / z_scale| + z_settled`` (the prior and the true
    z_sharp both lie in z_bounds).
    """
    gain = np.sqrt(np.sum((J_z * z_scale[None, :]) ** 2, axis=1))
    low, high = J_v * (v_bar - v_box.upper)[None, :], J_v * (v_bar - v_box.lower)[None, :]
    with np.errstate(invalid="ignore"):
        noise = np.maximum(np.maximum(low, high).sum(axis=1), -np.minimum(low, high).sum(axis=1))
        settled = gain * z_settled + noise
    initial = 2.0 * float(np.sqrt(c_x)) * float(np.linalg.norm(z_width / z_scale)) if len(z_width) else 0.0
    return linear_bound(gain, settled, initial, rate)


def impulse_bound(
    F: FloatArray, first: FloatArray, step: FloatArray, transient: FloatArray, lower: FloatArray, upper: FloatArray
) -> tuple[FloatArray, int | None]:
    r"""Worst case over k of ``e_k = (F^k transient) + sum_{m>=0} G_m d_{k-m}`` with every ``d`` in ``[lower, upper]``.

    ``G_0 = first``, ``G_m = F^{m-1} step`` (m >= 1). The noise part of row i is at most
    ``max(sum_m sum_l max(G_m lower, G_m upper)_il, -sum_m sum_l min(...)_il)`` (each d chosen
    per term), summed until the remainder is below 1e-13 of the largest sum: with a power
    ``|F^p|_inf = q <= 1/2``, each later block of p terms is at most q times the one before, so
    the remainder is at most ``q / (1 - q)`` times the last block's largest entry, and it is added
    to every row (the result stays an upper bound). The initial part of row i is at most
    ``sum_l |(F^k transient)_il|`` (``transient``: the initial error's box as columns).

    Returns :data:`SETTLED` times the noise part per row, and the first step from which the
    initial part stays below ``SETTLED - 1`` times it (:func:`_impulse_settling`).
    """
    n = F.shape[0]
    if not (np.all(np.isfinite(lower)) and np.all(np.isfinite(upper))):
        reached = np.any(first != 0, axis=1) | np.any(step != 0, axis=1)
        return np.where(reached, np.inf, 0.0), None
    radius = np.maximum(np.abs(lower), np.abs(upper))

    def worst(G: FloatArray) -> tuple[FloatArray, FloatArray]:
        a, b = G * lower[None, :], G * upper[None, :]
        return np.maximum(a, b).sum(axis=1), -np.minimum(a, b).sum(axis=1)

    high, low = worst(first)
    power = np.eye(n)  # F^(m-1)
    recent: deque[FloatArray] = deque()
    period, q = 0, 1.0
    for m in range(1, MAX_SETTLING + 1):
        G = power @ step
        up, down = worst(G)
        high, low = high + up, low + down
        recent.append(np.abs(G) @ radius)
        power = F @ power
        if not period:
            norm = float(np.max(np.abs(power).sum(axis=1), initial=0.0))
            if norm <= 0.5:
                period, q = m, norm
        if period:
            while len(recent) > period:
                recent.popleft()
            tail = q / (1.0 - q) * float(np.max(np.sum(recent, axis=0), initial=0.0))
            if tail <= 1e-13 * float(np.max(np.maximum(high, low), initial=0.0)):
                limit = np.maximum(high, low) + tail
                return SETTLED * limit, _impulse_settling(F, transient, (SETTLED - 1.0) * limit)
    return np.full(n, np.inf), None


def _impulse_settling(F: FloatArray, transient: FloatArray, target: FloatArray) -> int | None:
    """The first k with ``rowsum |F^j transient| <= target`` for every j >= k (None if none within the limit).

    With a power ``|F^p| target <= target`` (elementwise), p consecutive steps below the target
    keep every later one below it.
    """
    if not np.all(np.isfinite(transient)) or np.any(target <= 0.0) or not np.all(np.isfinite(target)):
        return None
    period, power = 1, F.copy()
    while not np.all(np.abs(power) @ target <= target):
        power, period = F @ power, period + 1
        if period > MAX_SETTLING:
            return None
    current, start, run = transient.copy(), 0, 0
    for k in range(MAX_SETTLING):
        if np.all(np.abs(current).sum(axis=1) <= target):
            run += 1
            if run == period:
                return start
        else:
            start, run = k + 1, 0
        current = F @ current
    return None
