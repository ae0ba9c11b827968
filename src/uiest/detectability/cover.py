r"""Finite sets of matrices whose convex hull contains a matrix function over a box.

The certificates' LMIs are affine in the Jacobian, so where they hold at matrices ``M_1..M_m``
they hold on their convex hull; if that hull contains ``M(z)`` for every z in the domain, it
contains the mean-value Jacobians of every pair too (the domain is a box, hence convex), and
the certificate holds on the whole domain. :func:`cover` finds such vertices:

- **constant**: every entry of M is constant over the domain: one vertex.
- **exact by entries** (the default): M's entries are read as exact forms
  (:mod:`uiest.detectability.affine`); a basis of their non-constant parts is chosen among the
  entries themselves (an entry that is another one up to a constant factor and offset, or a
  combination of others, is not a parameter of its own), so ``M(z) = M_0 + sum_j theta_j(z) M_j``
  holds exactly with ``theta_j`` the basis entries. Each ``theta_j`` is bounded over the box by
  interval arithmetic with branch and bound (:mod:`uiest.detectability.interval`: sound, rounding
  included), and the 2^r corners of that box, mapped through the exact relations, are the vertices.
- **parameter box**: the same with the user's functions ``theta(z)``; every entry must be an exact
  combination of theta's forms. A map that does not carry the Jacobian is refused, naming the
  entry, the residual of its best affine fit at the points that excite the entries and the
  parameters most, and where.
- **sampled cover** (only on request, :mod:`uiest.detectability.sampled_cover`): a polytope around
  sampled values, evidence and not a proof.

The vertices are evaluated in floating point from the exact coefficients; :attr:`Cover.rounding`
bounds that rounding relative to the largest vertex entry (a few units in the last place).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from fractions import Fraction

import casadi as ca
import numpy as np
from numpy.typing import NDArray

from uiest.box import Box, FloatArray
from uiest.detectability import interval
from uiest.detectability.affine import Expressed, Forms, constant_of, express, variable_part
from uiest.detectability.lmi import batched, grid_points
from uiest.detectability.sampled_cover import sampled_vertices
from uiest.errors import ModelError, OptionError

__all__ = ["MAX_PARAMETERS", "Cover", "cover"]

CONSTANT, ENTRIES, PARAMETER_BOX, SAMPLED = "constant", "exact by entries", "parameter box", "sampled cover"
"""The kinds of cover; all but SAMPLED are proofs."""

METHODS = ("exact", "sampled")
"""``cover(method=...)``: "exact" (a proof, or a ModelError saying why none is possible) or "sampled"."""

MAX_PARAMETERS = 10
"""Most parameters (basis entries) of an exact cover: 2^10 = 1024 vertices."""

AFFINE_RTOL = 1e-9
"""A parameter map whose best affine fit misses an entry by more than this fraction of its spread is 'not affine'."""

WHAT_TO_DO = (
    "give parameters= (a few functions of x and u it is affine in), a smaller X, or cover='sampled' (a check "
    "at samples, not a proof)"
)
"""What a refused exact cover's message tells the user to do."""


@dataclass(frozen=True, kw_only=True)
class Cover:
    """Vertices whose convex hull contains ``M(z)`` over a box.

    Attributes
    ----------
    vertices : ndarray, shape (m, a, b)
        The matrices ``M_1 .. M_m``.
    kind : str
        :data:`CONSTANT`, :data:`ENTRIES`, :data:`PARAMETER_BOX` or :data:`SAMPLED`.
    sound : bool
        True when the hull provably contains M over the whole box (every kind but SAMPLED).
    dimension : int
        Number of parameters (the affine dimension the matrices vary in).
    description : str
        One sentence on how the vertices were found, with the numbers.
    samples : ndarray, shape (s, a, b)
        The matrices at sampled points of the box and, for exact covers, at the points where the
        parameters' extremes were found. The hull of the vertices contains them: an LMI infeasible
        at these is infeasible on the domain.
    rounding : float
        Bound on the rounding of the vertices' floating-point evaluation, relative to their
        largest entry (0 for a sampled cover, whose vertices carry no exact claim).
    extremes : ndarray, shape (k, n) or None
        Points of the box where the parameters' extremes were found (exact covers), where narrow
        features of the Jacobian are: the adversarial search of :mod:`uiest.detectability.falsify`
        starts pairs there.

    """

    vertices: FloatArray
    kind: str
    sound: bool
    dimension: int
    description: str
    samples: FloatArray
    rounding: float = 0.0
    extremes: FloatArray | None = None


def relevant_axes(fun: ca.Function) -> NDArray[np.bool_]:
    """Boolean mask over the entries of z that ``fun(z)`` depends on (structurally)."""
    z = ca.SX.sym("z", fun.numel_in(0))
    out = ca.vec(fun(z))
    return np.array([bool(ca.depends_on(out, z[i])) for i in range(z.numel())], dtype=bool)


def cover(
    fun: ca.Function,
    box: Box,
    *,
    parameters: ca.Function | None = None,
    method: str = "exact",
    samples: int = 4000,
    seed: int = 0,
    names: tuple[str, ...] | None = None,
) -> Cover:
    """Vertices covering ``{fun(z) : z in box}`` (see the module docstring).

    Parameters
    ----------
    fun : casadi.Function
        ``z (n,) -> M (a, b)``, an SX function.
    box : Box
        The domain of z; sides that M depends on must be finite.
    parameters : casadi.Function, optional
        ``z (n,) -> theta (r,)`` that M is affine in (a parameter box); None: the exact cover by entries.
    method : {"exact", "sampled"}
        "sampled" covers the values at samples (not a proof); ``parameters`` are then ignored.
    samples : int
        Uniform samples of the box (besides corners and a grid).
    seed : int
        Seed of the samples.
    names : tuple of str, optional
        Names of the entries of z, for messages.

    Raises
    ------
    ModelError
        An unbounded side that M depends on; M not affine in the given parameters (or not provably);
        an exact cover that needs more than :data:`MAX_PARAMETERS` parameters or an operation interval
        arithmetic cannot bound (the message says what to do).

    """
    if method not in METHODS:
        raise OptionError(f"cover: expected one of {METHODS}, got {method!r}")
    names = names or tuple(f"z[{i}]" for i in range(box.size))
    use = parameters if method == "exact" else None
    mask = relevant_axes(fun) | (relevant_axes(use) if use is not None else False)
    rows, cols = fun.size_out(0)
    if not mask.any():
        value = np.asarray(fun(box.center), dtype=float).reshape(1, rows, cols)
        return Cover(
            vertices=value,
            kind=CONSTANT,
            sound=True,
            dimension=0,
            description="the matrix is constant over the domain (structurally)",
            samples=value,
        )
    unbounded = [names[i] for i in np.flatnonzero(mask & ~(np.isfinite(box.lower) & np.isfinite(box.upper)))]
    if unbounded:
        raise ModelError(
            f"the Jacobian depends on {unbounded}, whose domain is unbounded; a certificate covers a bounded domain: "
            "give finite bounds for them"
        )
    center = box.center
    domain = Box(np.where(mask, box.lower, center), np.where(mask, box.upper, center))
    points = _sample_points(domain, samples, seed)
    if method == "sampled":
        values = _evaluate(fun, points)
        vertices, r, description = sampled_vertices(fun, values, points, domain, rows, cols)
        return Cover(
            vertices=vertices,
            kind=SAMPLED,
            sound=False,
            dimension=r,
            description=description,
            samples=_unvec(values, rows, cols),
        )
    return _exact(fun, domain, use, points, seed, names)


def _fixed(fun: ca.Function, domain: Box) -> ca.Function:
    """``fun`` with the degenerate sides of ``domain`` substituted (CasADi folds what becomes constant)."""
    z = ca.SX.sym("z", domain.size)
    sides = enumerate(zip(domain.lower, domain.upper, strict=True))
    given = [ca.SX(float(lo)) if lo == hi else z[i] for i, (lo, hi) in sides]
    return ca.Function(fun.name(), [z], [ca.densify(fun(ca.vertcat(*given) if given else z))])


def _exact(
    fun: ca.Function, domain: Box, parameters: ca.Function | None, points: FloatArray, seed: int, names: tuple[str, ...]
) -> Cover:
    rows, cols = fun.size_out(0)
    fixed = _fixed(fun, domain)
    forms = Forms()
    entries = forms.of(fixed)
    varying = [e for e, form in enumerate(entries) if variable_part(form)]
    z = ca.SX.sym("z", domain.size)
    matrix = ca.vec(fixed(z))
    if not varying:
        value = np.array([float(constant_of(form)) for form in entries])
        vertex = _unvec(value[None], rows, cols)
        return Cover(
            vertices=vertex,
            kind=CONSTANT,
            sound=True,
            dimension=0,
            description="every entry of the matrix is constant over the domain (exact forms)",
            samples=vertex,
        )
    if parameters is None:
        basis_forms = [entries[e] for e in varying]
        reduction = express(basis_forms, basis_forms)
        theta = ca.Function("theta", [z], [ca.vertcat(*[matrix[varying[j]] for j in reduction.basis])])
        kind = ENTRIES
    else:
        given = _fixed(parameters, domain)
        basis_forms = forms.of(given)
        reduction = express(basis_forms, [entries[e] for e in varying])
        outside = [varying[i] for i, c in reduction.coefficients.items() if c is None]
        if outside:
            raise _not_carried(fixed, given, outside, domain, points, names, rows)
        theta = ca.Function("theta", [z], [ca.vec(given(z))[list(reduction.basis)]])
        kind = PARAMETER_BOX
    r = len(reduction.basis)
    if r > MAX_PARAMETERS:
        raise ModelError(
            f"the Jacobian's {len(varying)} varying entries span {r} independent functions over the domain (exact "
            f"forms), more than {MAX_PARAMETERS} for an exact cover (2^{r} vertices): {WHAT_TO_DO}"
        )
    found = _bounds(theta, domain, rows, kind, reduction, varying, seed)
    offset, slopes = _coefficients(entries, varying, basis_forms, reduction)
    corners = np.array(list(itertools.product(*zip(found.lower, found.upper, strict=True))))
    flat = offset + corners @ slopes
    flat = np.unique(flat, axis=0)
    size = max(float(np.abs(flat).max()), 1e-300)
    rounding = (r + 2) * 2.0**-53 * float((np.abs(offset) + np.abs(corners) @ np.abs(slopes)).max()) / size
    gap = float(np.max(found.gap / np.maximum(found.upper - found.lower, 1e-300)))
    what = (f"{r} of its {len(varying)} varying entries (the others are exact combinations of them)"
            if kind == ENTRIES else
            f"{r} parameters that carry its {len(varying)} varying entries exactly")  # fmt: skip
    description = (
        f"{len(flat)} corners of the box of {what}, bounded by interval arithmetic ({found.boxes} sub-boxes, within "
        f"{gap:.1e} of the attained range)"
    )
    extremes = np.vstack([found.lower_at, found.upper_at])
    samples = _unvec(_evaluate(fun, np.vstack([points, extremes])), rows, cols)
    return Cover(
        vertices=_unvec(flat, rows, cols),
        kind=kind,
        sound=True,
        dimension=r,
        description=description,
        samples=samples,
        rounding=rounding,
        extremes=extremes,
    )


def _coefficients(
    entries: list[dict], varying: list[int], basis_forms: list[dict], reduction: Expressed
) -> tuple[FloatArray, FloatArray]:
    """``vec M = offset + theta @ slopes`` (exact rationals rounded once): offset (d,), slopes (r, d)."""
    position = {j: k for k, j in enumerate(reduction.basis)}
    offset = [constant_of(form) for form in entries]
    slopes = [[Fraction(0)] * len(entries) for _ in reduction.basis]
    for i, e in enumerate(varying):
        for j, c in (reduction.coefficients[i] or {}).items():
            slopes[position[j]][e] = c
            offset[e] -= c * constant_of(basis_forms[j])
    return np.array([float(c) for c in offset]), np.array([[float(c) for c in row] for row in slopes]).reshape(
        len(reduction.basis), len(entries)
    )


def _entry(e: int, rows: int) -> str:
    return f"[{e % rows}, {e // rows}]"


def _bounds(
    theta: ca.Function, domain: Box, rows: int, kind: str, reduction: Expressed, varying: list[int], seed: int
) -> interval.Bounds:
    """Interval bounds of the parameters; ModelError when interval arithmetic cannot give finite ones."""
    what = "the parameters" if kind == PARAMETER_BOX else "the Jacobian's entries"
    try:
        found = interval.bounds(theta, domain, seed=seed)
    except interval.IntervalUnsupportedError as exc:
        raise ModelError(f"interval arithmetic cannot bound {what} over the domain ({exc}): {WHAT_TO_DO}") from None
    infinite = np.flatnonzero(~(np.isfinite(found.lower) & np.isfinite(found.upper)))
    if len(infinite):
        j = int(infinite[0])
        name = f"parameter {reduction.basis[j]}" if kind == PARAMETER_BOX else (
            f"entry {_entry(varying[reduction.basis[j]], rows)}")  # fmt: skip
        raise ModelError(
            f"interval arithmetic finds {name} unbounded over the domain (bounds {found.lower[j]:.3g} .. "
            f"{found.upper[j]:.3g}; e.g. a division by a quantity that can vanish): {WHAT_TO_DO}"
        )
    return found


def _not_carried(
    fixed: ca.Function,
    given: ca.Function,
    outside: list[int],
    domain: Box,
    points: FloatArray,
    names: tuple[str, ...],
    rows: int,
) -> ModelError:
    """Why a parameter map does not carry the entries ``outside``: the best affine fit's residual and where.

    The fit uses the sampled points and the points where interval branch and bound found the
    extremes of the parameters and of those entries (narrow features are found there).
    """
    z = ca.SX.sym("z", domain.size)
    entries = ca.Function("entries", [z], [ca.vec(fixed(z))[outside]])
    extra = [points]
    for f in (given, entries):
        try:
            found = interval.bounds(f, domain)
            extra += [found.lower_at, found.upper_at]
        except interval.IntervalUnsupportedError:
            pass
    at = np.vstack(extra)
    values = _evaluate(entries, at)
    theta = _evaluate(given, at)
    design = np.hstack([np.ones((len(at), 1)), theta])
    coef, *_ = np.linalg.lstsq(design, values, rcond=None)
    residual = np.abs(design @ coef - values)
    spread = np.ptp(values, axis=0)
    spread = np.where(spread > 0, spread, np.abs(values).max(axis=0))
    relative = residual.max(axis=0) / np.maximum(spread, 1e-300)
    worst = int(np.argmax(relative))
    point = at[int(np.argmax(residual[:, worst]))]
    sides = zip(names, point, domain.lower, domain.upper, strict=True)
    where = ", ".join(f"{n}={v:.6g}" for n, v, lo, hi in sides if lo < hi)
    entry = _entry(outside[worst], rows)
    if relative[worst] > AFFINE_RTOL:
        return ModelError(
            f"parameters: the Jacobian is not affine in the given parameters: entry {entry} (scaled) misses its best "
            f"affine fit in them by {residual[:, worst].max():.3g} ({relative[worst]:.2g} of its spread) at {where}, "
            f"among {len(at)} points; include every nonlinear function of x and u that the Jacobian depends on"
        )
    return ModelError(
        f"parameters: the Jacobian's expressions are not exact combinations of the parameters' expressions (entry "
        f"{entry}, and {len(outside) - 1} more), though its best affine fit in them misses it by only "
        f"{relative[worst]:.1e} of its spread at {len(at)} points (an identity the exact forms do not apply, e.g. "
        "1/cosh(x)^2 for 1 - tanh(x)^2, or rounding in the model's constants); write the parameters as the "
        "expressions that appear in df/dx, or omit parameters= for the exact cover by the Jacobian's entries"
    )


def _sample_points(domain: Box, samples: int, seed: int) -> FloatArray:
    """Corners, a 5-point grid (at most ~3000 points) and uniform samples, shape (m, n)."""
    free = int(np.count_nonzero(domain.width > 0))
    per_axis = max(2, min(5, int(3000 ** (1.0 / max(free, 1)))))
    rng = np.random.default_rng(seed)
    return np.vstack([grid_points(domain, per_axis), domain.sample(rng, samples)])


def _evaluate(fun: ca.Function, points: FloatArray) -> FloatArray:
    """``fun`` at each point, flattened column-major like ``ca.vec``: (m, a b)."""
    (values,) = batched(fun, [points])
    return np.transpose(values, (0, 2, 1)).reshape(len(points), -1)


def _unvec(flat: FloatArray, rows: int, cols: int) -> FloatArray:
    """Inverse of the column-major flattening of :func:`_evaluate`: (m, a b) -> (m, a, b)."""
    return np.transpose(flat.reshape(-1, cols, rows), (0, 2, 1))
