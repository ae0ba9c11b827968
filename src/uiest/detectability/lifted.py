r"""A certificate domain cut from a box by an affine map into another box, with its Jacobians over that box.

The dissipation certificates (:mod:`uiest.detectability.dissipation`) cover the Jacobians of a one-step
model over a box of points ``p = (z, u, d)``. A reduced-order model's box ``T_sharp(X) x U x Y x V`` holds
points whose full state ``x = T^-1(psi(gamma, z, v), z)`` lies outside X, where the model may be undefined
(``sqrt(h)`` with ``h < 0``) and where no trajectory the two-stage UISE compares goes: Theorem 4.8 applies the
i-IOSS inequality to the true trajectory (``x = x_k`` in X) and to the window's nodes, which Eq. (30)
constrains to X. A :class:`LiftedDomain` restricts the certificate to

::

    D = {p in the box : point(p) in Q},

with ``point`` affine and the Jacobians given as functions of ``q = point(p)`` over the box Q. This is sound:

- D is convex (a box intersected with the preimage of a box under an affine map), so the segment between two
  points of D stays in D, and every mean-value Jacobian of a pair in D is an average of Jacobians at points
  of D;
- at a point of D the Jacobian equals ``jacobian(point(p))`` with ``point(p)`` in Q, so a cover of the
  Jacobian over the box Q (the cover's usual domain) contains every Jacobian the pairs of D meet.

The falsification search and ``verify`` draw their pairs from the box until the pairs requested have both points
in D (or fifty times that many were drawn; :func:`~uiest.detectability.certificate.sample_admitted_pairs`) and score
only those (``Falsification.scored``, ``Verification.pairs_used`` count them, ``pairs``/``pairs_drawn`` count every
pair drawn): the certificate claims nothing outside.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from uiest.box import Box, FloatArray
from uiest.errors import ModelError

__all__ = ["LiftedDomain"]


@dataclass(frozen=True, eq=False)
class LiftedDomain:
    """``D = {p in box : point(p) in Q}`` and the Jacobians of the one-step model as functions of ``q = point(p)``.

    Attributes
    ----------
    point : casadi.Function
        ``p = (z (n,), u (nu,), d (nd,)) -> q (m,)``, affine in p (checked).
    box : Box
        Q, bounded (m,).
    step_jacobian : casadi.Function
        ``q -> dF/d(z, d)`` (n, n + nd) in original units, equal to the Jacobian of the step at every p of D.
    output_jacobian : casadi.Function
        ``q -> dH/d(z, d)`` (ny, n + nd) in original units, likewise.
    description : str
        What Q is, for the certificate's text (e.g. "x = T^-1(psi(gamma, z, v), z) in X").

    """

    point: ca.Function
    box: Box
    step_jacobian: ca.Function
    output_jacobian: ca.Function
    description: str

    def __post_init__(self) -> None:
        p = ca.SX.sym("p", self.point.numel_in(0))
        if ca.depends_on(ca.vec(ca.jacobian(self.point(p), p)), p):
            raise ModelError(f"point: expected a map affine in (z, u, d), got {self.point}")
        if not self.box.is_bounded:
            raise ModelError(f"box: expected a bounded box (the cover's domain), got {self.box}")

    def inside(self, p: FloatArray) -> np.ndarray:
        """Which rows of ``p`` (m, n + nu + nd) lie in D's cut (``point(p)`` in Q); shape (m,)."""
        q = np.asarray(self.point.map(len(p))(np.asarray(p, dtype=float).T), dtype=float).T
        return np.asarray(self.box.contains(q), dtype=bool)

    def admits(self, a: FloatArray, b: FloatArray, u: FloatArray, n: int) -> np.ndarray:
        """Which pairs have both points in D: rows ``a, b = (z (n,), d)`` with the shared ``u``; shape (m,)."""
        return self.inside(np.hstack([a[:, :n], u, a[:, n:]])) & self.inside(np.hstack([b[:, :n], u, b[:, n:]]))

    def indicator(self, p: ca.SX) -> ca.SX:
        """A symbolic 1/0: ``point(p)`` in Q."""
        q = self.point(p)
        inside = ca.SX(1)
        for i in range(self.box.size):
            inside = ca.logic_and(inside, ca.logic_and(q[i] >= self.box.lower[i], q[i] <= self.box.upper[i]))
        return inside
