r"""A cover of a matrix function by a polytope around its values at sampled points: evidence, not a proof.

Used only on request (``cover="sampled"``). M is sampled densely (corners, a grid, uniform
points); its varying entries span an affine space of small dimension r (SVD); in r <= 3 the
samples' convex hull is outer-approximated by a polytope with many face directions (evenly
spread ones plus the directions of each varying entry), each face pushed out to the largest value
found by sampling and local maximisation (L-BFGS-B) plus a margin of 1e-4 of the extent; in
r >= 4 a box. Its vertices cover every sampled and locally maximised point, not provably all of
the box: a narrow feature between the samples escapes it.
"""

from __future__ import annotations

import itertools

import casadi as ca
import numpy as np
import scipy.linalg
import scipy.optimize
import scipy.spatial

from uiest.box import Box, FloatArray
from uiest.errors import ModelError

__all__ = ["sampled_vertices"]

MARGIN = 1e-4
"""Faces of a sampled cover are pushed out by this fraction of the samples' extent."""

SPAN_RTOL = 1e-10
"""Directions of the sampled matrices below this fraction of their spread are dropped (rank)."""

MAX_BOX_DIMENSION = 10
"""Beyond this many independent directions a cover would need over 1024 vertices."""


def sampled_vertices(
    fun: ca.Function, values: FloatArray, points: FloatArray, domain: Box, rows: int, cols: int
) -> tuple[FloatArray, int, str]:
    """Vertices (m, rows, cols), the dimension r and a description of the polytope around ``values``.

    ``values`` (s, rows cols) are ``fun`` at ``points`` (s, n), flattened column-major.
    """
    mean = values.mean(axis=0)
    deviation = values - mean
    if np.abs(deviation).max() <= 1e-12 * max(1.0, float(np.abs(mean).max())):
        return _unvec(mean[None], rows, cols), 0, f"the matrix did not vary at {len(points)} sampled points"
    basis = _span(deviation)  # (r, d)
    r = basis.shape[0]
    if r > MAX_BOX_DIMENSION:
        raise ModelError(
            f"the Jacobian varies in {r} independent directions at the samples (more than {MAX_BOX_DIMENSION}); "
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
        try:
            vertex_coords = scipy.spatial.HalfspaceIntersection(halfspaces, np.zeros(r)).intersections
        except scipy.spatial.QhullError as exc:  # the samples' mean not strictly inside every face
            raise ModelError(
                f"cover: the sampled cover's polytope around the Jacobians at {len(points)} sampled points is "
                f"degenerate (qhull: {str(exc).splitlines()[0]}); use the exact cover (the default) or parameters="
            ) from None
    vertices = _unvec(mean + vertex_coords @ basis, rows, cols)
    description = (
        f"{len(vertices)} vertices of a polytope with {len(normals)} faces around the Jacobians at {len(points)} "
        f"sampled points (affine span of dimension {r}; faces at the largest sampled or locally maximised value "
        f"+ {MARGIN:g} of the extent)"
    )
    return vertices, r, description


def _unvec(flat: FloatArray, rows: int, cols: int) -> FloatArray:
    """Inverse of the column-major flattening: (m, a b) -> (m, a, b)."""
    return np.transpose(flat.reshape(-1, cols, rows), (0, 2, 1))


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
