r"""Exponential i-IOSS of a reduced-order model (Assumption 4.7 and Eq. (27) of Guo et al.; see the theory map) by LMIs.

The reduced model Eq. (21) is ``z+ = f_sharp(z, gamma, u, v)``, ``y = h_sharp(z, gamma, v)``
with the fictitious input gamma (it lives in Y). With the dissipation inequality of
:mod:`uiest.detectability.dissipation` for ``V = |z - z~|_P^2`` (scaled coordinates, ``P >= I``)::

    V+ <= mu V + q_gamma |dgamma|^2 + q_v |dv|^2 + r |dy|^2,

summing ``V_k <= mu^k V_0 + sum_i mu^(k-1-i) (...)_i`` and ``lambda_min |dz|^2 <= V <= lambda_max |dz|^2``
gives Eq. (27) with::

    c_x = lambda_max(P) / lambda_min(P),   c_y = r / (mu lambda_min(P)),
    c_v = q_v / (mu lambda_min(P)),        c_gamma = q_gamma / (mu lambda_min(P)),

all in scaled norms ``|S^-1 .|``. The horizon condition Eq. (31) is ``N > -log_mu(4 c_x)``.
"""

from __future__ import annotations

import dataclasses
import functools
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import casadi as ca
import numpy as np

from uiest.box import Box, FloatArray
from uiest.detectability import dissipation
from uiest.detectability.certificate import DEFAULT_MAX_CONDITION, NOT_PROVED, MuCertificate, Verification
from uiest.detectability.interval import range_box
from uiest.detectability.lifted import LiftedDomain
from uiest.detectability.lmi import finite_box
from uiest.errors import ModelError

if TYPE_CHECKING:  # the reduction sits above the certificates: it is only read here
    from uiest.reduction import ReducedModel

__all__ = ["ReducedIOSS", "certify_reduced_ioss", "certify_reduced_model"]


@dataclass(frozen=True, eq=False, kw_only=True)
class ReducedIOSS(MuCertificate):
    """An exponential i-IOSS certificate of a reduced-order model (Assumption 4.7 of Guo et al.).

    Beyond :class:`~uiest.detectability.certificate.Certificate` (``rate`` is mu):

    Attributes
    ----------
    c_x, c_v, c_y, c_gamma : float
        The constants of Eq. (27) in scaled norms.
    R_v, R_y, R_gamma : ndarray
        ``c_v |dv|^2`` etc. as weight matrices in original units (``|dv|^2_{R_v}``): the weights of
        the two-stage MHE cost Eq. (28).
    q, r : ndarray, float
        The scaled weights of the dissipation inequality (channels gamma and v, and the output).
    recertify : callable, optional
        ``recertify(max_condition=...)`` makes this certificate again with another bound on cond(P)
        (:meth:`tradeoff`); None when not made by :func:`certify_reduced_ioss`.

    """

    model: dissipation.IncrementalModel = field(repr=False)
    q: FloatArray
    r: float
    recertify: Callable[..., ReducedIOSS] | None = field(default=None, repr=False, compare=False)

    kind = "reduced_eioss"

    @property
    def noise_gain(self) -> FloatArray:
        """Theorem 4.8's per-step noise gain per component of z, in z's units: ``2 sqrt(c_v) d z_scale``.

        d is V's scaled diameter: Eq. (33) bounds the error of z by ``sum_i lambda^i 2 sqrt(c_v) |v - v_bar|``
        (scaled norms). NaN when not certified.
        """
        if not self.certified:
            return np.full(len(self.scale), np.nan)
        return 2.0 * np.sqrt(self.c_v) * self.model.diameter("v") * self.scale

    @property
    def output_gain(self) -> float:
        """``r / lambda_min(P)`` (scaled): the weight on outputs against the storage's."""
        return self.r / self.alpha_1_scaled

    @property
    def c_x(self) -> float:
        """``lambda_max(P) / lambda_min(P)`` (scaled)."""
        return self.condition

    def _c(self, weight: float) -> float:
        return weight / (self.mu * self.alpha_1_scaled)

    @property
    def c_gamma(self) -> float:
        """Gain of the fictitious input (scaled norms)."""
        return self._c(float(self.q[0]))

    @property
    def c_v(self) -> float:
        """Gain of the measurement noise (scaled norms)."""
        return self._c(float(self.q[1]))

    @property
    def c_y(self) -> float:
        """Gain of the output (scaled norms)."""
        return self._c(self.r)

    def _matrix(self, c: float, scale: FloatArray) -> FloatArray:
        return c * np.diag(1.0 / scale**2)

    @property
    def R_gamma(self) -> FloatArray:
        """``c_gamma`` as a weight matrix in original units."""
        p = self.model.channels[0][1]
        return self._matrix(self.c_gamma, self.model.d_scale[:p])

    @property
    def R_v(self) -> FloatArray:
        """``c_v`` as a weight matrix in original units."""
        p = self.model.channels[0][1]
        return self._matrix(self.c_v, self.model.d_scale[p:])

    @property
    def R_y(self) -> FloatArray:
        """``c_y`` as a weight matrix in original units."""
        return self._matrix(self.c_y, self.model.y_scale)

    def _horizon(self) -> int:
        """Smallest N with ``N > -log_mu(4 c_x)`` (Eq. (31))."""
        return int(np.floor(np.log(4.0 * self.c_x) / np.log(1.0 / self.mu))) + 1

    def _verify(self, n_pairs: int, seed: int) -> Verification:
        """The one-step inequality of the module docstring on random pairs (nonlinear f, h)."""
        lam = self.alpha_1_scaled * self.mu
        weights = [self.R_gamma * lam, self.R_v * lam]
        check = dissipation.check_pairs(self.model, self.P, self.mu, weights, self.R_y * lam, n_pairs, seed)
        return Verification(
            worst_ratio=check.worst_ratio,
            pairs_used=check.pairs,
            pairs_drawn=check.drawn,
            note="ratio = LHS / RHS of V+ <= mu V + ...",
        )

    def _details(self) -> dict[str, object]:
        ok = self.certified
        return {
            "mu": self.mu,
            "mu_min": self.mu_min,
            "c_x": self.c_x if ok else None,
            "c_v": self.c_v if ok else None,
            "c_y": self.c_y if ok else None,
            "c_gamma": self.c_gamma if ok else None,
            "z_box": self.model.z_box.to_dict(),
            "domain": "the box" if self.model.lift is None else self.model.lift.description,
        }


def _scale(box: Box, given: Any, name: str) -> FloatArray:
    if given is not None:
        scale = np.broadcast_to(np.asarray(given, dtype=float), (box.size,)).copy()
        if not np.all(np.isfinite(scale) & (scale > 0)):
            raise ModelError(f"{name}: expected positive finite scales, got {scale.tolist()}")
        return scale
    width = box.width
    return np.where(np.isfinite(width) & (width > 0), width, 1.0)


def _finite(box: Box, name: str) -> Box:
    if not box.is_bounded:
        raise ModelError(f"{name}: expected a bounded box (the certificate grids it), got {box}")
    return box


def certify_reduced_ioss(
    f_sharp: ca.Function,
    h_sharp: ca.Function,
    *,
    z_bounds: Box | tuple[Any, Any],
    gamma_bounds: Box | tuple[Any, Any],
    v_bounds: Box | tuple[Any, Any],
    u_bounds: Box | tuple[Any, Any] | None = None,
    z_scale: Any = None,
    gamma_scale: Any = None,
    v_scale: Any = None,
    mu: float | None = None,
    max_condition: float = DEFAULT_MAX_CONDITION,
    lift: LiftedDomain | None = None,
    **options: Any,
) -> ReducedIOSS:
    """Certify exponential i-IOSS (Assumption 4.7 of Guo et al.) of a reduced-order model by LMIs.

    Parameters
    ----------
    f_sharp : casadi.Function
        ``(z (n,), gamma (p,), u (nu,), v (nv,)) -> z+ (n,)``.
    h_sharp : casadi.Function
        ``(z (n,), gamma (p,), v (nv,)) -> y (p,)``.
    z_bounds, gamma_bounds, v_bounds, u_bounds : Box or (lower, upper)
        Bounded domains of z (the projection of T(X)), gamma (Y), v (V) and u (U; None when
        ``nu = 0``).
    z_scale, gamma_scale, v_scale : array_like, optional
        Nominal magnitudes (default: the box widths). The output shares gamma's scale.
    mu : float, optional
        Discount to certify; None minimises it (``mu = min(2 mu_min, (1 + mu_min) / 2)``).
    max_condition : float
        Largest cond(P) in scaled coordinates (:data:`~uiest.detectability.certificate.DEFAULT_MAX_CONDITION`);
        a larger bound can buy a faster rate for larger weights (:meth:`ReducedIOSS.tradeoff`).
    lift : LiftedDomain, optional
        Certify only on the points ``(z, u, gamma, v)`` of the boxes that it maps into its box
        (:mod:`uiest.detectability.lifted`); None: on the whole product of the boxes.
    **options
        Passed to :func:`uiest.detectability.dissipation.solve` (parameters, cover, samples, tol, seed).

    """
    start = time.perf_counter()
    dissipation.check_options(options, "certify_reduced_ioss")
    for name, fun, n_in in (("f_sharp", f_sharp, 4), ("h_sharp", h_sharp, 3)):
        if not isinstance(fun, ca.Function) or fun.n_in() != n_in or fun.n_out() != 1:
            raise ModelError(f"{name}: expected a casadi.Function with {n_in} inputs and one output, got {fun!r}")
    n, p, nu, nv = (f_sharp.numel_in(i) for i in range(4))
    if f_sharp.numel_out(0) != n:
        raise ModelError(f"f_sharp: expected an output of size {n} (the size of z), got {f_sharp.numel_out(0)}")
    if (h_sharp.numel_in(0), h_sharp.numel_in(1), h_sharp.numel_in(2), h_sharp.numel_out(0)) != (n, p, nv, p):
        raise ModelError(
            f"h_sharp: expected inputs of sizes ({n}, {p}, {nv}) and an output of size {p}, got inputs "
            f"({h_sharp.numel_in(0)}, {h_sharp.numel_in(1)}, {h_sharp.numel_in(2)}), output {h_sharp.numel_out(0)}"
        )
    z_box = _finite(Box.coerce(z_bounds, n, "z_bounds"), "z_bounds")
    g_box = _finite(Box.coerce(gamma_bounds, p, "gamma_bounds"), "gamma_bounds")
    v_box = _finite(Box.coerce(v_bounds, nv, "v_bounds"), "v_bounds")
    u_box = _finite(Box.coerce(u_bounds, nu, "u_bounds"), "u_bounds") if nu else Box(np.zeros(0), np.zeros(0))
    g_scale = _scale(g_box, gamma_scale, "gamma_scale")
    if lift is not None and (
        lift.point.numel_in(0) != n + nu + p + nv
        or lift.step_jacobian.size_out(0) != (n, n + p + nv)
        or lift.output_jacobian.size_out(0) != (p, n + p + nv)
    ):
        raise ModelError(
            f"lift: expected a point map of (z, u, gamma, v) ({n + nu + p + nv} entries) and Jacobians of shapes "
            f"({n}, {n + p + nv}) and ({p}, {n + p + nv}), got {lift.point.numel_in(0)} entries, "
            f"{lift.step_jacobian.size_out(0)} and {lift.output_jacobian.size_out(0)}"
        )
    z, u, d = ca.SX.sym("z", n), ca.SX.sym("u", nu), ca.SX.sym("d", p + nv)
    model = dissipation.IncrementalModel(
        step=ca.Function("step", [z, u, d], [f_sharp(z, d[:p], u, d[p:])]),
        output=ca.Function("output", [z, d], [h_sharp(z, d[:p], d[p:])]),
        z_box=z_box,
        u_box=u_box,
        d_box=Box(np.concatenate([g_box.lower, v_box.lower]), np.concatenate([g_box.upper, v_box.upper])),
        z_scale=_scale(z_box, z_scale, "z_scale"),
        d_scale=np.concatenate([g_scale, _scale(v_box, v_scale, "v_scale")]),
        y_scale=g_scale,
        channels=(("gamma", p), ("v", nv)),
        lift=lift,
    )
    solution = dissipation.solve(model, mu=mu, max_condition=max_condition, **options)
    recertify = functools.partial(certify_reduced_ioss, f_sharp, h_sharp, z_bounds=z_box, gamma_bounds=g_box,
                                  v_bounds=v_box, u_bounds=u_box if nu else None, z_scale=model.z_scale,
                                  gamma_scale=g_scale, v_scale=model.d_scale[p:], lift=lift, **options)  # fmt: skip
    fields = solution.certificate_fields(model.z_scale, time.perf_counter() - start)
    if lift is not None:  # a certificate on part of the boxes says so
        fields["reason"] = f"{fields['reason']}; over {lift.description}"
        fields["coverage"] = f"{fields['coverage']}; over {lift.description}"
    return ReducedIOSS(**fields, model=model, q=solution.q, r=solution.r, recertify=recertify)


def certify_reduced_model(reduced: ReducedModel, **options: Any) -> ReducedIOSS:
    """:func:`certify_reduced_ioss` of a :class:`~uiest.reduction.ReducedModel` on its domain, in its ``z_scale``.

    gamma ranges over Y (``h(X, V)``, bounded by interval arithmetic), v over V, u over U. Where
    ``x(z_sharp, gamma, v) = T^-1(psi(gamma, z_sharp, v), z_sharp)`` is affine (a linear T and a psi affine in
    gamma and v, as in :func:`~uiest.reduction.reduce_quasi_state_affine` with the identity phi and an output
    affine in v), the certificate covers only the points of those boxes with x in X
    (:mod:`uiest.detectability.lifted`): the only points the two-stage UISE's theorem compares, and inside the model's
    domain although the boxes' product reaches beyond X. Elsewhere it covers the whole product. The reduced state is
    scaled by ``reduced.z_scale`` (from the state scales; T(X)'s widths only where they are smaller), as the
    two-stage UISE's window is: a wide X with small state scales costs no digits. Where T(X) or h(X, V) was bounded
    at a grid rather than proved, a certificate that holds there is returned as not proved (``status``
    :data:`~uiest.detectability.certificate.NOT_PROVED`, ``certified=False``, the reason naming the bound).

    Examples
    --------
    >>> from uiest.detectability import certify_reduced_model
    >>> from uiest.models import closed_form
    >>> cert = certify_reduced_model(closed_form.reduction())
    >>> cert.certified, cert.mu < 1
    (True, True)

    """
    system = reduced.system
    xv = ca.SX.sym("xv", system.nx + system.nv)
    h = ca.Function("h_xv", [xv], [system.h(xv[: system.nx], xv[system.nx :])])
    XV = Box(np.concatenate([system.x.bounds.lower, system.v.bounds.lower]),
             np.concatenate([system.x.bounds.upper, system.v.bounds.upper]))  # fmt: skip
    gamma_box, gamma_note = range_box(h, XV, "h(X, V)", int(options.get("seed", 0)))
    u_box = finite_box(system.u.bounds, system.u.bounds.center, system.u.scale)
    lift = options.pop("lift", None)  # a given cut, else the states in X where the map to them is affine
    lift = _reduced_domain(reduced, u_box) if lift is None else lift
    try:
        cert = certify_reduced_ioss(
            reduced.f_sharp,
            reduced.h_sharp,
            z_bounds=reduced.z_bounds,
            gamma_bounds=gamma_box,
            v_bounds=system.v.bounds,
            u_bounds=u_box if system.nu else None,
            z_scale=reduced.z_scale,
            gamma_scale=system.y.scale,
            v_scale=system.v.scale,
            lift=lift,
            **options,
        )
    except ModelError as exc:
        beyond = None if lift is not None else _beyond_x(reduced, gamma_box, int(options.get("seed", 0)))
        if beyond is None:
            raise
        raise ModelError(f"{exc}. {beyond}") from exc
    unproved = "; ".join(note for note in (reduced.z_bounds_note, gamma_note) if note)
    if not (unproved and cert.certified):
        return cert
    return dataclasses.replace(cert, certified=False, status=NOT_PROVED, sound=False,
                               reason=f"{NOT_PROVED}: {unproved}; {cert.reason}")  # fmt: skip


def _reduced_domain(reduced: ReducedModel, u_box: Box) -> LiftedDomain | None:
    """The points ``(z_sharp, u, gamma, v)`` with ``x = T^-1(psi(gamma, z_sharp, v), z_sharp)`` in X.

    None where that map is not affine in ``(z_sharp, gamma, v)`` (then the cut is not convex in general and
    the certificate keeps the whole box), where X is unbounded, or where the maps are not SX-expressible. The
    Jacobians are those of ``T_sharp(f(x, u, w_nominal))`` and ``h(x, v)`` composed with the map's constant
    Jacobian: the chain rule of ``f_sharp`` and ``h_sharp``'s own definition, so equal to theirs on the cut.
    """
    system = reduced.system
    if not system.x.bounds.is_bounded:
        return None
    n, ny, nu, nv = reduced.n_sharp, system.ny, system.nu, system.nv
    z, u, g, v, x = (ca.SX.sym(name, size) for name, size in (("z", n), ("u", nu), ("gamma", ny), ("v", nv),
                                                                ("x", system.nx)))  # fmt: skip
    try:
        x_of = reduced.T_inv(ca.vertcat(reduced.psi(g, z, v), z))
        step = reduced.T(system.f(x, u, ca.DM(system.nominal_w)))[reduced.n_flat :]
        output = system.h(x, v)
    except (NotImplementedError, RuntimeError, TypeError):  # MX maps: no exact forms to cover
        return None
    p = ca.vertcat(z, u, g, v)
    dx = ca.jacobian(x_of, ca.vertcat(z, g, v))
    if ca.depends_on(ca.vec(dx), p):
        return None
    picks_v = ca.horzcat(ca.SX.zeros(nv, n + ny), ca.SX.eye(nv))
    q = ca.vertcat(x, u, v)
    box = Box(np.concatenate([system.x.bounds.lower, u_box.lower, system.v.bounds.lower]),
              np.concatenate([system.x.bounds.upper, u_box.upper, system.v.bounds.upper]))  # fmt: skip
    return LiftedDomain(
        point=ca.Function("x_u_v", [p], [ca.vertcat(x_of, u, v)]),
        box=box,
        step_jacobian=ca.Function("dF", [q], [ca.jacobian(step, x) @ dx]),
        output_jacobian=ca.Function("dH", [q], [ca.jacobian(output, x) @ dx + ca.jacobian(output, v) @ picks_v]),
        description="the points with x = T^-1(psi(gamma, z_sharp, v), z_sharp) in X",
    )


def _beyond_x(reduced: ReducedModel, gamma_box: Box, seed: int) -> str | None:
    """Why a certificate kept on the whole box may meet an undefined model: the box's full states leave X.

    None where they stay in X (or cannot be bounded).
    """
    system = reduced.system
    n, ny, nv = reduced.n_sharp, system.ny, system.nv
    p = ca.SX.sym("p", n + ny + nv)
    try:
        x_of = reduced.T_inv(ca.vertcat(reduced.psi(p[n : n + ny], p[:n], p[n + ny :]), p[:n]))
        box = Box(np.concatenate([reduced.z_bounds.lower, gamma_box.lower, system.v.bounds.lower]),
                  np.concatenate([reduced.z_bounds.upper, gamma_box.upper, system.v.bounds.upper]))  # fmt: skip
        reach, _ = range_box(ca.Function("x_of", [p], [x_of]), box, "x(z_sharp, gamma, v)", seed)
    except (NotImplementedError, RuntimeError, TypeError, ModelError):
        return None
    X = system.x.bounds
    if np.all(reach.lower >= X.lower) and np.all(reach.upper <= X.upper):
        return None
    return (
        f"The reduced model's domain, z_sharp in {_text(reduced.z_bounds)}, gamma in {_text(gamma_box)}, v in "
        f"{_text(system.v.bounds)}, holds full states x = T^-1(psi(gamma, z_sharp, v), z_sharp) in {_text(reach)}, "
        f"beyond X = {_text(X)}, where f may be undefined; x(z_sharp, gamma, v) is not affine, so the certificate "
        "cannot be cut to the states in X. Give a reduction with a linear T and a psi affine in (gamma, v) (its "
        "certificate covers only the states in X), or an X whose reduced box keeps the full states where f is "
        "defined"
    )


def _text(box: Box) -> str:
    return " x ".join(f"[{lo:.4g}, {hi:.4g}]" for lo, hi in zip(box.lower, box.upper, strict=True))
