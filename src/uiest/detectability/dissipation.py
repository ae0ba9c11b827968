r"""Quadratic incremental dissipation inequalities by LMIs: the engine of the i-IOSS certificates.

A one-step model ``z+ = F(z, u, d)``, ``y = H(z, d)`` with a known input ``u`` (equal in both
trajectories) and a disturbance ``d`` made of named channels ``d = (d_1, ..., d_c)``. In scaled
coordinates find ``P >= I`` with ``cond(P) <= max_condition``, channel weights ``q_c >= 0`` and an
output weight ``r >= 0`` with

::

    |F(z,u,d) - F(z~,u,d~)|_P^2 <= mu |z - z~|_P^2 + sum_c q_c |d_c - d~_c|^2 + r |H(z,d) - H(z~,d~)|^2.

With ``J = dF/d(z, d)`` and ``G = dH/d(z, d)`` the pointwise condition is

::

    M(J, G) = blkdiag(mu P, q_1 I, ..., q_c I) + r G^T G - J^T P J >= 0,

equivalent to the Schur form ``[blkdiag(mu P, q I) + r G^T G, J^T P; P J, P] >= 0`` of Schiller
et al.'s Corollary 3, eq. (33), which is affine in J: where it holds at the vertices of a cover
of J over the domain (:mod:`uiest.detectability.cover`) it holds at every mean-value Jacobian.
If G varies, ``r G^T G`` is not affine in G and the vertex argument covers J only: the
certificate says so.

:mod:`uiest.detectability.dissipation_lmi` solves it in stages: the rate on the states the output
does not see (where the weights drop out), a design at the chosen rate, the output weight in closed
form, and an independent numpy re-check at every vertex, which alone decides. The bound on cond(P)
is the price of the rate: a storage that contracts states seen only through a weak coupling needs a
large condition number, and the weights (the noise gain) grow with it
(:meth:`uiest.detectability.Certificate.tradeoff` tabulates it).
"""

from __future__ import annotations

import dataclasses
import inspect
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np

from uiest.box import Box, FloatArray
from uiest.checks import check_samples, check_seed
from uiest.detectability import cover as covers
from uiest.detectability import falsify, lmi
from uiest.detectability.certificate import (
    DEFAULT_MAX_CONDITION,
    UNDECIDED,
    check_rate,
    quad,
    sample_admitted_pairs,
    sample_pairs,
    verdict,
)
from uiest.detectability.cover import Cover
from uiest.detectability.dissipation_design import ROUNDING, Finished, design_and_check
from uiest.detectability.dissipation_lmi import Vertices
from uiest.detectability.dissipation_rate import RateStage
from uiest.detectability.lifted import LiftedDomain
from uiest.detectability.tradeoff import check_condition
from uiest.errors import OptionError

__all__ = ["DissipationSolution", "IncrementalModel", "PairCheck", "check_options", "check_pairs", "solve"]

STRUCTURES = ("full", "identity")


@dataclass(frozen=True, eq=False)
class IncrementalModel:
    """``z+ = step(z, u, d)``, ``y = output(z, d)`` with finite boxes and scales.

    Attributes
    ----------
    step : casadi.Function
        ``(z (n,), u (nu,), d (nd,)) -> z+ (n,)``.
    output : casadi.Function
        ``(z (n,), d (nd,)) -> y (p,)``.
    z_box, u_box, d_box : Box
        Finite boxes: the domain of the certificate.
    z_scale, d_scale, y_scale : ndarray
        Positive nominal magnitudes; the LMI is solved in ``z / z_scale`` etc.
    channels : tuple of (str, int)
        Names and sizes partitioning ``d``; each channel gets one scalar weight.
    lift : LiftedDomain, optional
        Restricts the domain to the points of the box that it maps into its box Q; the Jacobians are then covered
        over Q (:mod:`uiest.detectability.lifted`). None: the whole box.

    """

    step: ca.Function
    output: ca.Function
    z_box: Box
    u_box: Box
    d_box: Box
    z_scale: FloatArray
    d_scale: FloatArray
    y_scale: FloatArray
    channels: tuple[tuple[str, int], ...]
    lift: LiftedDomain | None = None

    @property
    def n(self) -> int:
        """State dimension."""
        return self.z_box.size

    @property
    def nd(self) -> int:
        """Disturbance dimension."""
        return self.d_box.size

    @property
    def domain(self) -> Box:
        """The product box ``Z x U x D``, columns ordered (z, u, d)."""
        return Box(
            np.concatenate([self.z_box.lower, self.u_box.lower, self.d_box.lower]),
            np.concatenate([self.z_box.upper, self.u_box.upper, self.d_box.upper]),
        )

    def diameter(self, channel: str) -> float:
        """The scaled diameter ``|width / scale|`` of a channel's box (the largest scaled increment in it)."""
        start = 0
        for name, size in self.channels:
            if name == channel:
                part = slice(start, start + size)
                return float(np.linalg.norm(self.d_box.width[part] / self.d_scale[part]))
            start += size
        raise KeyError(channel)

    def jacobians(self) -> tuple[ca.Function, ca.Function]:
        """Functions of ``p = (z, u, d)``: the scaled J (n, n + nd) and G (p, n + nd)."""
        n, nu = self.n, self.u_box.size
        point = ca.SX.sym("p", n + nu + self.nd)
        z, u, d = point[:n], point[n : n + nu], point[n + nu :]
        zd = ca.vertcat(z, d)
        col = np.concatenate([self.z_scale, self.d_scale])
        J = ca.diag(1.0 / self.z_scale) @ ca.jacobian(self.step(z, u, d), zd) @ ca.diag(col)
        G = ca.diag(1.0 / self.y_scale) @ ca.jacobian(self.output(z, d), zd) @ ca.diag(col)
        return ca.Function("J", [point], [J]), ca.Function("G", [point], [G])

    def covered_jacobians(self) -> tuple[ca.Function, ca.Function, Box]:
        """The scaled J and G as functions of the cover's variable, and that variable's box.

        ``(z, u, d)`` over :attr:`domain`, or ``q`` over the lift's Q.
        """
        if self.lift is None:
            return (*self.jacobians(), self.domain)
        q = ca.SX.sym("q", self.lift.box.size)
        col = ca.diag(np.concatenate([self.z_scale, self.d_scale]))
        J = ca.diag(1.0 / self.z_scale) @ self.lift.step_jacobian(q) @ col
        G = ca.diag(1.0 / self.y_scale) @ self.lift.output_jacobian(q) @ col
        return ca.Function("J", [q], [J]), ca.Function("G", [q], [G]), self.lift.box


@dataclass(frozen=True, eq=False, kw_only=True)
class DissipationSolution:
    """Outcome of :func:`solve`, in scaled coordinates.

    Attributes
    ----------
    outcome : str
        ``lmi.FEASIBLE`` (certified), ``lmi.INFEASIBLE``, ``lmi.FAILED``, "below mu_min" or
        "re-check failed".
    reason : str
        Why (not) certified, with the numbers.
    mu, mu_min : float
        Rate used and the smallest rate found by bisection.
    P : ndarray (n, n)
        Scaled storage matrix (``P >= I``); NaN when not solved.
    q : ndarray (c,)
        Scaled channel weights.
    r : float
        Scaled output weight.
    margin : float
        The re-check's smallest margin over the vertices (:class:`~uiest.detectability.dissipation_lmi.Recheck`).
    cover : Cover
        The vertices of J (and G).
    output_constant : bool
        Whether G is constant (else the vertex argument covers J only).
    max_condition : float
        The bound on cond(P) of the rate problem and the design.
    design : str
        Which solve produced P: "design" or the fallback's description ('' when not solved).
    falsification : Falsification or None
        The adversarial search on the solved inequality (None when not solved).

    """

    outcome: str
    reason: str
    mu: float
    mu_min: float
    P: FloatArray
    q: FloatArray
    r: float
    margin: float
    cover: Cover
    output_constant: bool
    max_condition: float
    design: str
    falsification: falsify.Falsification | None = None

    @property
    def coverage(self) -> str:
        """The cover's kind, soundness and how it was found."""
        sound = self.cover.sound and self.output_constant
        tail = "" if self.output_constant else "; the output Jacobian varies, so r G'G is a sampled check only"
        return f"{self.cover.kind} ({'sound' if sound else 'sampled, not a proof'}): {self.cover.description}{tail}"

    def certificate_fields(self, scale: FloatArray, seconds: float) -> dict[str, Any]:
        """The :class:`~uiest.detectability.certificate.Certificate` fields of this solution."""
        unproved = " and ".join(
            ([f"the cover is sampled ({self.cover.description})"] if not self.cover.sound else [])
            + (["the output Jacobian varies, so r G'G is checked at the vertices only"]
               if not self.output_constant else [])
        )  # fmt: skip
        certified, status, reason = verdict(self.outcome, self.reason, unproved=unproved,
                                            falsification=self.falsification)  # fmt: skip
        return {
            "certified": certified,
            "status": status,
            "reason": reason,
            "rate": self.mu,
            "rate_min": self.mu_min,
            "P_scaled": self.P,
            "scale": scale,
            "solve_time": seconds,
            "coverage": self.coverage,
            "cover_kind": self.cover.kind,
            "sound": self.cover.sound and self.output_constant,
            "margin": self.margin,
            "falsification": self.falsification,
        }


def check_options(options: dict[str, Any], caller: str) -> None:
    """OptionError naming any keyword :func:`solve` does not take (``structure`` and ``mu`` are the caller's)."""
    known = set(inspect.signature(solve).parameters) - {"model", "mu"}
    unknown = sorted(set(options) - known)
    if unknown:
        raise OptionError(f"{caller}: unknown options {unknown}; expected some of {sorted(known)}")
    if "samples" in options:
        check_samples(options["samples"], "samples", low=10)
    if "seed" in options:
        check_seed(options["seed"])
    if "cover" in options and options["cover"] not in covers.METHODS:
        raise OptionError(f"cover: expected one of {covers.METHODS}, got {options['cover']!r}")


def solve(
    model: IncrementalModel,
    *,
    mu: float | None,
    structure: str = "full",
    parameters: ca.Function | None = None,
    cover: str = "exact",
    samples: int = 4000,
    max_condition: float = DEFAULT_MAX_CONDITION,
    tol: float = 1e-4,
    seed: int = 0,
) -> DissipationSolution:
    """Find (P, q, r) of the module docstring; mu given or ``min(2 mu_min, (1 + mu_min) / 2)``.

    ``parameters`` is a function of ``(z, u, d)`` that J is affine in (a parameter box); else the
    exact cover by J's entries (:func:`uiest.detectability.cover.cover`); ``cover="sampled"``
    covers J at samples only (never certified). ``max_condition`` bounds cond(P) in the rate problem
    and in the design. A solved inequality is searched for violating pairs (:func:`falsify_solution`).
    """
    if structure not in STRUCTURES:
        raise OptionError(f"structure: expected one of {STRUCTURES}, got {structure!r}")
    mu = check_rate(mu, "mu")
    kappa = check_condition(max_condition)
    G_center, covered, output_constant, vertices = _covered_vertices(model, parameters, cover, samples, seed)
    n = model.n
    channels = tuple(size for _, size in model.channels)
    stage = RateStage(vertices, structure, kappa)
    nan = float("nan")

    def fail(outcome: str, reason: str, mu_min: float = nan) -> DissipationSolution:
        return DissipationSolution(
            outcome=outcome,
            reason=reason,
            mu=nan,
            mu_min=mu_min,
            P=np.full((n, n), nan),
            q=np.full(len(channels), nan),
            r=nan,
            margin=nan,
            cover=covered,
            output_constant=output_constant,
            max_condition=kappa,
            design="",
        )

    bisection = lmi.bisect_rate(stage.probe, tol=tol)
    notes = [bisection.note] if bisection.note else []
    if stage.inexact:
        notes.append(
            f"rate(s) {', '.join(f'{r:.6g}' for r in stage.inexact)} judged infeasible from solves to reduced accuracy"
        )
    note = f" ({'; '.join(notes)})" if notes else ""
    if bisection.rate is None:
        if bisection.outcome != lmi.INFEASIBLE:
            return fail(lmi.FAILED, f"the LMI solver failed at every rate tried; nothing was decided{note}")
        reason = (f"infeasible for every rate < 1: no quadratic storage with cond(P) <= {kappa:g} contracts the states "
                  f"the current output does not see")  # fmt: skip
        if covered.kind == covers.CONSTANT:
            return fail(lmi.INFEASIBLE, f"{reason}{note}")
        outcome, reason, mu_min = _decided_at_samples(covered, G_center, model, channels, structure, kappa, mu, tol,
                                                      output_constant, reason)  # fmt: skip
        return fail(outcome, f"{reason}{note}", mu_min)
    mu_min = bisection.rate
    mu_used = mu if mu is not None else min(2.0 * mu_min, 0.5 * (1.0 + mu_min))
    outcome = stage.settle(mu_used)
    if outcome == lmi.INFEASIBLE and mu_used < mu_min:
        return fail("below mu_min", f"mu={mu_used:.6g} is below the smallest certifiable rate mu_min={mu_min:.6g}"
                    f" with cond(P) <= {kappa:g}", mu_min)  # fmt: skip
    if outcome != lmi.FEASIBLE:  # above a feasible rate, 'infeasible' contradicts monotonicity: a failure
        return fail(lmi.FAILED, f"the solver failed in the rate problem at mu={mu_used:.6g} ('{outcome}'; "
                    f"mu_min={mu_min:.6g} was feasible){note}", mu_min)  # fmt: skip
    found = stage.storage(mu_used)
    if found is None:
        return fail(lmi.FAILED, f"no storage with cond(P) <= {kappa:g} found at mu={mu_used:.6g} to the solver's "
                    f"accuracy (mu_min={mu_min:.6g}){note}", mu_min)  # fmt: skip
    finished = design_and_check(vertices, *found, mu_used, kappa, structure)
    if finished is None:
        return fail(lmi.FAILED, f"no finite weights for the rate problem's storage at mu={mu_used:.6g} "
                    f"(mu_min={mu_min:.6g}){note}", mu_min)  # fmt: skip
    check = finished.check
    ok = check.passed
    solution = DissipationSolution(
        outcome=lmi.FEASIBLE if ok else "re-check failed",
        reason=_checked_reason(finished, mu_used, mu_min, kappa, note),
        mu=float(mu_used),
        mu_min=float(mu_min),
        P=finished.P,
        q=finished.q,
        r=float(finished.r),
        margin=check.margin,
        cover=covered,
        output_constant=output_constant,
        max_condition=kappa,
        design=finished.note,
    )
    return falsify_solution(model, solution, seed)


def _covered_vertices(
    model: IncrementalModel, parameters: ca.Function | None, cover: str, samples: int, seed: int
) -> tuple[FloatArray, Cover, bool, Vertices]:
    """The cover of J (and of G where the output map varies) and the LMI's vertices.

    Over the lift's Q where the model has one and no ``parameters`` (functions of ``(z, u, d)``) are given; over
    the box otherwise (which contains the lifted domain). Returns ``(G at the centre, cover, output_constant,
    vertices)``.
    """
    J_fun, G_fun, domain = model.covered_jacobians() if parameters is None else (*model.jacobians(), model.domain)
    point = ca.SX.sym("p", J_fun.numel_in(0))
    output_constant = not ca.depends_on(ca.vec(G_fun(point)), point)
    stacked = J_fun if output_constant else ca.Function("JG", [point], [ca.vertcat(J_fun(point), G_fun(point))])
    covered = covers.cover(stacked, domain, parameters=parameters, method=cover, samples=samples, seed=seed)
    n = model.n
    J = covered.vertices[:, :n, :]
    G_center = np.asarray(G_fun(domain.center), dtype=float)
    G = np.repeat(G_center[None], len(J), axis=0) if output_constant else covered.vertices[:, n:, :]
    channels = tuple(size for _, size in model.channels)
    return G_center, covered, output_constant, Vertices.build(J, G, channels, n)


def _checked_reason(finished: Finished, mu_used: float, mu_min: float, kappa: float, note: str) -> str:
    """The reason of a solution whose weights were designed: certified with its margins, or the failed re-check."""
    check = finished.check
    condition = float(np.linalg.cond(finished.P))
    source = "" if finished.note == "design" else f"; P from {finished.note}"
    if check.passed:
        return (
            f"certified: mu={mu_used:.6g} (mu_min={mu_min:.6g} with cond(P) <= {kappa:g}), cond(P) {condition:.3g}, "
            f"re-check margins: kernel {check.kernel.min():.2e}, output {check.schur.min():.2e}{note}{source}"
        )
    return (
        f"re-check failed at mu={mu_used:.6g}: kernel margin {check.kernel.min():.2e}, output margin "
        f"{check.schur.min():.2e}, direct {check.direct.min():.2e} (rounding {ROUNDING:.0e}){note}{source}"
    )


def falsify_solution(model: IncrementalModel, solution: DissipationSolution, seed: int) -> DissipationSolution:
    """``solution`` with the adversarial search (:func:`uiest.detectability.falsify.search`) on its inequality.

    Scaled, per pair ``(z, d), (z~, d~)`` and shared u: ``lhs = |F(z,u,d) - F(z~,u,d~)|_P^2`` against
    ``rhs = mu |z - z~|_P^2 + sum_c q_c |d_c - d~_c|^2 + r |H(z,d) - H(z~,d~)|^2``. Unsolved solutions
    are returned as they are. With a lift, the search draws pairs until enough lie in its domain, a point outside it
    scores NaN (the local searches), and the cover's extremes (points of Q, not of the box) are not used as anchors.
    """
    if solution.outcome != lmi.FEASIBLE:
        return solution
    n, nu, nd = model.n, model.u_box.size, model.nd
    a, b, u = ca.SX.sym("a", n + nd), ca.SX.sym("b", n + nd), ca.SX.sym("u", nu)
    z_scale, d_scale, y_scale = ca.DM(model.z_scale), ca.DM(model.d_scale), ca.DM(model.y_scale)
    dz_next = (model.step(a[:n], u, a[n:]) - model.step(b[:n], u, b[n:])) / z_scale
    dz, dd = (a[:n] - b[:n]) / z_scale, (a[n:] - b[n:]) / d_scale
    dy = (model.output(a[:n], a[n:]) - model.output(b[:n], b[n:])) / y_scale
    weights = np.repeat(solution.q, [size for _, size in model.channels]) if model.channels else np.zeros(0)
    P = ca.DM(solution.P)
    lhs = ca.bilin(P, dz_next, dz_next)
    if model.lift is not None:
        inside = ca.logic_and(model.lift.indicator(ca.vertcat(a[:n], u, a[n:])),
                              model.lift.indicator(ca.vertcat(b[:n], u, b[n:])))  # fmt: skip
        lhs = ca.if_else(inside, lhs, float("nan"))
    rhs = solution.mu * ca.bilin(P, dz, dz) + ca.dot(ca.DM(weights), dd * dd) + solution.r * ca.sumsqr(dy)
    joint = Box(np.concatenate([model.z_box.lower, model.d_box.lower]),
                np.concatenate([model.z_box.upper, model.d_box.upper]))  # fmt: skip
    extremes = solution.cover.extremes
    anchors = None
    if extremes is not None and model.lift is None:  # a lift's extremes are points of Q
        anchors = np.hstack([extremes[:, :n], extremes[:, n + nu :]])
    channels = tuple(f"{name}[{i}]" for name, size in model.channels for i in range(size))
    labels = tuple(f"z[{i}]" for i in range(n)) + channels + tuple(f"u[{i}]" for i in range(nu))
    lift = model.lift
    admit = None if lift is None else (lambda a, b, u: lift.admits(a, b, u, n))
    found = falsify.search(ca.Function("dissipation_terms", [a, b, u], [lhs, rhs]), joint, model.u_box,
                           np.concatenate([model.z_scale, model.d_scale]), anchors=anchors, labels=labels,
                           admit=admit, seed=seed)  # fmt: skip
    return dataclasses.replace(solution, falsification=found)


def _decided_at_samples(
    covered: Cover,
    G_center: FloatArray,
    model: IncrementalModel,
    channels: tuple[int, ...],
    structure: str,
    kappa: float,
    mu: float | None,
    tol: float,
    output_constant: bool,
    reason: str,
) -> tuple[str, str, float]:
    """Infeasible at the cover's vertices: infeasible if also at the sampled Jacobians themselves, else undecided.

    The vertices' hull holds the Jacobians and more (a box of the entries' bounds), so that no storage works
    at the vertices proves nothing by itself; that none works at the Jacobians of actual points of the domain
    does. Returns (outcome, reason, mu_min at the samples or NaN).
    """
    n = model.n
    J = covered.samples[:, :n, :]
    G = np.repeat(G_center[None], len(J), axis=0) if output_constant else covered.samples[:, n:, :]
    bisection = lmi.bisect_rate(RateStage(Vertices.build(J, G, channels, n), structure, kappa).probe, tol=tol)
    where = f"{len(J)} sampled points of the domain"
    if bisection.outcome == lmi.INFEASIBLE:
        return lmi.INFEASIBLE, f"{reason}, at the Jacobians of {where} themselves", float("nan")
    if bisection.rate is not None and mu is not None and mu < bisection.rate:
        return (
            "below mu_min",
            (
                f"mu={mu:.6g} is below the smallest rate certifiable at the Jacobians of {where} "
                f"themselves ({bisection.rate:.6g}; at the cover's vertices none is)"
            ),
            bisection.rate,
        )
    found = (
        f"feasible at the Jacobians of {where} themselves (mu_min {bisection.rate:.6g} there)"
        if bisection.rate is not None
        else f"the solver did not decide at the Jacobians of {where} themselves"
    )
    return UNDECIDED, (f"{reason} at the {len(covered.vertices)} vertices of the cover, whose hull holds more than the "
                       f"Jacobians, but {found}: neither certified nor refuted; a tighter cover may certify "
                       "(parameters=, a smaller domain)"), float("nan")  # fmt: skip


@dataclass(frozen=True, kw_only=True)
class PairCheck:
    """Worst ratio of the dissipation inequality over sampled pairs (see :func:`check_pairs`)."""

    worst_ratio: float
    pairs: int
    """The pairs scored."""
    drawn: int
    """The pairs drawn (more than requested where a lift admits only part of the box)."""


def check_pairs(
    model: IncrementalModel,
    P: FloatArray,
    mu: float,
    weights: Sequence[FloatArray],
    R: FloatArray,
    n_pairs: int,
    seed: int,
) -> PairCheck:
    """Test the inequality in original units on random pairs with the nonlinear F and H.

    ``weights[c]`` is the (size_c, size_c) weight matrix of channel c, ``R`` the output weight.
    Half of the pairs are close (see :func:`~uiest.detectability.certificate.sample_pairs`); with a lift, pairs
    are drawn until ``n_pairs`` have both points in its domain, half of them close
    (:func:`~uiest.detectability.certificate.sample_admitted_pairs`), and only those are scored (none: ``pairs == 0``,
    ratio NaN).
    """
    rng = np.random.default_rng(seed)
    n = model.n
    joint = Box(
        np.concatenate([model.z_box.lower, model.d_box.lower]), np.concatenate([model.z_box.upper, model.d_box.upper])
    )
    scale = np.concatenate([model.z_scale, model.d_scale])
    lift = model.lift
    if lift is None:
        a, b = sample_pairs(rng, joint, n_pairs, scale)
        u = model.u_box.sample(rng, n_pairs)
        drawn = n_pairs
    else:
        a, b, u, drawn = sample_admitted_pairs(rng, joint, model.u_box, n_pairs, scale,
                                               lambda a, b, u: lift.admits(a, b, u, n))  # fmt: skip
    if not len(a):  # no drawn pair lies in the lift's domain: nothing tested
        return PairCheck(worst_ratio=float("nan"), pairs=0, drawn=drawn)
    z, d, zt, dt = a[:, :n], a[:, n:], b[:, :n], b[:, n:]

    def run(fun: ca.Function, *cols: FloatArray) -> FloatArray:
        return np.asarray(fun.map(len(a))(*[c.T for c in cols]), dtype=float).T

    dz_next = run(model.step, z, u, d) - run(model.step, zt, u, dt)
    dy = run(model.output, z, d) - run(model.output, zt, dt)
    W = np.zeros((model.nd, model.nd))
    start = 0
    for (_, size), weight in zip(model.channels, weights, strict=True):
        W[start : start + size, start : start + size] = weight
        start += size
    lhs = quad(dz_next, P)
    rhs = mu * quad(z - zt, P) + quad(d - dt, W) + quad(dy, R)
    used = rhs > 0.0
    return PairCheck(worst_ratio=float((lhs[used] / rhs[used]).max(initial=-np.inf)), pairs=int(used.sum()),
                     drawn=drawn)  # fmt: skip
