r"""An adversarial search for pairs that violate a certificate's incremental inequality.

Every certificate claims ``lhs(a, b, s) <= rhs(a, b, s)`` for all pairs of points ``a, b`` of a
box and shared inputs ``s`` (strong detectability: the states of two trajectories and the known
input, with the worst unknown-input increment in closed form; the dissipation certificates: state
and disturbance of each trajectory). Before a ``certify_*`` function returns a certificate,
:func:`search` tries to refute it:

1. sampled pairs: uniform pairs and close pairs ``b = a + step d`` with d along given directions
   (ker C for strong detectability: increments the output does not see) and steps of 1e-6 .. 1e-1
   of the box's width, half and half; then close pairs at the *anchors*, points where the
   Jacobian's entries reach their extremes (found by the cover's branch and bound), where narrow
   features live;
2. local maximisation of ``lhs / rhs`` (projected gradient ascent with CasADi's gradient, inside
   the boxes) from the worst pairs found.

A ratio above ``1 + REFUTE_RTOL`` refutes the certificate (:attr:`Falsification.refuted`); the
tolerance sits far above the rounding of the ratio for pairs at least :data:`MIN_SEPARATION` of the
box's scaled diameter apart, and closer pairs (which clipping at a side or a local maximisation can
make) are not scored. Where the domain is only part of the boxes (a reduced certificate's lift), pairs are drawn
until enough lie in it (``admit``).
Not finding a violation proves nothing; finding one disproves the certificate.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import casadi as ca
import numpy as np

from uiest.box import Box, FloatArray
from uiest.detectability.certificate import sample_admitted_pairs, sample_pairs

__all__ = ["MIN_SEPARATION", "Falsification", "pairs_text", "search"]

PAIRS = 20_000
"""Sampled pairs (half of them close), besides the anchored ones."""

ANCHORED = 64
"""Close pairs at each anchor."""

SEARCHES = 6
"""Local maximisations, started from the worst distinct pairs."""

ITERATIONS = 60
"""Most gradient steps per local maximisation."""

REFUTE_RTOL = 1e-6
"""A pair whose ratio exceeds ``1 + REFUTE_RTOL`` refutes the certificate."""

MIN_SEPARATION = 1e-7
"""Pairs closer than this fraction of the box's scaled diameter are not scored: their ratio measures the rounding
of the model's evaluation (two states one unit in the last place apart gave ratios of 4)."""


@dataclass(frozen=True, kw_only=True)
class Falsification:
    """What the adversarial search tried and the worst pair it found.

    Attributes
    ----------
    pairs : int
        Pairs drawn by sampling (uniform, close, anchored), those a domain's ``admit`` rejected included.
    scored : int
        Of those, the pairs whose ratio was scored: admitted, not NaN (where the model is undefined) and at least
        :data:`MIN_SEPARATION` apart.
    searches : int
        Local maximisations run.
    evaluations : int
        Evaluations of the ratio in the local maximisations.
    worst_ratio : float
        Largest ``lhs / rhs`` found (<= 1: no violation found; inf: an unbounded violation).
    first, second : ndarray, shape (n,)
        The worst pair's two points (original units).
    shared : ndarray, shape (ns,)
        The worst pair's shared inputs.
    labels : tuple of str
        Names of the entries of ``first`` (and ``second``) then ``shared``, for the text.
    seconds : float
        CPU time of the search (this thread).

    """

    pairs: int
    scored: int
    searches: int
    evaluations: int
    worst_ratio: float
    first: FloatArray
    second: FloatArray
    shared: FloatArray
    labels: tuple[str, ...]
    seconds: float

    @property
    def refuted(self) -> bool:
        """True when a pair violates the inequality by more than ``REFUTE_RTOL``."""
        return self.worst_ratio > 1.0 + REFUTE_RTOL

    def pair_text(self) -> str:
        """The worst pair, e.g. ``(x1, x2) = (1.3, 2) and (1.3, 1), u = (25)``."""
        n = len(self.first)
        names, shared_names = self.labels[:n], self.labels[n:]

        def values(v: FloatArray) -> str:
            return "(" + ", ".join(f"{x:.6g}" for x in v) + ")"

        text = f"({', '.join(names)}) = {values(self.first)} and {values(self.second)}"
        if len(self.shared):
            text += f", ({', '.join(shared_names)}) = {values(self.shared)}"
        return text

    def text(self) -> str:
        """One sentence: the search's size and its worst ratio (and pair when refuted)."""
        size = f"{pairs_text(self.scored, self.pairs)} and {self.searches} local searches"
        if self.refuted:
            return f"refuted: the pair {self.pair_text()} gives lhs / rhs = {self.worst_ratio:.4g} > 1 ({size})"
        if not self.scored:
            return f"not searched: {size}"
        return f"no violation found: worst lhs / rhs {self.worst_ratio:.4g} over {size}"

    def to_dict(self) -> dict[str, object]:
        """Plain data for JSON."""
        return {
            "pairs": self.pairs,
            "pairs_scored": self.scored,
            "local_searches": self.searches,
            "evaluations": self.evaluations,
            "worst_ratio": self.worst_ratio,
            "refuted": self.refuted,
            "worst_pair": {"first": self.first.tolist(), "second": self.second.tolist(),
                           "shared": self.shared.tolist()},
            "cpu_s": self.seconds,
        }  # fmt: skip


def pairs_text(scored: int, drawn: int) -> str:
    """``"20,000 pairs"``, or ``"2,929 pairs scored of 20,000 drawn"`` where some drawn pairs were not scored."""
    if scored == drawn:
        return f"{drawn:,} pair{'s' * (drawn != 1)}"
    return f"{'no' if not scored else f'{scored:,}'} pair{'s' * (scored != 1)} scored of {drawn:,} drawn"


def search(
    terms: ca.Function,
    domain: Box,
    shared: Box,
    scale: FloatArray,
    *,
    directions: FloatArray | None = None,
    anchors: FloatArray | None = None,
    labels: tuple[str, ...] | None = None,
    admit: Callable[[FloatArray, FloatArray, FloatArray], np.ndarray] | None = None,
    pairs: int = PAIRS,
    searches: int = SEARCHES,
    seed: int = 0,
) -> Falsification:
    """Look for pairs with ``lhs > rhs`` (see the module docstring).

    Parameters
    ----------
    terms : casadi.Function
        ``(a (n,), b (n,), s (ns,)) -> (lhs, rhs)``, scalars, an SX function.
    domain : Box
        Bounded box of a and b (n,).
    shared : Box
        Bounded box of s (ns,).
    scale : ndarray, shape (n,)
        Nominal magnitudes of a's entries (close pairs step in ``directions`` scaled by them).
    directions : ndarray, shape (n, k), optional
        Directions of close pairs in scaled coordinates (all when None).
    anchors : ndarray, shape (m, n), optional
        Points to take close pairs at (outside points are clipped into the domain).
    labels : tuple of str, optional
        Names of a's entries then s's, for the text.
    admit : callable, optional
        ``admit(a (m, n), b (m, n), s (m, ns))``: a boolean mask (m,) of the pairs in the domain, where it is only
        part of the boxes; pairs are drawn until ``pairs`` of them are admitted (or
        :data:`~uiest.detectability.certificate.ADMIT_DRAWS` times that many were drawn). ``terms`` must still
        return NaN outside the domain, where the local searches go.

    """
    start = time.thread_time()
    n, ns = domain.size, shared.size
    labels = labels or tuple(f"z[{i}]" for i in range(n)) + tuple(f"s[{i}]" for i in range(ns))
    rng = np.random.default_rng(seed)
    if admit is None:
        a, b = sample_pairs(rng, domain, pairs, scale, directions)
        s, drawn = np.zeros((0, ns)), pairs
    else:
        a, b, s, drawn = sample_admitted_pairs(rng, domain, shared, pairs, scale, admit, directions)
    if anchors is not None and len(anchors):
        base = np.repeat(domain.clip(np.asarray(anchors, dtype=float)), ANCHORED, axis=0)
        basis = np.eye(n) if directions is None else directions
        d = rng.standard_normal((len(base), basis.shape[1])) @ basis.T
        d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-300)
        width = np.where(domain.width > 0, domain.width, scale)
        step = 10.0 ** rng.uniform(-6.0, 0.0, (len(base), 1)) * float(np.linalg.norm(width / scale))
        a, b = np.vstack([a, base]), np.vstack([b, domain.clip(base + step * d * scale)])
        drawn += len(base)
    s = np.vstack([s, shared.sample(rng, len(a) - len(s))])
    if not len(a):  # a domain so thin that no drawn pair lies in it
        nothing = np.full(n, np.nan)
        return Falsification(pairs=drawn, scored=0, searches=0, evaluations=0, worst_ratio=-np.inf, first=nothing,
                             second=nothing.copy(), shared=np.full(ns, np.nan), labels=labels,
                             seconds=time.thread_time() - start)  # fmt: skip
    lhs, rhs = (np.asarray(v, dtype=float).ravel() for v in terms.map(len(a))(a.T, b.T, s.T))
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(rhs > 0.0, lhs / rhs, np.where(lhs > 0.0, np.inf, -np.inf))
    floor = MIN_SEPARATION * float(np.linalg.norm(np.where(domain.width > 0, domain.width, 0.0) / scale))
    scored = ~(np.isnan(lhs) | np.isnan(rhs) | np.isnan(ratio)) & (np.linalg.norm((a - b) / scale, axis=1) >= floor)
    ratio = np.where(scored, ratio, -np.inf)
    best = int(np.argmax(ratio))
    worst = (float(ratio[best]), a[best], b[best], s[best])
    evaluations = 0
    started = 0
    if np.isfinite(worst[0]):
        local = _local(terms, domain, shared, scale, floor)
        for i in _starts(ratio, a, b, searches):
            value, point, count = local(np.concatenate([a[i], b[i], s[i]]))
            evaluations += count
            started += 1
            if value > worst[0]:
                worst = (value, point[:n], point[n : 2 * n], point[2 * n :])
    return Falsification(
        pairs=drawn,
        scored=int(scored.sum()),
        searches=started,
        evaluations=evaluations,
        worst_ratio=worst[0],
        first=worst[1].copy(),
        second=worst[2].copy(),
        shared=worst[3].copy(),
        labels=labels,
        seconds=time.thread_time() - start,
    )


def _starts(ratio: FloatArray, a: FloatArray, b: FloatArray, count: int) -> list[int]:
    """Indices of the ``count`` worst pairs with finite ratios, one per distinct first point."""
    order = np.argsort(-ratio)
    chosen: list[int] = []
    for i in (int(i) for i in order[np.isfinite(ratio[order])]):
        if len(chosen) == count:
            break
        if all(not np.allclose(a[i], a[j]) or not np.allclose(b[i], b[j]) for j in chosen):
            chosen.append(i)
    return chosen


def _local(
    terms: ca.Function, domain: Box, shared: Box, scale: FloatArray, floor: float
) -> Callable[[FloatArray], tuple[float, FloatArray, int]]:
    """A maximiser of ``lhs / rhs`` from a start ``(a, b, s)``: returns (ratio, point, evaluations).

    Points whose pair is closer than ``floor`` (scaled by ``scale``) score -inf.

    Projected gradient ascent in the boxes (coordinates scaled to [0, 1]) with Barzilai-Borwein steps
    and an Armijo backtrack, CasADi's gradient; pure numpy on a few numbers per step (scipy's L-BFGS-B
    calls BLAS at every iteration, which costs milliseconds per step where BLAS threads compete).
    """
    n, ns = domain.size, shared.size
    v = ca.SX.sym("v", 2 * n + ns)
    lhs, rhs = terms(v[:n], v[n : 2 * n], v[2 * n :])
    ratio = lhs / rhs
    evaluate = ca.Function("ratio", [v], [ratio, ca.gradient(ratio, v), rhs])
    lower = np.concatenate([domain.lower, domain.lower, shared.lower])
    upper = np.concatenate([domain.upper, domain.upper, shared.upper])
    free = upper > lower
    width = np.where(free, upper - lower, 1.0)

    def run(start: FloatArray) -> tuple[float, FloatArray, int]:
        count = 0

        def point(t: FloatArray) -> FloatArray:
            full = start.copy()
            full[free] = lower[free] + t * width[free]
            return full

        def objective(t: FloatArray) -> tuple[float, FloatArray]:
            nonlocal count
            count += 1
            full = point(t)
            if np.linalg.norm((full[:n] - full[n : 2 * n]) / scale) < floor:
                return -np.inf, np.zeros_like(t)
            ratio_dm, grad, rhs_dm = evaluate(full)
            value, denominator = float(ratio_dm), float(rhs_dm)
            if not (np.isfinite(value) and denominator > 0.0):
                return -np.inf, np.zeros_like(t)
            g = np.asarray(grad, dtype=float).ravel()[free] * width[free]
            return value, np.where(np.isfinite(g), g, 0.0)

        t = np.clip((start[free] - lower[free]) / width[free], 0.0, 1.0)
        value, grad = objective(t)
        step = 0.1 / max(float(np.abs(grad).max(initial=0.0)), 1e-300)
        for _ in range(ITERATIONS):
            if not np.isfinite(value) or not grad.any():
                break
            for _ in range(30):  # Armijo backtrack on the projected step
                trial = np.clip(t + step * grad, 0.0, 1.0)
                moved = trial - t
                if not moved.any():
                    break
                new_value, new_grad = objective(trial)
                if new_value >= value + 1e-4 * float(grad @ moved):
                    break
                step *= 0.25
            else:
                break
            if not moved.any() or new_value < value + 1e-4 * float(grad @ moved):
                break
            change = new_grad - grad
            curvature = float(moved @ change)
            t, value, grad = trial, new_value, new_grad
            step = float(moved @ moved) / -curvature if curvature < 0.0 else 4.0 * step  # Barzilai-Borwein
        return value, point(t), count

    return run
