"""Step health as data: what happened at a step (:class:`Outcome`), which states lie at X's sides, the display text.

Every estimator's :class:`~uiest.results.StepEstimate` carries an :class:`Outcome` and typed fields
(the solver's status, whether its fallback solver was used, the states at X's sides, the held
input, ...); :func:`status_text` derives the one-line status shown to a user from them, and no
code reads that text back. :func:`at_bound` is the one test of "on a side of a box";
:func:`bound_message` is the warning of a run whose estimates sit at X's sides in many steps.
"""

from __future__ import annotations

import functools
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from enum import StrEnum
from typing import ParamSpec, TypeVar

import numba
import numpy as np
from numpy.typing import NDArray

from uiest.box import Box, FloatArray
from uiest.errors import BoundWarning, DataError, FailureWarning

Params = ParamSpec("Params")
Result = TypeVar("Result")


class Outcome(StrEnum):
    """What happened at one step of an estimator (the value is the name shown in tables and files).

    Window estimators (UISE, FIE, standard MHE, two-stage and delayed UISE):

    - ``SOLVED``: the window problem was solved; the solver reported success (``solver_status``
      says which status, and ``fallback`` whether the Gauss-Newton backend handed the window to
      IPOPT). With the ``rti`` backend one Gauss-Newton step counts as success (``"RTI_Step"``).
    - ``FAILED``: the window problem was not solved, also from a cold start; the model propagated
      the last estimate (``solver_status`` is the last attempt's status).
    - ``ERROR``: the step raised an exception (``reason`` holds it); the model propagated the last
      estimate and the run went on.
    - ``PROPAGATED``: no measurement in the whole window (an outage longer than the window): the
      model propagated the last estimate. Not a failure: there was nothing to estimate from.
    - ``PRIOR``: no measured node yet (the one-step-ahead standard MHE at k = 0): the prior.
    - ``ALGEBRAIC``: nothing to optimise (the two-stage UISE with ``n_sharp = 0``): the estimate
      follows from ``y[k]`` alone.

    Filters and observers (EKF, UKF, linear UIO):

    - ``UPDATED``: the prediction was updated with ``y[k]`` (a filter with missing channels
      drops them; a step without any measurement is ``PROPAGATED``, the prediction).
    - ``UPDATE_SKIPPED``: the update failed (``reason`` says why); the prediction is the estimate.
    - ``KEPT``: the prediction was not finite, even with the model evaluated inside X; the last
      estimate is kept.
    - ``DIVERGED``: the estimate lies outside X by more than X's width.

    ``FAILED``, ``ERROR``, ``UPDATE_SKIPPED``, ``KEPT`` and ``DIVERGED`` are failures
    (:attr:`failed`); the others are not.
    """

    SOLVED = "solved"
    FAILED = "failed"
    ERROR = "error"
    PROPAGATED = "propagated"
    PRIOR = "prior"
    ALGEBRAIC = "algebraic"
    UPDATED = "updated"
    UPDATE_SKIPPED = "update skipped"
    KEPT = "kept"
    DIVERGED = "diverged"

    @property
    def failed(self) -> bool:
        """Whether the step failed (its estimate did not come from the step's own update or solve)."""
        return self in FAILURES


FAILURES = frozenset({Outcome.FAILED, Outcome.ERROR, Outcome.UPDATE_SKIPPED, Outcome.KEPT, Outcome.DIVERGED})
"""The outcomes counted as failed steps."""

AT_BOUND_RTOL = 1e-5
"""A state lies at a side of a box when it is within this fraction of the box's width (its scale where the width
is infinite) of that side, or beyond it: wider than an interior-point solver's distance to an active side, narrower
than an estimate's distance to a side that does not hold it (design notes: step health)."""

BOUND_SHARE = 0.05
"""A run warns (:func:`bound_message`) when some state's estimate lies at a side of X in more than this share of
its steps."""

FAILURE_SHARE = 0.05
"""A run warns (:func:`failure_message`, :class:`~uiest.errors.FailureWarning`) when more than this share of its
steps failed."""


def at_bound(box: Box, x: FloatArray, scale: FloatArray) -> NDArray[np.bool_]:
    """Which entries of ``x (..., n)`` lie on or beyond a finite side of ``box`` (:data:`AT_BOUND_RTOL`).

    ``scale (n,)`` replaces the width of a side-infinite axis. Axes of zero width (a fixed
    state) are never at a side. :class:`BoundTest` is the same test with its thresholds computed once.
    """
    return BoundTest(box, scale)(x)


class BoundTest:
    """:func:`at_bound` for one box and scale, its thresholds computed once (a test repeated every step).

    Parameters
    ----------
    box : Box
        The box, dimension n.
    scale : ndarray (n,)
        Replaces the width of a side-infinite axis.

    """

    def __init__(self, box: Box, scale: FloatArray) -> None:
        width = np.where(np.isfinite(box.width), box.width, scale)
        tol = AT_BOUND_RTOL * width
        wide = box.width > 0
        self._low, self._high = box.lower + tol, box.upper - tol
        self._has_low, self._has_high = np.isfinite(box.lower) & wide, np.isfinite(box.upper) & wide

    def __call__(self, x: FloatArray) -> NDArray[np.bool_]:
        """Which entries of ``x (..., n)`` lie on or beyond a finite side of the box."""
        arr = np.asarray(x, dtype=float)
        result: NDArray[np.bool_] = (self._has_low & (arr <= self._low)) | (self._has_high & (arr >= self._high))
        return result

    def any(self, x: FloatArray) -> bool:
        """Whether some row of ``x (m, n)`` has an entry on or beyond a finite side (one compiled pass)."""
        arr = np.asarray(x, dtype=float)
        if arr.shape[-1:] != self._low.shape:
            raise DataError(f"x: expected rows of {self._low.size} entries, got shape {arr.shape}")
        if not self._low.size:
            return False
        return bool(_any_at_bound(arr.reshape(-1, self._low.size), self._low, self._high, self._has_low,
                                  self._has_high))  # fmt: skip


@numba.njit(cache=True)
def _any_at_bound(x, low, high, has_low, has_high):  # pragma: no cover (compiled)
    """:meth:`BoundTest.any` for ``x (m, n)``."""
    for i in range(x.shape[0]):
        for j in range(x.shape[1]):
            if (has_low[j] and x[i, j] <= low[j]) or (has_high[j] and x[i, j] >= high[j]):
                return True
    return False


def status_text(
    outcome: Outcome | str,
    *,
    solver_status: str = "",
    primary_status: str = "",
    reason: str = "",
    held_input: bool = False,
    at_bound_names: tuple[str, ...] = (),
    on_boundary: bool = False,
    evaluated_inside: bool = False,
) -> str:
    """The one-line status of a step, for display (derived from its fields; never parsed).

    ``"solved (Converged)"``, ``"solved (gn QP_failed -> ipopt Solve_Succeeded)"``,
    ``"failed (Maximum_Iterations_Exceeded)"``, ``"propagated (no data)"``, ``"updated"``, ...
    then what else the fields say, after semicolons.
    """
    outcome = Outcome(outcome)
    solver = f"{primary_status} -> ipopt {solver_status}" if primary_status else solver_status
    detail = {
        Outcome.SOLVED: solver,
        Outcome.FAILED: solver,
        Outcome.ERROR: reason,
        Outcome.PROPAGATED: "no data",
        Outcome.UPDATE_SKIPPED: reason,
        Outcome.KEPT: "the prediction is not finite",
        Outcome.DIVERGED: "outside X by more than its width",
    }.get(outcome, "")
    parts = [f"{outcome.value} ({detail})" if detail else outcome.value]
    if evaluated_inside:
        parts.append("the model evaluated inside X (not finite at the estimate or a sigma point)")
    if held_input:
        parts.append("y[k] misses outputs the newest unknown input reaches: that part of it held at its last estimate")
    if at_bound_names:
        parts.append(f"at a side of X: {', '.join(at_bound_names)}")
    if on_boundary:
        parts.append("held there against the data (output residual above 10x the noise)")
    return "; ".join(parts)


def failure_message(estimator: str, outcome: list[str]) -> str | None:
    """The warning of a run whose steps failed in more than :data:`FAILURE_SHARE` of them, or None.

    ``outcome``: one :class:`Outcome` value per step.
    """
    steps = len(outcome)
    failed = int(np.isin(outcome, [value.value for value in FAILURES]).sum())
    if failed <= FAILURE_SHARE * steps:
        return None
    return (f"{estimator}: {failed} of {steps} steps failed ({100 * failed / steps:.0f} %): their estimates are the "
            "model's propagation of the last one, or the last one kept (the result's outcome and solver_status say "
            "which and why)")  # fmt: skip


def bound_message(
    estimator: str,
    at_bound_steps: NDArray[np.bool_],
    x_hat: FloatArray,
    box: Box,
    names: tuple[str, ...],
    *,
    constrained: bool = True,
) -> str | None:
    """The warning of a run whose estimates lie at a side of X in more than :data:`BOUND_SHARE` of the steps.

    ``at_bound_steps (K+1, nx)`` and ``x_hat (K+1, nx)`` are the run's flags and estimates; the
    message names each such state, the side (lower or upper, with its value) and the share of
    steps, then the three readings: X too narrow (``constrained``: the estimator keeps its estimates
    in X, so a true state beyond a side is estimated at it), a physical limit the state reaches, or
    an estimate wrong there. None when no state reaches the share.
    """
    described = _at_sides(at_bound_steps, x_hat, box, names, "X")
    if described is None:
        return None
    narrow = (
        "X may be too narrow (this estimator keeps its estimates in X, so a true state beyond a side is estimated at "
        "it: give a wider X)"
        if constrained
        else "X may be too narrow for the true state (give a wider X)"
    )
    return (
        f"{estimator}: the estimate of {described}. Three readings: {narrow}; the side is a physical "
        "limit the state reaches (estimates on it are then expected); or the estimate is wrong there (the data or "
        "the estimator's weights do not determine the state: see its guarantee)"
    )


def input_bound_message(
    estimator: str, at_bound_steps: NDArray[np.bool_], w_hat: FloatArray, box: Box, names: tuple[str, ...]
) -> str | None:
    """The warning of a run whose unknown-input estimates lie at a side of W in more than :data:`BOUND_SHARE` of them.

    For an estimator whose model bounds the unknown input by W and keeps ``w_hat`` in it (the smooth-input MHE's
    augmented state): ``at_bound_steps`` and ``w_hat`` are (K, nw). None when no input reaches the share.
    """
    described = _at_sides(at_bound_steps, w_hat, box, names, "W")
    if described is None:
        return None
    return (
        f"{estimator}: the unknown-input estimate of {described}. W may be too narrow: this estimator keeps w in W, "
        "so a larger input is estimated at W's side and the states' estimates err with it (give a wider W: "
        "w_bounds=, or the model's w_range; without either W is nominal_w +- 100 w.scale)"
    )


def _at_sides(
    at_bound_steps: NDArray[np.bool_], values: FloatArray, box: Box, names: tuple[str, ...], domain: str
) -> str | None:
    """Each component at a side of ``domain`` in more than :data:`BOUND_SHARE` of the rows: its sides and share."""
    steps = at_bound_steps.shape[0]
    if not steps:
        return None
    counts = at_bound_steps.sum(axis=0)
    flagged = np.flatnonzero(counts > BOUND_SHARE * steps)
    if not flagged.size:
        return None
    lower_side = np.abs(values - box.lower) <= np.abs(values - box.upper)
    described = []
    for i in flagged:
        low = int(np.count_nonzero(at_bound_steps[:, i] & lower_side[:, i]))
        pairs = (("lower", box.lower[i], low), ("upper", box.upper[i], counts[i] - low))
        sides = [f"{side} side {value:.6g}" for side, value, n in pairs if n]
        described.append(f"{names[i]} at or beyond {domain}'s {' and '.join(sides)} in {counts[i]} of {steps} steps "
                         f"({100.0 * counts[i] / steps:.0f} %)")  # fmt: skip
    return "; ".join(described)


@contextmanager
def quiet_bound_warnings() -> Iterator[None]:
    """Silence :class:`~uiest.errors.BoundWarning` and :class:`~uiest.errors.FailureWarning` inside.

    For runs whose at-bound and failed steps the caller counts itself: design trials, filter tuning and studies run
    many estimators whose results the user never sees one by one; their steps are counted where they are reported.
    """
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BoundWarning)
        warnings.simplefilter("ignore", FailureWarning)
        yield


def without_bound_warnings(function: Callable[Params, Result]) -> Callable[Params, Result]:
    """``function`` run inside :func:`quiet_bound_warnings` (a wrapper in uiest: ``user_stacklevel`` skips it)."""

    @functools.wraps(function)
    def wrapper(*args: Params.args, **kwargs: Params.kwargs) -> Result:
        with quiet_bound_warnings():
            return function(*args, **kwargs)

    return wrapper


__all__ = [
    "AT_BOUND_RTOL",
    "BOUND_SHARE",
    "FAILURES",
    "FAILURE_SHARE",
    "BoundTest",
    "Outcome",
    "at_bound",
    "bound_message",
    "failure_message",
    "input_bound_message",
    "quiet_bound_warnings",
    "status_text",
    "without_bound_warnings",
]
