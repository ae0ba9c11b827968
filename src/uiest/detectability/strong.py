r"""Strong nonlinear detectability certificates (Theorem 3.2 of Guo et al.; see the theory map) with quadratic storage.

For ``x+ = f1(x, u) + B d`` (d free: w is unbounded), ``y = C x + g(v)`` the certificate is
:mod:`uiest.detectability.strong_lmi`'s::

    |dx+|_P^2 <= mu |dx|_P^2 + s1 |C dx|^2 + s2 |C dx+|^2      for every w, w~     (scaled)

at the vertices of a cover of the state Jacobian over X x U (:mod:`uiest.detectability.cover`).
With ``C dx = dy - (g(v) - g(v~))`` and ``|a - b|^2 <= 2 |a|^2 + 2 |b|^2`` it gives the paper's
Eq. (5b) with ``V = |x - x~|_P^2``, ``alpha_1 = lambda_min(P)``, ``alpha_2 = lambda_max(P)`` and::

    sigma_y(r) = sigma_y r^2,  sigma_y = 2 max(s1, s2),      sigma_v(r) = sigma_y ||D||^2 r^2
    (as solved; :meth:`StrongDetectability.with_output_weight` multiplies both)

(scaled norms; ``D`` the scaled ``dg/dv``). The per-step noise-to-error gain
``sqrt(2 sigma_v(d_max) / alpha_1)`` (d_max the largest noise increment in V) is reported per state.
"""

from __future__ import annotations

import dataclasses
import functools
import numbers
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import casadi as ca
import numpy as np
import scipy.linalg

from uiest.box import Box, FloatArray
from uiest.checks import check_samples, check_seed, shown
from uiest.detectability import cover as covers
from uiest.detectability import falsify, lmi
from uiest.detectability.certificate import (
    DEFAULT_MAX_CONDITION,
    UNDECIDED,
    StrongDetectabilityBase,
    Verification,
    check_rate,
    quad,
    sample_pairs,
    state_labels,
    verdict,
)
from uiest.detectability.cover import Cover
from uiest.detectability.strong_lmi import StrongLMI, StrongSolution
from uiest.detectability.structure import InputStructure, input_structure
from uiest.detectability.tradeoff import check_condition
from uiest.errors import ModelError, OptionError
from uiest.system import System, as_function
from uiest.theory import DECREASE_CONDITION

__all__ = ["StrongDetectability", "certify_strong_detectability", "worst_case_ratio"]


@dataclass(frozen=True, eq=False, kw_only=True)
class StrongDetectability(StrongDetectabilityBase):
    """A strong-detectability certificate (Theorem 3.2 of Guo et al.): ``V = |x - x~|_P^2``.

    Beyond :class:`~uiest.detectability.certificate.Certificate`:

    Attributes
    ----------
    sigma_y, sigma_v : float
        ``sigma_y(r) = sigma_y r^2`` on the scaled output increment, ``sigma_v(r) = sigma_v r^2``
        on the scaled noise increment (Eq. (5b)).
    R_y, R_v : ndarray
        The same as weight matrices in original units: ``sigma_y(dy) = |dy|_{R_y}^2``.
    noise_gain : ndarray (nx,)
        ``sqrt((sigma_v(d) + sigma_v(d)) / alpha_1)`` in state units, d the largest noise
        increment ``|v - v~|`` in V (its diameter): how far the noise terms of one step of
        Eq. (5b) can move the bound on each state (inf when V is unbounded).
    s1, s2, eps : float
        The core certificate's output weights on ``|C dx|^2``, ``|C dx+|^2`` (scaled) and the
        output scaling of the solve.
    n_vertices : int
        Vertices of the cover the LMI was imposed at.
    design : str
        Which solve produced P.
    output_weight : float
        How many times the certified output weights ``sigma_y``, ``sigma_v`` are (1 as solved; see
        :meth:`with_output_weight`).
    recertify : callable, optional
        ``recertify(max_condition=...)`` makes this certificate again with another bound on cond(P)
        (:meth:`tradeoff`); None when not made by :func:`certify_strong_detectability`.

    """

    system: System = field(repr=False)
    structure: InputStructure = field(repr=False)
    cover: Cover = field(repr=False)
    sigma_y: float
    sigma_v: float
    R_y: FloatArray
    R_v: FloatArray
    noise_gain: FloatArray
    s1: float
    s2: float
    eps: float
    n_vertices: int
    design: str
    output_weight: float = 1.0
    recertify: Callable[..., StrongDetectability] | None = field(default=None, repr=False, compare=False)

    kind = "strong_detectability"

    @property
    def output_gain(self) -> float:
        """``sigma_y / lambda_min(P)`` (scaled): the weight on outputs against the prior's."""
        return self.sigma_y / self.alpha_1_scaled

    def _state_labels(self) -> tuple[str, ...]:
        return state_labels(self.system.x.names, self.system.x.units)

    def with_output_weight(self, factor: float) -> StrongDetectability:
        """The weaker certificate with ``sigma_y``, ``sigma_v`` (and ``R_y``, ``R_v``) times ``factor >= 1``.

        Eq. (5b) still holds (only its right side grows), with the same mu and P, so the horizon
        and the guarantee stay; the estimator weighs its outputs ``factor`` times more against its
        prior, and the noise gain grows by ``sqrt(factor)``. ``s1``, ``s2`` stay the core solve's.
        :func:`~uiest.design.design_uise` tries a few factors.
        """
        self.require("with_output_weight")
        if not (isinstance(factor, numbers.Real) and not isinstance(factor, bool) and 1.0 <= factor < np.inf):
            raise OptionError(f"factor: expected a finite number >= 1, got {factor!r}")
        f = float(factor)
        return dataclasses.replace(self, sigma_y=f * self.sigma_y, sigma_v=f * self.sigma_v, R_y=f * self.R_y,
                                   R_v=f * self.R_v, noise_gain=np.sqrt(f) * self.noise_gain,
                                   output_weight=f * self.output_weight)  # fmt: skip

    @property
    def alpha_1(self) -> float:
        """``lambda_min(P)`` in original units."""
        return float(np.linalg.eigvalsh(self.P)[0]) if self.certified else float("nan")

    @property
    def alpha_2(self) -> float:
        """``lambda_max(P)`` in original units."""
        return float(np.linalg.eigvalsh(self.P)[-1]) if self.certified else float("nan")

    def _verify(self, n_pairs: int, seed: int) -> Verification:
        return _verify(self, n_pairs, seed)

    def _like_this(self, certificate: Any) -> Any:
        """The certificate with this one's output weight factor (:meth:`with_output_weight`)."""
        if self.output_weight == 1.0 or not certificate.certified:
            return certificate
        return certificate.with_output_weight(self.output_weight)

    def _details(self) -> dict[str, object]:
        ok = self.certified
        return {
            "system": self.system.name,
            "mu": self.mu,
            "mu_min": self.mu_min,
            "sigma_y": self.sigma_y,
            "sigma_v": self.sigma_v,
            "R_y": self.R_y.tolist() if ok else None,
            "R_v": self.R_v.tolist() if ok else None,
            "noise_gain": self.noise_gain.tolist(),
            "s1": self.s1,
            "s2": self.s2,
            "eps": self.eps,
            "rank_B": self.structure.rank_B,
            "rank_CB": self.structure.rank_CB,
            "input_structure": self.structure.evidence,
            "cover": self.cover.kind,
            "cover_sound": self.cover.sound,
            "n_vertices": self.n_vertices,
            "design": self.design,
            "output_weight": self.output_weight,
        }


def certify_strong_detectability(
    system: System,
    mu: float | None = None,
    *,
    parameters: Callable[[Any, Any], Any] | ca.Function | None = None,
    cover: str = "exact",
    samples: int = 4000,
    tol: float = 1e-4,
    seed: int = 0,
    max_condition: float = DEFAULT_MAX_CONDITION,
) -> StrongDetectability:
    """Certify strong nonlinear detectability of ``system`` (Theorem 3.2 of Guo et al.) by LMIs.

    Before a certificate is returned, :func:`uiest.detectability.falsify.search` looks for a pair
    of states that violates the LMI's inequality (worst unknown input in closed form); a pair found
    makes it "refuted". The search's size and worst ratio are in ``falsification``.

    Parameters
    ----------
    system : System
        Needs a bounded X, an output ``y = C x + g(v)`` and an unknown input through a constant
        input matrix (``x+ = f1(x, u) + B f2(w, x, u)``) with ``rank(C B) = rank(B)``.
    mu : float, optional
        Design rate in (0, 1). None: ``mu_min + 0.02 (1 - mu_min)``.
    parameters : callable or casadi.Function, optional
        ``theta(x, u)``: the few scalar functions of the state and known input that the state
        Jacobian ``df/dx`` is affine in (e.g. ``lambda x, u: [ca.sin(x[1]), x[0]]``), traced like
        :meth:`System.from_callables`, written as they appear in df/dx: every entry must be an exact
        combination of them (:mod:`uiest.detectability.cover`). The cover is then the box of theta,
        bounded by interval arithmetic. Without it, the box of a basis of the Jacobian's own
        entries ("exact by entries").
    cover : {"exact", "sampled"}
        "sampled" covers the Jacobians at samples only: the result is at best "holds at the samples,
        not proved", never ``certified``.
    samples : int
        Uniform samples of X x U for a sampled cover, and the points at whose Jacobians an LMI
        infeasible at the cover's vertices is re-checked (besides corners and a grid).
    tol : float
        Bisection tolerance on mu.
    seed : int
        Seed of the samples.
    max_condition : float
        Largest cond(P) (scaled coordinates, > 1) of the rate problem and the design
        (:data:`~uiest.detectability.certificate.DEFAULT_MAX_CONDITION`). A larger bound can buy a
        faster rate at the price of larger weights; :meth:`StrongDetectability.tradeoff` tabulates it.
        The estimator's horizon grows with cond(P): ``min_horizon() <= N`` when ``cond(P) < mu^-N / 8``.

    Returns
    -------
    StrongDetectability
        The certificate: its ``status`` (a :class:`~uiest.detectability.certificate.CertificateStatus`;
        ``certified`` only when proved on the whole domain), rate ``mu``, storage matrix ``P``, noise and
        output weights, and :meth:`~StrongDetectability.min_horizon`.

    Raises
    ------
    ModelError
        Unbounded X (or U where the Jacobian depends on u), a nonlinear output, a failed
        matching condition or an unknown input whose direction is not constant (with the ranks);
        parameters the Jacobian is not (provably) affine in; no exact cover possible (too many
        independent entries, an operation interval arithmetic cannot bound: the message says what
        to do).
    OptionError
        ``mu`` outside (0, 1), bad ``cover``, ``samples``, ``tol`` or ``max_condition``.

    Examples
    --------
    >>> from uiest.detectability import certify_strong_detectability
    >>> from uiest.models import closed_form
    >>> system = closed_form.system(x_bounds=((-100.0, -10.0), (100.0, 10.0)))
    >>> certificate = certify_strong_detectability(system)
    >>> certificate.status.value, certificate.certified, round(certificate.mu, 2)
    ('certified', True, 0.65)
    >>> certificate.min_horizon()  # the UISE's horizon condition (Eq. (13) of Guo et al.)
    30

    """
    start = time.perf_counter()
    if not isinstance(system, System):
        raise OptionError(f"system: expected a uiest.System, got {shown(system)}")
    mu = check_rate(mu, "mu")
    samples, seed = check_samples(samples, "samples", low=10), check_seed(seed)
    if not (isinstance(tol, float | int) and 0.0 < tol < 0.1):
        raise OptionError(f"tol: expected a number in (0, 0.1), got {tol!r}")
    kappa = check_condition(max_condition)
    if cover not in covers.METHODS:
        raise OptionError(f"cover: expected one of {covers.METHODS}, got {cover!r}")
    structure = input_structure(system, seed=seed)
    traced = None if parameters is None else as_function(parameters, "parameters", [("x", system.nx), ("u", system.nu)])
    theta = None if traced is None else _parameter_function(traced, system)
    recertify = functools.partial(certify_strong_detectability, system, parameters=traced, cover=cover,
                                  samples=samples, tol=tol, seed=seed)  # fmt: skip
    covered = covers.cover(structure.state_jacobian, structure.box, parameters=theta, method=cover, samples=samples,
                           seed=seed, names=structure.names)  # fmt: skip
    solution = StrongLMI(covered.vertices, structure.B, structure.C, kappa).solve(mu, tol=tol)
    if solution.outcome == lmi.INFEASIBLE and covered.kind != covers.CONSTANT:
        solution = _decided_at_samples(solution, covered, structure, mu, tol, kappa)
    found = _falsify(system, structure, covered, solution, seed) if solution.outcome == lmi.FEASIBLE else None
    certificate = _certificate(system, structure, covered, solution, found, time.perf_counter() - start)
    return dataclasses.replace(certificate, recertify=recertify)


def _decided_at_samples(
    solution: StrongSolution, covered: Cover, structure: InputStructure, mu: float | None, tol: float, kappa: float
) -> StrongSolution:
    """Infeasible at the cover's vertices: infeasible on X if also at the sampled Jacobians, else undecided.

    The vertices' hull holds the Jacobians and more (a box around them in four or more dimensions,
    interval bounds of the parameters), so that no P works at the vertices proves nothing by itself;
    that none works at the Jacobians of actual points of X does (the LMI must hold at each of them).
    """
    samples = covered.samples
    at_samples = StrongLMI(samples, structure.B, structure.C, kappa).solve(None, tol=tol)
    where = f"{len(samples)} sampled points of X"
    if at_samples.outcome == lmi.INFEASIBLE:
        return dataclasses.replace(solution, reason=f"{solution.reason}, at the Jacobians of {where} themselves")
    if at_samples.outcome == lmi.FEASIBLE and mu is not None and mu < at_samples.mu_min:
        return dataclasses.replace(solution, outcome="below mu_min", reason=(
            f"mu={mu:.6g} is below the smallest rate certifiable at the Jacobians of {where} themselves "
            f"({at_samples.mu_min:.6g}; at the cover's vertices none is)"))  # fmt: skip
    found = (f"feasible at the Jacobians of {where} themselves (mu_min {at_samples.mu_min:.6g} there)"
             if at_samples.outcome == lmi.FEASIBLE else
             f"the solver did not decide at the Jacobians of {where} themselves ({at_samples.outcome})")  # fmt: skip
    return dataclasses.replace(solution, outcome=UNDECIDED, reason=(
        f"{solution.reason} at the {len(covered.vertices)} vertices of the cover, whose hull holds more than the "
        f"Jacobians, but {found}: neither certified nor refuted; a tighter cover may certify (parameters=, a smaller "
        "X)"))  # fmt: skip


def _parameter_function(parameters: Any, system: System) -> ca.Function:
    """``z = (x, u) -> theta`` from a callable of (x, u) or a casadi.Function of (x, u)."""
    fun = as_function(parameters, "parameters", [("x", system.nx), ("u", system.nu)])
    z = ca.SX.sym("z", system.nx + system.nu)
    theta = fun(z[: system.nx], z[system.nx :])
    if theta.numel() == 0:
        raise ModelError("parameters: expected at least one function of x and u")
    return ca.Function("theta", [z], [theta])


def _falsify(
    system: System, structure: InputStructure, covered: Cover, solution: StrongSolution, seed: int
) -> falsify.Falsification:
    r"""The adversarial search on the LMI's inequality, scaled, with the worst unknown-input increment.

    ``max_dd |a + B dd|_P^2 - s2 |C (a + B dd)|^2 <= mu |dx|_P^2 + s1 |C dx|^2`` with
    ``a = S_x^-1 (f(x, u, w0) - f(x~, u, w0))``; the maximum over dd is ``a' Q a - g' H^-1 g`` with
    ``Q = P - s2 C'C``, ``H = B' Q B`` (negative definite when the LMI holds) and ``g = B' Q a``, evaluated at ``a``
    moved along B first (:func:`_without_seen_input`: the maximum is the same, the rounding far smaller).
    Close pairs step along ker C; anchors are the points where the cover's parameters reach their extremes.
    """
    nx, nu = system.nx, system.nu
    P, C, B = solution.P, structure.C, structure.B
    Q = P - solution.s2 * C.T @ C
    H = B.T @ Q @ B
    x, xt, u = ca.SX.sym("x", nx), ca.SX.sym("xt", nx), ca.SX.sym("u", nu)
    w0 = ca.DM(system.nominal_w)
    sx = system.x.scale
    a = _without_seen_input(((system.f(x, u, w0) - system.f(xt, u, w0)) / ca.DM(sx)).T, C, B).T
    dx = (x - xt) / ca.DM(sx)
    lhs = ca.bilin(ca.DM(Q), a, a)
    if B.shape[1]:
        if np.linalg.eigvalsh(0.5 * (H + H.T))[-1] >= 0.0:  # some unknown input makes the left side unbounded
            lhs = ca.SX.inf() * (1.0 + ca.sumsqr(dx))
        else:
            g = ca.mtimes(ca.DM(B.T @ Q), a)
            lhs = lhs - ca.bilin(ca.DM(np.linalg.inv(H)), g, g)
    rhs = solution.mu * ca.bilin(ca.DM(P), dx, dx) + solution.s1 * ca.sumsqr(ca.mtimes(ca.DM(C), dx))
    terms = ca.Function("strong_terms", [x, xt, u], [lhs, rhs])
    box = structure.box
    anchors = covered.extremes[:, :nx] if covered.extremes is not None else None
    U = Box(box.lower[nx:], box.upper[nx:])
    return falsify.search(terms, system.x.bounds, U, sx, directions=scipy.linalg.null_space(C), anchors=anchors,
                          labels=tuple(system.x.names) + tuple(system.u.names), seed=seed)  # fmt: skip


def _certificate(
    system: System,
    structure: InputStructure,
    covered: Cover,
    solution: StrongSolution,
    found: falsify.Falsification | None,
    seconds: float,
) -> StrongDetectability:
    unproved = "" if covered.sound else f"the cover is sampled ({covered.description})"
    certified, status, reason = verdict(solution.outcome, solution.reason, unproved=unproved, falsification=found)
    ok = solution.outcome == lmi.FEASIBLE
    sx, sy, sv = system.x.scale, system.y.scale, system.v.scale
    sigma_y = solution.sigma_y if ok else float("nan")
    sigma_v = sigma_y * structure.D_norm**2
    diameter = float(np.linalg.norm(system.v.bounds.width / sv)) if system.nv else 0.0  # largest |v - v~|
    alpha_1 = float(np.linalg.eigvalsh(solution.P)[0]) if ok else float("nan")
    gain = sx * np.sqrt(2.0 * sigma_v * diameter**2 / alpha_1) if ok else np.full(system.nx, np.nan)
    D = structure.D
    R_v_scaled = sigma_y * (D.T @ D if structure.noise_constant else structure.D_norm**2 * np.eye(system.nv))
    sound = covered.sound  # the input structure is proved (exact forms of df/dw)
    coverage = (
        f"{covered.kind} ({'sound' if covered.sound else 'sampled, not a proof'}): {covered.description}; "
        f"input structure {structure.evidence}"
    )
    return StrongDetectability(
        certified=certified,
        status=status,
        reason=reason,
        rate=solution.mu,
        rate_min=solution.mu_min,
        P_scaled=solution.P,
        scale=sx,
        solve_time=seconds,
        coverage=coverage,
        cover_kind=covered.kind,
        sound=sound,
        margin=solution.margin,
        system=system,
        structure=structure,
        cover=covered,
        sigma_y=float(sigma_y),
        sigma_v=float(sigma_v),
        R_y=sigma_y * np.diag(1.0 / sy**2),
        R_v=R_v_scaled / np.outer(sv, sv),
        noise_gain=np.asarray(gain, dtype=float),
        s1=solution.s1,
        s2=solution.s2,
        eps=solution.eps,
        n_vertices=len(covered.vertices),
        design=solution.design,
        falsification=found,
    )


def _verify(cert: StrongDetectability, n_pairs: int, seed: int) -> Verification:
    """Eq. (5b) on pairs of X (half close pairs along ker C), u in U, noise from V for half of them."""
    system, s = cert.system, cert.structure
    rng = np.random.default_rng(seed)
    sx, sy, sv = system.x.scale, system.y.scale, system.v.scale
    x, xt = sample_pairs(rng, system.x.bounds, n_pairs, sx, scipy.linalg.null_space(s.C))
    U = lmi.finite_box(system.u.bounds, system.u.bounds.center, system.u.scale)
    V = lmi.finite_box(system.v.bounds, system.v.bounds.center, sv)
    u = U.sample(rng, n_pairs)
    noisy = (np.arange(n_pairs) % 2 == 0)[:, None]
    v, vt, vp, vtp = (np.where(noisy, V.sample(rng, n_pairs), V.center) for _ in range(4))
    w0 = np.broadcast_to(system.nominal_w, (n_pairs, system.nw))
    dv2 = np.sum(((v - vt) / sv) ** 2, axis=1) + np.sum(((vp - vtp) / sv) ** 2, axis=1)
    leak = _input_leak(cert, x, u, rng)
    if leak > STRUCTURE_RTOL:
        return Verification(
            worst_ratio=float("inf"),
            pairs_used=n_pairs,
            pairs_drawn=n_pairs,
            note=f"the unknown input moves the state outside the span of "
            f"B by {leak:.2e} of its effect: the elimination does not hold",
        )
    return worst_case_ratio(
        a=(system.step(x, u, w0) - system.step(xt, u, w0)) / sx,
        dx=(x - xt) / sx,
        dy=(system.output(x, v) - system.output(xt, vt)) / sy,
        noise_next=(system.output(x, vp) - system.output(x, vtp)) / sy,
        dv2=dv2,
        P=cert.P_scaled,
        C=s.C,
        B=s.B,
        mu=cert.rate,
        sigma_y=cert.sigma_y,
        sigma_v=cert.sigma_v,
    )


STRUCTURE_RTOL = 1e-9
"""``verify`` fails when w moves the state outside the span of B by more than this fraction."""


def _input_leak(cert: StrongDetectability, x: FloatArray, u: FloatArray, rng: np.random.Generator) -> float:
    """How far w moves the state outside the span of B, relative to how far it moves it (w up to 1e9 scales).

    The largest ``|(I - B B^T) df| / |df|`` with ``df = f(x, u, w) - f(x, u, w0)`` (scaled), the
    rounding of the two evaluations (100 eps their size) discounted.
    """
    system, B = cert.system, cert.structure.B
    n, nw = x.shape[0], system.nw
    w = system.nominal_w + system.w.scale * 10.0 ** rng.uniform(0.0, 9.0, (n, nw)) * rng.choice([-1, 1], (n, nw))
    with np.errstate(all="ignore"):
        moved, nominal = system.step(x, u, w) / system.x.scale, system.step(x, u, system.nominal_w) / system.x.scale
    effect = moved - nominal
    keep = np.all(np.isfinite(effect), axis=1)
    rounding = 1e2 * np.finfo(float).eps * (np.linalg.norm(moved, axis=1) + np.linalg.norm(nominal, axis=1))
    excess = np.maximum(np.linalg.norm(effect - (effect @ B) @ B.T, axis=1) - rounding, 0.0)
    size = np.linalg.norm(effect, axis=1)
    keep &= size > 0
    return float((excess[keep] / size[keep]).max(initial=0.0))


def _without_seen_input(a: Any, C: FloatArray, B: FloatArray, noise: FloatArray | None = None) -> Any:
    """The increments ``a`` (rows) moved along B so that ``C a + noise`` loses its part in range(C B).

    The maximum over dd of ``|a + B dd|_P^2 - sigma |C (a + B dd) + noise|^2`` does not change when ``a`` moves
    along B, but evaluated as it is it subtracts two terms of order ``sigma |C a|^2`` (1e20 on a Henon map with a
    wide X, a sum of 1e6 left): rounding then refuted a certificate that holds. After the move the large part is
    gone and the sum is formed without it. ``a`` is an array (m, n) or an SX row.
    """
    if not B.shape[1]:
        return a
    move = np.linalg.pinv(C @ B).T @ B.T  # (p, n): from C a + noise to the move along B that cancels it best
    if isinstance(a, ca.SX):
        return a - ca.mtimes(ca.mtimes(a, ca.DM(C.T)), ca.DM(move))
    seen = a @ C.T if noise is None else a @ C.T + noise
    return a - seen @ move


def worst_case_ratio(
    *,
    a: FloatArray,
    dx: FloatArray,
    dy: FloatArray,
    noise_next: FloatArray,
    dv2: FloatArray,
    P: FloatArray,
    C: FloatArray,
    B: FloatArray,
    mu: float,
    sigma_y: float,
    sigma_v: float,
) -> Verification:
    """Largest ``LHS / RHS`` of Eq. (5b) over pairs, with the worst unknown-input increment.

    All scaled, per pair (rows): the drift increment ``a = f1(x) - f1(x~)`` (m, n), ``dx``,
    ``dy``, the noise part of ``dy+`` (m, p) and ``|dv|^2 + |dv+|^2`` (m,). With
    ``dx+ = a + B dd``, ``|dx+|_P^2 - sigma_y |C dx+ + noise_next|^2`` is a quadratic in dd; it
    is bounded above iff ``B^T (P - sigma_y C^T C) B < 0``, and then its maximum is closed-form (evaluated at ``a``
    moved along B, :func:`_without_seen_input`).
    """
    n_pairs = len(a)
    a = _without_seen_input(a, C, B, noise_next)
    value = quad(a, P) - sigma_y * np.sum((a @ C.T + noise_next) ** 2, axis=1)
    if B.shape[1]:
        H = B.T @ (P - sigma_y * C.T @ C) @ B
        if np.linalg.eigvalsh(0.5 * (H + H.T))[-1] >= 0.0:
            note = "unbounded: B'(P - sigma_y C'C)B is not negative definite, so some w violates it"
            return Verification(worst_ratio=float("inf"), pairs_used=n_pairs, pairs_drawn=n_pairs, note=note)
        g = a @ P @ B - sigma_y * (a @ C.T + noise_next) @ C @ B
        value = value - np.einsum("mi,ij,mj->m", g, np.linalg.inv(H), g)
    rhs = mu * quad(dx, P) + sigma_y * np.sum(dy**2, axis=1) + sigma_v * dv2
    used = rhs > 0.0
    return Verification(
        worst_ratio=float((value[used] / rhs[used]).max(initial=-np.inf)),
        pairs_used=int(used.sum()),
        pairs_drawn=n_pairs,
        note=f"ratio = LHS / RHS of {DECREASE_CONDITION} with the worst unknown-input increment (closed form)",
    )
