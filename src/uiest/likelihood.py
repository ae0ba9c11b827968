r"""The prediction-error method: a variance chosen by the likelihood of a filter's innovations.

A Kalman filter run over a record ``y[0..K]`` predicts each measurement before it sees it: the
innovation ``e[k] = y[k] - y_pred[k]`` (observed channels only) with covariance ``S[k]`` from the
filter's own model. Under that model the innovations are independent Gaussians, so the record's
log-likelihood is::

    L(q) = sum_k -1/2 (log det(2 pi S[k]) + e[k]' S[k]^-1 e[k])

for the filter with variance ``q``. :func:`maximise_likelihood` evaluates ``L`` on a log grid of
``q`` (a factor times a scale^2), refines the best interior point by golden-section search in
``log q``, and returns the whole :class:`LikelihoodProfile`: it needs the measurements only, no
true states. The profile says how well the record determines ``q``: the 95 % likelihood-ratio
interval (``L >= max L - LIKELIHOOD_INTERVAL``) and its :class:`ProfileShape` (interior, at an end
of the grid, or flat over the whole grid).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from enum import StrEnum

import numpy as np
from numpy.typing import NDArray

from uiest.box import FloatArray
from uiest.checks import shown
from uiest.errors import OptionError

LIKELIHOOD_INTERVAL = 1.92
"""Half the 95 % quantile of chi^2 with one degree of freedom (3.84 / 2): variances whose log-likelihood is within this
of the maximum are not rejected by a likelihood-ratio test at 5 % (Wilks), so the record does not tell them apart."""
REFINE_STEPS = 8
"""Golden-section evaluations between the best grid point's neighbours (a bracket of 0.618^7 = 3 % of it)."""
DEFAULT_GRID = np.logspace(-8, 2, 21)
"""Variance factors tried by default (times the signal's scale^2): a random walk from nearly constant to 10 scales per
step."""
GRID_EXTENSION = 12
"""Points the default grid grows by, at its own spacing, beyond an end where the likelihood is largest (six decades
of half-decade steps): a signal whose scale was not given (w's scale 1 where w is a flow of 1e-5 m^3/s, say) puts
the maximum outside the grid, and a variance at the grid's end would be far from the one the record supports."""
GOLDEN = (np.sqrt(5.0) - 1.0) / 2.0


def innovation_log_density(innovation: FloatArray, S: FloatArray) -> float:
    """``-1/2 (log det(2 pi S) + e' S^-1 e)`` of an innovation ``e (m,)`` with covariance ``S (m, m)``.

    NaN if S is not positive definite.
    """
    try:
        L = np.linalg.cholesky(0.5 * (S + S.T))
    except np.linalg.LinAlgError:
        return float("nan")
    whitened = np.linalg.solve(L, innovation)
    m = innovation.size
    return float(-np.sum(np.log(np.diag(L))) - 0.5 * (whitened @ whitened) - 0.5 * m * np.log(2.0 * np.pi))


class ProfileShape(StrEnum):
    """Where the likelihood interval (``L >= max L - LIKELIHOOD_INTERVAL``) lies on the grid.

    - ``INTERIOR``: strictly inside the grid; the record determines the variance from both sides.
    - ``LOWER_END``: it reaches the grid's smallest variance (and not its largest): the record bounds the variance
      from above only (an input as constant as the grid allows fits as well).
    - ``UPPER_END``: it reaches the grid's largest variance only: a larger variance may fit better.
    - ``FLAT``: it covers the whole grid: the record does not determine the variance.
    """

    INTERIOR = "interior"
    LOWER_END = "at the grid's lower end"
    UPPER_END = "at the grid's upper end"
    FLAT = "flat"


@dataclass(frozen=True, kw_only=True)
class Score:
    """One filter run's log-likelihood, the steps it could not score and the steps at which it diverged."""

    log_likelihood: float
    unscored: int = 0
    diverged: int = 0

    @property
    def admissible(self) -> bool:
        """Every measured step scored, no divergence, a finite value: comparable with the other runs."""
        return bool(np.isfinite(self.log_likelihood)) and not self.unscored and not self.diverged


@dataclass(frozen=True, kw_only=True)
class LikelihoodProfile:
    """The log-likelihood of a record against a variance: what :func:`maximise_likelihood` evaluated.

    Attributes
    ----------
    name : str
        The variance's name (``"w_variance"``).
    unit : str
        What a factor multiplies (``"w.scale^2"``).
    factors : ndarray (n,)
        Variances tried, in units of ``scale^2``, increasing (the grid and the refinement's points).
    log_likelihood : ndarray (n,)
        ``L`` of each (module docstring); ``-inf`` where the filter diverged, an update failed or the value was not
        finite (such a run scored fewer innovations and is not comparable).
    unscored : ndarray (n,) of int
        Measured steps each run could not score (failed updates) plus its diverged steps.
    scale : ndarray (m,)
        The signal's scale: the variance is ``factor * scale^2`` per component.
    grid : ndarray (g,)
        The grid's factors (its ends are the profile's ends), with the points it was extended by.
    extended : int
        Points added beyond the given grid's ends, where the likelihood was largest at an end
        (:func:`maximise_likelihood`'s ``extend``).

    """

    name: str
    unit: str
    factors: FloatArray
    log_likelihood: FloatArray
    unscored: NDArray[np.int_]
    scale: FloatArray
    grid: FloatArray
    extended: int = 0

    @property
    def best(self) -> int:
        """Index of the largest log-likelihood."""
        return int(np.argmax(self.log_likelihood))

    @property
    def chosen(self) -> float:
        """The factor with the largest log-likelihood (variance ``chosen * scale^2``)."""
        return float(self.factors[self.best])

    @property
    def variance(self) -> FloatArray:
        """The chosen variance per component, ``chosen * scale^2`` (m,)."""
        return self.chosen * self.scale**2

    @property
    def maximum(self) -> float:
        """The largest log-likelihood."""
        return float(self.log_likelihood[self.best])

    @property
    def spread(self) -> float:
        """How much the log-likelihood varies over the admissible points (max - min)."""
        finite = self.log_likelihood[np.isfinite(self.log_likelihood)]
        return float(finite.max() - finite.min())

    @property
    def interval(self) -> tuple[float, float]:
        """The factors where ``L >= max L - LIKELIHOOD_INTERVAL``, interpolated linearly in ``log q``.

        A side of the interval that reaches an end of the profile is that end.
        """
        threshold = self.maximum - LIKELIHOOD_INTERVAL
        inside = self.log_likelihood >= threshold
        i = j = self.best
        while i > 0 and inside[i - 1]:
            i -= 1
        while j < len(inside) - 1 and inside[j + 1]:
            j += 1
        return self._crossing(i, i - 1, threshold), self._crossing(j, j + 1, threshold)

    def _crossing(self, inner: int, outer: int, threshold: float) -> float:
        """Where L crosses ``threshold`` between the points ``inner`` (above) and ``outer`` (below; none: ``inner``)."""
        if outer < 0 or outer >= len(self.factors):
            return float(self.factors[inner])
        a, b = self.log_likelihood[inner], self.log_likelihood[outer]
        t = 1.0 if not np.isfinite(b) else (a - threshold) / (a - b)
        log_q = (1.0 - t) * np.log(self.factors[inner]) + t * np.log(self.factors[outer])
        return float(np.exp(log_q))

    @property
    def at_end(self) -> bool:
        """The largest value is the grid's first or last point: the maximum may lie beyond the grid."""
        return self.best in (0, len(self.factors) - 1) and self.shape is not ProfileShape.FLAT

    @property
    def shape(self) -> ProfileShape:
        """Where the likelihood interval lies on the grid (:class:`ProfileShape`)."""
        inside = self.log_likelihood >= self.maximum - LIKELIHOOD_INTERVAL
        low, high = bool(inside[0]), bool(inside[-1])
        if low and high:
            return ProfileShape.FLAT
        if low:
            return ProfileShape.LOWER_END
        if high:
            return ProfileShape.UPPER_END
        return ProfileShape.INTERIOR

    def summary(self) -> str:
        """One line: the chosen variance, the profile's shape and the interval the record supports."""
        lo, hi = self.interval
        shape = self.shape
        text = f"{self.name} {self.chosen:.3g} {self.unit}, the likelihood's maximum ({shape.value}"
        if shape is ProfileShape.FLAT:
            return (
                text + f": the log-likelihood varies by {self.spread:.2g} over {self.grid[0]:.3g} .. "
                f"{self.grid[-1]:.3g}, within {LIKELIHOOD_INTERVAL} of its maximum everywhere; the record does not "
                "determine it)"
            )
        grown = f" ({self.extended} points beyond the given grid)" if self.extended else ""
        if self.at_end:
            side = "smaller" if self.best == 0 else "larger"
            return text + f"{grown}: its largest value; a {side} one may fit better)"
        if shape is ProfileShape.LOWER_END:
            return text + f": any value up to {hi:.3g} fits as well, down to the grid's {self.grid[0]:.3g}{grown})"
        if shape is ProfileShape.UPPER_END:
            return text + f": any value from {lo:.3g} fits as well, up to the grid's {self.grid[-1]:.3g}{grown})"
        return text + f"; 95 % interval {lo:.3g} .. {hi:.3g}{grown})"

    def to_dict(self) -> dict[str, object]:
        """Plain data: the profile's points, the choice, the interval and the shape."""
        lo, hi = self.interval
        return {
            "name": self.name,
            "unit": self.unit,
            "factors": self.factors.tolist(),
            "log_likelihood": [float(v) if np.isfinite(v) else None for v in self.log_likelihood],
            "unscored": self.unscored.tolist(),
            "chosen": self.chosen,
            "interval": [lo, hi],
            "shape": self.shape.value,
            "at_end": self.at_end,
            "extended": self.extended,
        }


MAX_GRID = 1000
"""Most values a grid may hold: 1000 over the default grid's ten decades are 2.3 % apart, closer than the 3 %
bracket the golden-section refinement leaves around the best one, so a longer grid adds filter runs, not
information (each value is one filter run over the whole record)."""


def check_grid(variances: object | None, name: str = "variances") -> FloatArray:
    """The grid of factors: :data:`DEFAULT_GRID` for None, else positive finite numbers (sorted, unique).

    At most :data:`MAX_GRID` of them.

    ``name``: the argument's name in the OptionError.
    """
    if variances is None:
        return DEFAULT_GRID.copy()
    try:
        grid = np.asarray(variances, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise OptionError(f"{name}: expected positive numbers, got {variances!r}") from None
    if not grid.size or not np.all(np.isfinite(grid) & (grid > 0)):
        raise OptionError(f"{name}: expected positive numbers, got {shown(grid)}")
    if grid.size > MAX_GRID:
        raise OptionError(
            f"{name}: expected at most {MAX_GRID} values (one filter run each; the refinement resolves 3 % around "
            f"the best), got {grid.size:_}"
        )
    return np.unique(grid)


def maximise_likelihood(
    score: Callable[[float], Score],
    grid: FloatArray,
    *,
    name: str,
    unit: str,
    scale: FloatArray,
    refine: int = REFINE_STEPS,
    extend: int = 0,
) -> LikelihoodProfile:
    """Evaluate ``score`` on ``grid`` (factors, increasing) and refine the best interior point; the profile.

    Where the best value is at an end of the grid, the grid grows beyond that end at the spacing of its end points
    (half a decade for one point), one point at a time, until the best is interior or ``extend`` points were added.
    The refinement is a golden-section search in ``log q`` between the best grid point's neighbours, ``refine``
    evaluations (none when the best is an end of the grid, or ``refine = 0``). Raises OptionError when no run is
    admissible (:attr:`Score.admissible`).
    """
    points: dict[float, Score] = {}

    def value(q: float) -> float:
        points[q] = s = score(q)
        return s.log_likelihood if s.admissible else -np.inf

    def at(log_q: float) -> float:
        return value(float(np.exp(log_q)))

    values = np.array([value(float(q)) for q in grid])
    if not np.any(np.isfinite(values)):
        raise OptionError(
            f"{name}: every filter of the grid {grid[0]:.3g} .. {grid[-1]:.3g} diverged or failed an update on the "
            "record; give a smaller P0 (the default is X's uniform variance) or a prior closer to the data "
            "(x0_prior; --x0 in `uiest estimate`)"
        )
    grid, values, extended = _extended(value, np.asarray(grid, dtype=float), values, extend)
    best = int(np.argmax(values))
    if refine > 0 and 0 < best < len(grid) - 1:
        a, b = float(np.log(grid[best - 1])), float(np.log(grid[best + 1]))
        c, d = b - GOLDEN * (b - a), a + GOLDEN * (b - a)
        fc, fd = at(c), at(d)
        for _ in range(refine - 2):
            if fc >= fd:
                b, d, fd = d, c, fc
                c = b - GOLDEN * (b - a)
                fc = at(c)
            else:
                a, c, fc = c, d, fd
                d = a + GOLDEN * (b - a)
                fd = at(d)
    factors = np.array(sorted(points))
    scores = [points[q] for q in factors]
    return LikelihoodProfile(
        name=name,
        unit=unit,
        factors=factors,
        log_likelihood=np.array([s.log_likelihood if s.admissible else -np.inf for s in scores]),
        unscored=np.array([s.unscored + s.diverged for s in scores], dtype=int),
        scale=np.asarray(scale, dtype=float),
        grid=grid,
        extended=extended,
    )


def _extended(value: Callable[[float], float], grid: FloatArray, values: FloatArray,
              extend: int) -> tuple[FloatArray, FloatArray, int]:  # fmt: skip
    """``grid`` and its ``values`` grown beyond the end holding the best value (:func:`maximise_likelihood`)."""
    added = 0
    while added < extend:
        best = int(np.argmax(values))
        finite = values[np.isfinite(values)]
        if 0 < best < len(grid) - 1 or finite.max() - finite.min() <= LIKELIHOOD_INTERVAL:  # interior, or flat
            break
        step = grid[1] / grid[0] if len(grid) > 1 else np.sqrt(10.0)
        if best == 0:
            q = float(grid[0] / step)
            grid, values = np.concatenate([[q], grid]), np.concatenate([[value(q)], values])
        else:
            q = float(grid[-1] * (grid[-1] / grid[-2] if len(grid) > 1 else step))
            grid, values = np.concatenate([grid, [q]]), np.concatenate([values, [value(q)]])
        added += 1
    return grid, values, added


__all__ = [
    "DEFAULT_GRID",
    "GRID_EXTENSION",
    "LIKELIHOOD_INTERVAL",
    "LikelihoodProfile",
    "ProfileShape",
    "Score",
    "check_grid",
    "innovation_log_density",
    "maximise_likelihood",
]
