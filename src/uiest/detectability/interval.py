r"""Sound bounds of CasADi expressions over boxes: interval arithmetic with branch and bound.

:func:`enclosure` evaluates an SX :class:`casadi.Function` ``z (n,) -> g (k,)`` in interval
arithmetic on m boxes at once, instruction by instruction (numpy arrays of lower and upper
ends, widened outwards by two units in the last place after every operation, so that rounding
never makes an enclosure too small). :func:`bounds` turns enclosures into tight, still sound,
bounds of each output over one box: it splits the boxes whose enclosure could still exceed the
best value found at a point until the two meet within a tolerance.

The natural interval extension over-estimates when a variable appears more than once
(``x - x`` gives ``[-w, w]``); splitting shrinks that error linearly with the box size.
Operations outside :data:`SUPPORTED` raise :class:`IntervalUnsupportedError`, and the caller falls
back to sampled bounds (and says so).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import casadi as ca
import numpy as np
from numpy.typing import NDArray

from uiest.box import Box, FloatArray
from uiest.detectability.lmi import grid_points

__all__ = ["Bounds", "IntervalUnsupportedError", "bounds", "centered", "enclosure", "range_box"]

Interval = tuple[FloatArray, FloatArray]


class IntervalUnsupportedError(Exception):
    """The expression uses an operation interval arithmetic does not cover here."""


def _widen(lo: FloatArray, hi: FloatArray) -> Interval:
    """Outward rounding (two units in the last place on each side); NaN (no information) becomes +-inf."""
    lo = np.where(np.isnan(lo), -np.inf, lo)
    hi = np.where(np.isnan(hi), np.inf, hi)
    return np.nextafter(np.nextafter(lo, -np.inf), -np.inf), np.nextafter(np.nextafter(hi, np.inf), np.inf)


def _increasing(fun: Callable[[FloatArray], FloatArray]) -> Callable[[Interval], Interval]:
    return lambda a: (fun(a[0]), fun(a[1]))


def _even(fun: Callable[[FloatArray], FloatArray]) -> Callable[[Interval], Interval]:
    """``fun`` even and increasing on [0, inf) (x^2, |x|, cosh)."""

    def apply(a: Interval) -> Interval:
        lo, hi = a
        flo, fhi = fun(lo), fun(hi)
        straddles = (lo < 0) & (hi > 0)
        low = np.where(straddles, fun(np.zeros_like(lo)), np.minimum(flo, fhi))
        return low, np.maximum(flo, fhi)

    return apply


def _mul(a: Interval, b: Interval) -> Interval:
    products = np.stack([a[0] * b[0], a[0] * b[1], a[1] * b[0], a[1] * b[1]])
    products = np.where(np.isnan(products), 0.0, products)  # only 0 * inf (inputs are never NaN): the zero wins
    return products.min(axis=0), products.max(axis=0)


def _inv(a: Interval) -> Interval:
    lo, hi = a
    with np.errstate(divide="ignore"):
        spans_zero = (lo <= 0) & (hi >= 0)
        return np.where(spans_zero, -np.inf, 1.0 / hi), np.where(spans_zero, np.inf, 1.0 / lo)


def _periodic_peak(lo: FloatArray, hi: FloatArray, peak: float) -> NDArray[np.bool_]:
    """Whether ``[lo, hi]`` contains ``peak + 2 pi k`` for some integer k."""
    k = np.ceil((lo - peak) / (2.0 * np.pi))
    return peak + 2.0 * np.pi * k <= hi


def _sin(a: Interval) -> Interval:
    lo, hi = a
    s_lo, s_hi = np.sin(lo), np.sin(hi)
    low, high = np.minimum(s_lo, s_hi), np.maximum(s_lo, s_hi)
    wide = (hi - lo >= 2.0 * np.pi) | ~np.isfinite(lo) | ~np.isfinite(hi)
    high = np.where(wide | _periodic_peak(lo, hi, 0.5 * np.pi), 1.0, high)
    low = np.where(wide | _periodic_peak(lo, hi, -0.5 * np.pi), -1.0, low)
    return low, high


def _cos(a: Interval) -> Interval:
    lo, hi = a
    c_lo, c_hi = np.cos(lo), np.cos(hi)
    low, high = np.minimum(c_lo, c_hi), np.maximum(c_lo, c_hi)
    wide = (hi - lo >= 2.0 * np.pi) | ~np.isfinite(lo) | ~np.isfinite(hi)
    high = np.where(wide | _periodic_peak(lo, hi, 0.0), 1.0, high)
    low = np.where(wide | _periodic_peak(lo, hi, np.pi), -1.0, low)
    return low, high


def _tan(a: Interval) -> Interval:
    lo, hi = a
    pole = _periodic_peak(lo, hi, 0.5 * np.pi) | _periodic_peak(lo, hi, -0.5 * np.pi) | (hi - lo >= np.pi)
    return np.where(pole, -np.inf, np.tan(lo)), np.where(pole, np.inf, np.tan(hi))


def _domain(fun: Callable[[FloatArray], FloatArray], low: float) -> Callable[[Interval], Interval]:
    """Increasing ``fun`` defined on ``[low, inf)``, enclosed on the part of the argument where it is defined.

    An argument reaching below ``low`` is clamped to it (``log`` gives ``-inf``); one entirely below
    gives no information (``-inf, inf``).
    """

    def apply(a: Interval) -> Interval:
        lo, hi = a
        outside = hi < low
        with np.errstate(invalid="ignore", divide="ignore"):
            return (np.where(outside, -np.inf, fun(np.maximum(lo, low))),
                    np.where(outside, np.inf, fun(np.maximum(hi, low))))  # fmt: skip

    return apply


def _constpow(a: Interval, b: Interval) -> Interval:
    """``a ** p`` for a constant exponent p (``b`` is degenerate)."""
    p = float(b[0].flat[0]) if b[0].size else 0.0
    if not np.all(b[0] == b[1]):
        return _pow(a, b)
    if p == int(p):
        q = int(p)
        if q == 0:
            return np.ones_like(a[0]), np.ones_like(a[0])
        base = _even(np.abs)(a) if q % 2 == 0 else a
        if q > 0:
            return base[0] ** q, base[1] ** q
        return _constpow(_inv(a), (np.full_like(a[0], -q), np.full_like(a[0], -q)))
    with np.errstate(invalid="ignore", divide="ignore"):  # defined for a >= 0 only: clamp, as in _domain
        lo, hi = a
        outside = hi < 0
        lo, hi = np.maximum(lo, 0.0), np.maximum(hi, 0.0)
        out = (lo**p, hi**p) if p > 0 else (hi**p, lo**p)
        return np.where(outside, -np.inf, out[0]), np.where(outside, np.inf, out[1])


def _pow(a: Interval, b: Interval) -> Interval:
    """General ``a ** b = exp(b log a)`` (a > 0)."""
    return _increasing(np.exp)(_mul(b, _domain(np.log, 0.0)(a)))


def _compare(strict: bool) -> Callable[[Interval, Interval], Interval]:
    def apply(a: Interval, b: Interval) -> Interval:
        true = a[1] < b[0] if strict else a[1] <= b[0]
        false = a[0] >= b[1] if strict else a[0] > b[1]
        return np.where(true, 1.0, 0.0), np.where(false, 0.0, 1.0)

    return apply


def _if_else_zero(c: Interval, x: Interval) -> Interval:
    nonzero = (c[0] > 0) | (c[1] < 0)
    zero = (c[0] == 0) & (c[1] == 0)
    lo = np.where(nonzero, x[0], np.where(zero, 0.0, np.minimum(x[0], 0.0)))
    hi = np.where(nonzero, x[1], np.where(zero, 0.0, np.maximum(x[1], 0.0)))
    return lo, hi


UNARY: dict[int, Callable[[Interval], Interval]] = {
    ca.OP_NEG: lambda a: (-a[1], -a[0]),
    ca.OP_ASSIGN: lambda a: a,
    ca.OP_TWICE: lambda a: (2.0 * a[0], 2.0 * a[1]),
    ca.OP_SQ: _even(np.square),
    ca.OP_FABS: _even(np.abs),
    ca.OP_COSH: _even(np.cosh),
    ca.OP_INV: _inv,
    ca.OP_EXP: _increasing(np.exp),
    ca.OP_EXPM1: _increasing(np.expm1),
    ca.OP_TANH: _increasing(np.tanh),
    ca.OP_SINH: _increasing(np.sinh),
    ca.OP_ATAN: _increasing(np.arctan),
    ca.OP_ASINH: _increasing(np.arcsinh),
    ca.OP_SIGN: _increasing(np.sign),
    ca.OP_ERF: _increasing(np.vectorize(math.erf, otypes=[float])),
    ca.OP_SQRT: _domain(np.sqrt, 0.0),
    ca.OP_LOG: _domain(np.log, 0.0),
    ca.OP_LOG1P: _domain(np.log1p, -1.0),
    ca.OP_SIN: _sin,
    ca.OP_COS: _cos,
    ca.OP_TAN: _tan,
}

BINARY: dict[int, Callable[[Interval, Interval], Interval]] = {
    ca.OP_ADD: lambda a, b: (a[0] + b[0], a[1] + b[1]),
    ca.OP_SUB: lambda a, b: (a[0] - b[1], a[1] - b[0]),
    ca.OP_MUL: _mul,
    ca.OP_DIV: lambda a, b: _mul(a, _inv(b)),
    ca.OP_CONSTPOW: _constpow,
    ca.OP_POW: _pow,
    ca.OP_FMIN: lambda a, b: (np.minimum(a[0], b[0]), np.minimum(a[1], b[1])),
    ca.OP_FMAX: lambda a, b: (np.maximum(a[0], b[0]), np.maximum(a[1], b[1])),
    ca.OP_LT: _compare(strict=True),
    ca.OP_LE: _compare(strict=False),
    ca.OP_IF_ELSE_ZERO: _if_else_zero,
}

SUPPORTED = frozenset(UNARY) | frozenset(BINARY)
"""CasADi operation codes with an interval rule (plus constants, inputs and outputs)."""

_OP_NAMES = {getattr(ca, name): name[3:].lower() for name in dir(ca) if name.startswith("OP_")}


def check_supported(fun: ca.Function) -> None:
    """Raise :class:`IntervalUnsupportedError` naming the first operation without an interval rule."""
    if not fun.is_a("SXFunction"):
        raise IntervalUnsupportedError(f"{fun.name()} is not an SX function")
    for k in range(fun.n_instructions()):
        op = fun.instruction_id(k)
        if op not in SUPPORTED and op not in (ca.OP_CONST, ca.OP_INPUT, ca.OP_OUTPUT):
            raise IntervalUnsupportedError(f"operation '{_OP_NAMES.get(op, op)}' has no interval rule")


def centered(fun: ca.Function) -> ca.Function:
    """``z -> (g(z), dg/dz(z))`` for the mean-value form of :func:`enclosure` (dense outputs)."""
    z = ca.SX.sym("z", fun.numel_in(0))
    g = ca.densify(fun(z))
    return ca.Function(f"{fun.name()}_centered", [z], [g, ca.densify(ca.jacobian(g, z))])


UNIT_ROUNDOFF = 2.0**-53


def enclosure(
    fun: ca.Function, lower: FloatArray, upper: FloatArray, derivative: ca.Function | None = None
) -> Interval:
    """Interval enclosures of ``fun`` (one input z (n,), one output (k,)) on m boxes.

    With ``derivative`` (from :func:`centered`), the natural enclosure is intersected with the
    mean-value form ``g(c) + [dg/dz](box) (box - c)`` at the box centres c, whose
    over-estimation shrinks quadratically with the box size (``g(c)`` is itself enclosed, and
    the rounding of the sum is bounded).

    Parameters
    ----------
    fun : casadi.Function
        An SX function with one dense input and one output (a sparse output is densified).
    lower, upper : ndarray, shape (m, n)
        The boxes.

    Returns
    -------
    (lo, hi) : ndarrays, shape (m, k)
        ``lo <= fun(z) <= hi`` for every z in each box where fun is defined (``-inf, inf`` where
        nothing is known).

    """
    if derivative is None:
        return _natural(_dense(fun), lower, upper)
    lo, hi, _, _ = _enclose(_dense(fun), lower, upper, _jacobian_part(derivative))
    return lo, hi


def _enclose(
    fun: ca.Function, lower: FloatArray, upper: FloatArray, jacobian: ca.Function
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """:func:`enclosure` with the mean-value form, also returning the derivative's enclosure (m, k, n) twice."""
    lo, hi = _natural(fun, lower, upper)
    center = 0.5 * (lower + upper)
    k, n = fun.numel_out(0), fun.numel_in(0)
    g_lo, g_hi = _natural(fun, center, center)
    jac_lo, jac_hi = (a.reshape(-1, n, k).transpose(0, 2, 1) for a in _natural(jacobian, lower, upper))
    d_lo, d_hi = (lower - center)[:, None, :], (upper - center)[:, None, :]
    terms = np.stack([jac_lo * d_lo, jac_lo * d_hi, jac_hi * d_lo, jac_hi * d_hi])
    terms = np.where(np.isnan(terms), 0.0, terms)  # 0 * inf on a degenerate side: the term is 0
    low, high = g_lo + terms.min(axis=0).sum(axis=2), g_hi + terms.max(axis=0).sum(axis=2)
    with np.errstate(invalid="ignore"):
        slack = (n + 2) * UNIT_ROUNDOFF * (np.abs(g_lo) + np.abs(g_hi) + np.abs(terms).max(axis=0).sum(axis=2))
    mv_lo, mv_hi = _widen(low - slack, high + slack)
    return np.maximum(lo, mv_lo), np.minimum(hi, mv_hi), jac_lo, jac_hi


def _dense(fun: ca.Function) -> ca.Function:
    """``fun`` with a dense output (structural zeros become explicit constants)."""
    if fun.sparsity_out(0).is_dense():
        return fun
    check_supported(fun)
    z = ca.SX.sym("z", fun.numel_in(0))
    return ca.Function(f"{fun.name()}_dense", [z], [ca.densify(fun(z))])


def _jacobian_part(derivative: ca.Function) -> ca.Function:
    z = ca.SX.sym("z", derivative.numel_in(0))
    return ca.Function("jacobian", [z], [ca.vec(derivative(z)[1])])


def _natural(fun: ca.Function, lower: FloatArray, upper: FloatArray) -> Interval:
    """The natural interval extension of ``fun`` (dense output) on m boxes: (lo, hi) of shape (m, k)."""
    check_supported(fun)
    m = lower.shape[0]
    work: dict[int, Interval] = {}
    out_lo, out_hi = np.full((m, fun.numel_out(0)), -np.inf), np.full((m, fun.numel_out(0)), np.inf)
    with np.errstate(over="ignore", invalid="ignore"):
        for k in range(fun.n_instructions()):
            op, args, res = fun.instruction_id(k), fun.instruction_input(k), fun.instruction_output(k)
            if op == ca.OP_CONST:
                value = np.full(m, fun.instruction_constant(k))
                work[res[0]] = (value, value)
            elif op == ca.OP_INPUT:
                work[res[0]] = (lower[:, args[1]].copy(), upper[:, args[1]].copy())
            elif op == ca.OP_OUTPUT:
                out_lo[:, res[1]], out_hi[:, res[1]] = work[args[0]]
            elif op in UNARY:
                work[res[0]] = _widen(*UNARY[op](work[args[0]]))
            else:
                work[res[0]] = _widen(*BINARY[op](work[args[0]], work[args[1]]))
    return out_lo, out_hi


@dataclass(frozen=True, kw_only=True)
class Bounds:
    """Sound bounds of each output of a function over a box (see :func:`bounds`).

    Attributes
    ----------
    lower, upper : ndarray, shape (k,)
        ``lower <= g(z) <= upper`` on the whole box.
    attained_lower, attained_upper : ndarray, shape (k,)
        The smallest and largest values found at points (so the bounds are tight to within
        ``lower - attained_lower`` etc.).
    boxes : int
        Sub-boxes evaluated.
    lower_at, upper_at : ndarray, shape (k, n)
        The points where ``attained_lower`` and ``attained_upper`` were found.

    """

    lower: FloatArray
    upper: FloatArray
    attained_lower: FloatArray
    attained_upper: FloatArray
    boxes: int
    lower_at: FloatArray
    upper_at: FloatArray

    @property
    def gap(self) -> FloatArray:
        """Largest distance between a bound and the value attained, per output."""
        return np.maximum(self.attained_lower - self.lower, self.upper - self.attained_upper)


def bounds(fun: ca.Function, box: Box, *, rtol: float = 1e-3, max_boxes: int = 40_000, seed: int = 0) -> Bounds:
    """Sound lower and upper bounds of each output of ``fun`` over ``box``, tight to ``rtol``.

    Branch and bound on every output and side at once: a sub-box stays open for a side while its
    enclosure could exceed the best value found at a point (by more than ``rtol`` times the
    attained range), and a box open for any side is split along the side where the function
    changes most (the largest ``max|dg/dz_i| * width_i`` from the derivative's enclosure, for its
    most open output; the widest side relative to the box where that is unbounded), until none is
    left or ``max_boxes`` sub-boxes were evaluated; each bound is the worst enclosure among the boxes
    closed or left open for it, so it is sound either way. Degenerate sides of ``box`` are never
    split. Raises :class:`IntervalUnsupportedError`.
    """
    check_supported(fun)
    fun = _dense(fun)
    if not box.is_bounded:
        raise IntervalUnsupportedError(f"the box is unbounded: {box}")
    rng = np.random.default_rng(seed)
    k = fun.numel_out(0)
    points = np.vstack([box.corners() if box.size <= 10 else box.lower[None], box.center[None], box.sample(rng, 256)])
    values = np.asarray(fun.map(len(points))(points.T), dtype=float).reshape(k, -1).T  # (m, k)
    sides = np.hstack([values, -values])  # side j: output j from above; side k + j: from below
    best = np.nanmax(np.where(np.isnan(sides), -np.inf, sides), axis=0)
    at = points[np.argmax(np.where(np.isnan(sides), -np.inf, sides), axis=0)]
    bound, best, at, used = _branch_and_bound(fun, box, best, at, rtol, max_boxes)
    return Bounds(
        lower=-bound[k:],
        upper=bound[:k],
        attained_lower=-best[k:],
        attained_upper=best[:k],
        boxes=used,
        lower_at=at[k:],
        upper_at=at[:k],
    )


def _branch_and_bound(
    fun: ca.Function, box: Box, best: FloatArray, at: FloatArray, rtol: float, max_boxes: int
) -> tuple[FloatArray, FloatArray, FloatArray, int]:
    """Upper bounds of each side ``(g_1, .., g_k, -g_1, .., -g_k)`` over ``box`` (see :func:`bounds`).

    ``best`` (2k,) and ``at`` (2k, n) are the largest values found so far and their points; returns
    (bounds, best, at, boxes used).
    """
    k = fun.numel_out(0)
    scale = np.where(box.width > 0, box.width, 1.0)
    splittable = box.width > 0
    jacobian = _jacobian_part(centered(fun))
    partner = np.concatenate([np.arange(k, 2 * k), np.arange(k)])  # the opposite side of each side
    lower, upper = box.lower[None].copy(), box.upper[None].copy()
    open_ = np.ones((1, 2 * k), dtype=bool)
    kept = np.full(2 * k, -np.inf)
    best, at = best.copy(), at.copy()
    used = 0
    while len(lower):
        lo, hi, jac_lo, jac_hi = _enclose(fun, lower, upper, jacobian)
        used += len(lower)
        ub = np.hstack([hi, -lo])
        ub = np.where(np.isnan(ub), np.inf, ub)
        mid = 0.5 * (lower + upper)
        value = np.asarray(fun.map(len(mid))(mid.T), dtype=float).reshape(k, -1).T
        point = np.hstack([value, -value])
        if np.any(point > ub + 1e-9 * np.maximum(1.0, np.abs(point))):  # a value above its own enclosure
            raise IntervalUnsupportedError(f"an enclosure of {fun.name()} misses a value it contains (a bug)")
        point = np.where(np.isnan(point), -np.inf, point)
        better = point.max(axis=0) > best
        if better.any():
            index = np.argmax(point, axis=0)
            best = np.where(better, point.max(axis=0), best)
            at[better] = mid[index[better]]
        low = -best[partner]
        with np.errstate(invalid="ignore"):
            tol = rtol * np.maximum(np.maximum(best - low, 1e-9 * np.maximum(np.abs(best), np.abs(low))), 1e-300)
            still = open_ & (ub > best + tol)
        kept = np.maximum(kept, np.where(open_ & ~still, ub, -np.inf).max(axis=0))
        busy = still.any(axis=1)
        if used + 2 * int(busy.sum()) > max_boxes or not splittable.any():
            return np.maximum(kept, np.where(still, ub, -np.inf).max(axis=0)), best, at, used
        lower, upper, open_, ub = lower[busy], upper[busy], still[busy], ub[busy]
        with np.errstate(invalid="ignore", over="ignore"):
            excess = np.where(open_, (ub - best) / tol, -np.inf)
        output = np.argmax(excess, axis=1) % k  # the output most open in each box
        rows = np.arange(len(lower))
        axis = _split_axis(lower, upper, jac_lo[busy][rows, output], jac_hi[busy][rows, output], splittable, scale)
        cut = 0.5 * (lower[rows, axis] + upper[rows, axis])
        left_upper, right_lower = upper.copy(), lower.copy()
        left_upper[rows, axis] = cut
        right_lower[rows, axis] = cut
        lower, upper = np.vstack([lower, right_lower]), np.vstack([left_upper, upper])
        open_ = np.vstack([open_, open_])
    finite = np.isfinite(best)
    if np.any(finite & (kept < np.where(finite, best, 0.0) - 1e-9 * np.maximum(1.0, np.abs(best)))):
        raise IntervalUnsupportedError(f"the enclosures of {fun.name()} lie below a value attained (a bug)")
    return np.maximum(kept, best), best, at, used


def _split_axis(
    lower: FloatArray,
    upper: FloatArray,
    jac_lo: FloatArray,
    jac_hi: FloatArray,
    splittable: NDArray[np.bool_],
    scale: FloatArray,
) -> NDArray[np.intp]:
    """The side to halve per box: the largest smear ``max|dg/dz_i| * width_i`` (where the function changes most).

    Where a smear is infinite (no derivative bound), the widest side relative to the box among those.
    """
    width = upper - lower
    with np.errstate(invalid="ignore"):
        smear = np.maximum(np.abs(jac_lo), np.abs(jac_hi)) * width
    smear = np.where(np.isnan(smear), np.inf, smear)
    smear = np.where(splittable, smear, -1.0)
    relative = np.where(splittable, width / scale, -1.0)
    unknown = np.isinf(smear)
    by_width = np.argmax(np.where(unknown, relative, -1.0), axis=1)
    by_smear = np.argmax(smear, axis=1)
    use_width = unknown.any(axis=1) | (smear.max(axis=1) <= 0.0)
    fallback = np.argmax(relative, axis=1)
    return np.where(unknown.any(axis=1), by_width, np.where(use_width, fallback, by_smear))


GRID_POINTS = 5
"""Points per axis of the grid that bounds a map's range where interval arithmetic cannot (not a proof)."""

SNAP_RTOL = 1e-12
"""A proved bound this close (relative to the range) to a value attained at a point is taken as that value."""


def range_box(fun: ca.Function, box: Box, what: str, seed: int = 0) -> tuple[Box, str]:
    """A box containing ``fun(box)``: proved by interval arithmetic, else the range over a grid of ``box``.

    Returns (box, note); the note is empty when proved, else says that ``what`` was bounded at a grid.
    """
    try:
        found = bounds(fun, box, seed=seed)
        if np.all(np.isfinite(found.lower) & np.isfinite(found.upper)):
            # a bound within rounding of a value attained at a point is that value: the outward rounding of
            # interval arithmetic would otherwise move a box found exactly (a linear map's) by a few units
            slack = SNAP_RTOL * np.maximum(found.attained_upper - found.attained_lower, np.abs(found.attained_upper))
            lower = np.where(found.attained_lower - found.lower <= slack, found.attained_lower, found.lower)
            upper = np.where(found.upper - found.attained_upper <= slack, found.attained_upper, found.upper)
            return Box(lower, upper), ""
        reason = "interval arithmetic left a bound infinite"
    except IntervalUnsupportedError as exc:
        reason = str(exc)
    grid = grid_points(box, GRID_POINTS)
    values = np.asarray(fun.map(len(grid))(grid.T), dtype=float).reshape(-1, len(grid)).T
    note = f"{what} bounded at a grid of {len(grid)} points, not proved ({reason})"
    return Box(values.min(axis=0), values.max(axis=0)), note
