r"""Finite sets of matrices whose convex hull contains a matrix function over a box.

The certificates' LMIs are affine in the Jacobian, so where they hold at matrices ``M_1..M_m``
they hold on their convex hull; if that hull contains ``M(z)`` for every z in the domain, it
contains the mean-value Jacobians of every pair too (the domain is a box, hence convex), and
the certificate holds on the whole domain. :func:`cover` finds such vertices:

- **constant**: M does not depend on z (structurally): one vertex, exact.
- **parameter box**: the user names a few scalar functions ``theta(z)`` with
  ``M(z) = M_0 + sum_j theta_j(z) M_j``. The affine decomposition is fitted on sampled points
  and checked there to 1e-9; the box of theta comes from interval arithmetic with branch and
  bound (:mod:`uiest.detectability.interval`, sound), and its 2^r corners are the vertices.
- **sampled cover**: M is sampled densely (corners, a grid, uniform points); its varying
  entries span an affine space of small dimension r (SVD); in r <= 3 the samples' convex
  hull is outer-approximated by a polytope with many face directions (evenly spread ones plus
  the directions of each varying entry), each face pushed out to the largest value found by
  sampling and local maximisation (L-BFGS-B) plus a margin of 1e-4 of the extent; in r >= 4 a
  box. Its vertices cover every sampled and locally maximised point, not provably all of X:
  it is labelled so.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import casadi as ca
import numpy as np
import scipy.linalg
import scipy.optimize
import scipy.spatial

from uiest.box import Box, FloatArray
from uiest.detectability import interval
from uiest.detectability.lmi import batched, grid_points
from uiest.errors import ModelError

MARGIN = 1e-4
"""Faces of a sampled cover are pushed out by this fraction of the samples' extent."""

SPAN_RTOL = 1e-10
"""Directions of the sampled matrices below this fraction of their spread are dropped (rank)."""

AFFINE_RTOL = 1e-9
"""Largest residual of a parameter map's affine fit, relative to the matrices' size."""

MAX_BOX_DIMENSION = 10
"""Beyond this many independent directions a cover would need over 1024 vertices."""


@dataclass(frozen=True)
class Cover:
    """Vertices whose convex hull contains ``M(z)`` over a box.

    Attributes
    ----------
    vertices : ndarray, shape (m, a, b)
        The matrices ``M_1 .. M_m``.
    kind : str
        "constant", "parameter box" or "sampled cover".
    sound : bool
        True when the hull provably contains M over the whole box (constant, or a parameter
        box with interval bounds); False for a sampled cover.
    dimension : int
        Dimension of the affine set the matrices vary in (number of parameters).
    description : str
        One sentence on how the vertices were found, with the numbers.
    samples : ndarray, shape (s, a, b)
        The matrices at the sampled points themselves (the vertex for a constant matrix). The
        hull of the vertices contains them and more: an LMI infeasible at the vertices but
        feasible at these is undecided, one infeasible at these is infeasible on the domain.

    """

    vertices: FloatArray
    kind: str
    sound: bool
    dimension: int
    description: str
    samples: FloatArray


def relevant_axes(fun: ca.Function) -> FloatArray:
    """Boolean mask over the entries of z that ``fun(z)`` depends on (structurally)."""
    z = ca.SX.sym("z", fun.numel_in(0))
    out = ca.vec(fun(z))
    return np.array([bool(ca.depends_on(out, z[i])) for i in range(z.numel())], dtype=bool)


def cover(
    fun: ca.Function,
    box: Box,
    *,
    parameters: ca.Function | None = None,
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
        ``z (n,) -> theta (r,)`` with M affine in theta (a parameter box); None for a sampled cover.
    samples : int
        Uniform samples of the box (besides corners and a grid).
    seed : int
        Seed of the samples.
    names : tuple of str, optional
        Names of the entries of z, for error messages.

    Raises
    ------
    ModelError
        An unbounded side that M depends on, or M not affine in the given parameters.

    """
    names = names or tuple(f"z[{i}]" for i in range(box.size))
    mask = relevant_axes(fun) | (relevant_axes(parameters) if parameters is not None else False)
    rows, cols = fun.size_out(0)
    if not mask.any():
        value = np.asarray(fun(box.center), dtype=float).reshape(1, rows, cols)
        return Cover(value, "constant", True, 0, "the matrix is constant over the domain (structurally)", value)
    unbounded = [names[i] for i in np.flatnonzero(mask & ~(np.isfinite(box.lower) & np.isfinite(box.upper)))]
    if unbounded:
        raise ModelError(
            f"the Jacobian depends on {unbounded}, whose domain is unbounded; a certificate covers a bounded domain: "
            "give finite bounds for them"
        )
    center = box.center
    domain = Box(np.where(mask, box.lower, center), np.where(mask, box.upper, center))
    points = _sample_points(domain, samples, seed)
    values = _evaluate(fun, points)
    if parameters is not None:
        return _parameter_cover(values, parameters, points, domain, rows, cols, seed)
    return _sampled_cover(fun, values, points, domain, rows, cols)


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


def _parameter_cover(
    values: FloatArray, parameters: ca.Function, points: FloatArray, domain: Box, rows: int, cols: int, seed: int
) -> Cover:
    (theta,) = (a.reshape(len(points), -1) for a in batched(parameters, [points]))
    r = theta.shape[1]
    design = np.hstack([np.ones((len(points), 1)), theta])
    coef, *_ = np.linalg.lstsq(design, values, rcond=None)
    residual = float(np.abs(design @ coef - values).max())
    size = max(1.0, float(np.abs(values).max()))
    if residual > AFFINE_RTOL * size:
        raise ModelError(
            f"parameters: the Jacobian is not affine in the given parameters (largest residual of the affine fit "
            f"{residual:.3g} at {len(points)} points, relative {residual / size:.2e} > {AFFINE_RTOL:g}); include "
            "every nonlinear function of x and u that the Jacobian depends on"
        )
    try:
        found = interval.bounds(parameters, domain, seed=seed)
        if not np.all(np.isfinite(found.lower) & np.isfinite(found.upper)):
            raise interval.IntervalUnsupportedError("interval arithmetic left a bound infinite")
        lower, upper, sound = found.lower, found.upper, True
        gap = float(np.max(found.gap / np.maximum(upper - lower, 1e-300)))
        how = (
            f"bounds of theta by interval arithmetic ({found.boxes} sub-boxes, within {gap:.1e} of the attained range)"
        )
    except interval.IntervalUnsupportedError as exc:
        lower, upper = theta.min(axis=0), theta.max(axis=0)
        width = upper - lower
        lower, upper, sound = lower - MARGIN * width, upper + MARGIN * width, False
        how = f"bounds of theta sampled ({exc}), widened by {MARGIN:g}"
    corners = np.array(list(itertools.product(*zip(lower, upper, strict=True))))
    vertices = _unvec(coef[0] + corners @ coef[1:], rows, cols)
    return Cover(
        vertices,
        "parameter box",
        sound,
        r,
        f"{2**r} corners of the box of {r} parameters the Jacobian is affine in (fit checked at {len(points)} points "
        f"to {residual / size:.1e}); {how}",
        _unvec(values, rows, cols),
    )


def _span(deviation: FloatArray) -> FloatArray:
    """Orthonormal rows (r, d) spanning the deviations (m, d) up to ``SPAN_RTOL`` of their size."""
    _, s, vt = np.linalg.svd(deviation, full_matrices=False)
    biggest = float(np.abs(deviation).max())
    for r in range(1, len(s) + 1):
        residual = deviation - (deviation @ vt[:r].T) @ vt[:r]
        if np.abs(residual).max() <= SPAN_RTOL * biggest:
            return vt[:r]
    return vt


def _directions(r: int, entries: FloatArray) -> FloatArray:
    """Unit face normals in r-dimensional whitened coordinates: evenly spread ones and +-entries."""
    if r == 1:
        return np.array([[1.0], [-1.0]])
    if r == 2:
        angle = np.linspace(0.0, 2.0 * np.pi, 16, endpoint=False)
        spread = np.stack([np.cos(angle), np.sin(angle)], axis=1)
    elif r == 3:
        spread = np.array([d for d in itertools.product((-1.0, 0.0, 1.0), repeat=3) if any(d)])
    else:
        spread = np.vstack([np.eye(r), -np.eye(r)])
    if r <= 3:
        norms = np.linalg.norm(entries, axis=1, keepdims=True)
        useful = entries[norms[:, 0] > 1e-9 * norms.max()] / norms[norms[:, 0] > 1e-9 * norms.max()]
        spread = np.vstack([spread, useful, -useful])
    spread = spread / np.linalg.norm(spread, axis=1, keepdims=True)
    keep = [0]
    for i in range(1, len(spread)):  # drop duplicate directions
        if np.min(np.linalg.norm(spread[keep] - spread[i], axis=1)) > 1e-9:
            keep.append(i)
    return spread[keep]


def _sampled_cover(
    fun: ca.Function, values: FloatArray, points: FloatArray, domain: Box, rows: int, cols: int
) -> Cover:
    mean = values.mean(axis=0)
    deviation = values - mean
    if np.abs(deviation).max() <= 1e-12 * max(1.0, float(np.abs(mean).max())):
        description = f"the matrix did not vary at {len(points)} sampled points"
        return Cover(_unvec(mean[None], rows, cols), "sampled cover", False, 0, description, _unvec(values, rows, cols))
    basis = _span(deviation)  # (r, d)
    r = basis.shape[0]
    if r > MAX_BOX_DIMENSION:
        raise ModelError(
            f"the Jacobian varies in {r} independent directions over the domain (more than {MAX_BOX_DIMENSION}); "
            "give parameters= (the few functions of x and u it is affine in) or a smaller domain"
        )
    coords = deviation @ basis.T
    spread = coords.std(axis=0)
    if r >= 4:  # a box in the better of two coordinate systems: the SVD axes or r pivot entries
        normals, scale = _box_axes(basis, coords)
    else:
        normals = _directions(r, (basis * spread[:, None]).T)  # entry j's direction, whitened
        scale = 1.0 / spread
    functionals = (normals * scale) @ basis  # (d, a b): support values are functionals @ (M - mean)
    support = _supports(fun, functionals, mean, values, points, domain)
    extent = support + _supports_low(functionals, deviation)
    support = support + MARGIN * extent
    face_coords = normals * scale  # rows: normal in unwhitened span coordinates
    if r == 1:
        vertex_coords = np.array([[support[0] / face_coords[0, 0]], [-support[1] / abs(face_coords[1, 0])]])
    elif r >= 4:
        vertex_coords = _box_vertices(face_coords, support)
    else:
        halfspaces = np.hstack([face_coords, -support[:, None]])
        vertex_coords = scipy.spatial.HalfspaceIntersection(halfspaces, np.zeros(r)).intersections
    vertices = _unvec(mean + vertex_coords @ basis, rows, cols)
    return Cover(
        vertices,
        "sampled cover",
        False,
        r,
        f"{len(vertices)} vertices of a polytope with {len(normals)} faces around the Jacobians at {len(points)} "
        f"sampled points (affine span of dimension {r}; faces at the largest sampled or locally maximised value "
        f"+ {MARGIN:g} of the extent)",
        _unvec(values, rows, cols),
    )


def _box_axes(basis: FloatArray, coords: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Face normals (2r, r) and whitening (r,) of the smaller of the SVD box and the pivot-entry box."""
    r = basis.shape[0]
    svd_volume = float(np.prod(np.ptp(coords, axis=0)))
    _, _, pivots = scipy.linalg.qr(basis, pivoting=True)
    pivot = basis[:, pivots[:r]]  # entries = coords @ pivot, so coords = entries @ inv(pivot)
    pivot_volume = float(np.prod(np.ptp(coords @ pivot, axis=0)) / abs(np.linalg.det(pivot)))
    axes = np.eye(r) if svd_volume <= pivot_volume else pivot.T / np.linalg.norm(pivot.T, axis=1, keepdims=True)
    return np.vstack([axes, -axes]), np.ones(r)


def _box_vertices(face_coords: FloatArray, support: FloatArray) -> FloatArray:
    """Vertices of ``{c : n_i c <= b_i}`` for r pairs of opposite normals (a parallelotope)."""
    r = face_coords.shape[1]
    axes = face_coords[:r]
    corners = np.array(list(itertools.product(*[(-support[r + i], support[i]) for i in range(r)])))
    return np.linalg.solve(axes, corners.T).T


def _supports_low(functionals: FloatArray, deviation: FloatArray) -> FloatArray:
    """``-min`` of each functional over the samples (the extent's other side)."""
    return -(deviation @ functionals.T).min(axis=0)


def _supports(
    fun: ca.Function, functionals: FloatArray, mean: FloatArray, values: FloatArray, points: FloatArray, domain: Box
) -> FloatArray:
    """Largest value of each functional ``l @ (vec M(z) - mean)`` over the box: sampled, then L-BFGS-B."""
    sampled = (values - mean) @ functionals.T  # (m, d)
    z = ca.SX.sym("z", domain.size)
    expr = ca.mtimes(ca.DM(functionals), ca.vec(fun(z)) - ca.DM(mean))
    evaluate = ca.Function("supports", [z], [expr, ca.jacobian(expr, z)])
    bounds = list(zip(domain.lower, domain.upper, strict=True))
    best = sampled.max(axis=0)
    for j in range(functionals.shape[0]):

        def negative(zv: FloatArray, j: int = j) -> tuple[float, FloatArray]:
            value, grad = evaluate(zv)
            return -float(value[j]), -np.asarray(grad[j, :], dtype=float).ravel()

        start = points[int(np.argmax(sampled[:, j]))]
        result = scipy.optimize.minimize(negative, start, jac=True, method="L-BFGS-B", bounds=bounds,
                                         options={"maxiter": 50})  # fmt: skip
        best[j] = max(best[j], -float(result.fun))
    return best
