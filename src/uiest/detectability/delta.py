r"""delta-IOSS Lyapunov functions for the standard MHE (Schiller et al. 2023, Assumption 1, Cor. 3).

Schiller, Muntwiler, Köhler, Zeilinger, Müller, "A Lyapunov function for robust stability of
moving horizon estimation", IEEE TAC 68(12), 2023. Their Assumption 1 (eq. (4)) asks for W with
``|x - x~|_P1^2 <= W <= |x - x~|_P2^2`` and

::

    W(f(x,u,w), f(x~,u,w~)) <= eta W(x, x~) + |d - d~|_Q^2 + |y - y~|_R^2,

the generalised disturbance ``d = (w, v)`` bounded (the standard MHE treats the unknown input as
a bounded disturbance in its known range ``system.w_range``). With ``W = |x - x~|_P^2``
(``P1 = P2 = P``) and ``Q = blkdiag(Q_w, Q_v)`` this is the dissipation LMI of Corollary 3,
eq. (33), solved by :mod:`uiest.detectability.dissipation` in scaled coordinates with one weight
per channel (``Q_w = q_w S_w^-2``, ``Q_v = q_v S_v^-2``, ``R = r S_y^-2``).

Horizon, their eq. (16): the MHE is robustly stable if ``4 eta^M lambda_max(P2, P1) < 1``; with
``P1 = P2`` the generalised eigenvalue is 1, so ``M > ln 4 / ln(1 / eta)``.
"""

from __future__ import annotations

import functools
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import casadi as ca
import numpy as np

from uiest.box import Box, FloatArray
from uiest.checks import check_real, shown
from uiest.detectability import dissipation, lmi
from uiest.detectability.certificate import DEFAULT_MAX_CONDITION, Certificate, Verification, check_rate, state_labels
from uiest.errors import ModelError, OptionError
from uiest.system import System

__all__ = ["DeltaIOSS", "certify_delta_ioss"]


@dataclass(frozen=True, eq=False, kw_only=True)
class DeltaIOSS(Certificate):
    """A quadratic delta-IOSS Lyapunov function (Schiller et al. 2023, Assumption 1).

    Beyond :class:`~uiest.detectability.certificate.Certificate` (``rate`` is eta):

    Attributes
    ----------
    Q_w, Q_v, R : ndarray
        Weights in original units (nw, nw), (nv, nv), (ny, ny) (properties).
    structure : str
        "full" or "identity" (``P = p I`` in scaled coordinates, the paper's "scaled identity").
    w_box : Box
        The range of w the certificate covers (``system.w_range`` unless given).
    q, r : ndarray, float
        The scaled weights of the dissipation inequality (channels w and v, and the output).
    recertify : callable, optional
        ``recertify(max_condition=...)`` makes this certificate again with another bound on cond(P)
        (:meth:`tradeoff`); None when not made by :func:`certify_delta_ioss`.

    """

    system: System = field(repr=False)
    model: dissipation.IncrementalModel = field(repr=False)
    q: FloatArray
    r: float
    structure: str
    w_box: Box
    recertify: Callable[..., DeltaIOSS] | None = field(default=None, repr=False, compare=False)

    kind = "delta_ioss"

    @property
    def noise_gain(self) -> FloatArray:
        """Per-step noise gain per state, in the state's units: ``2 sqrt(q_v d^2 / (eta lambda_min(P))) x_scale``.

        The form of Theorem 4.8's (Guo et al.) (:attr:`ReducedIOSS.noise_gain`) for Assumption 1's noise channel, d V's
        scaled diameter. NaN when not certified.
        """
        if not self.certified:
            return np.full(self.system.nx, np.nan)
        c_v = float(self.q[1]) / (self.eta * self.alpha_1_scaled)
        return 2.0 * np.sqrt(c_v) * self.model.diameter("v") * self.scale

    @property
    def output_gain(self) -> float:
        """``r / lambda_min(P)`` (scaled): the weight on outputs against the storage's."""
        return self.r / self.alpha_1_scaled

    def _state_labels(self) -> tuple[str, ...]:
        return state_labels(self.system.x.names, self.system.x.units)

    @property
    def eta(self) -> float:
        """Discount of Assumption 1."""
        return self.rate

    @property
    def eta_min(self) -> float:
        """Smallest feasible discount (bisection)."""
        return self.rate_min

    @property
    def Q_w(self) -> FloatArray:
        """Weight of the unknown input, original units."""
        return float(self.q[0]) * np.diag(1.0 / self.system.w.scale**2)

    @property
    def Q_v(self) -> FloatArray:
        """Weight of the measurement noise, original units."""
        return float(self.q[1]) * np.diag(1.0 / self.system.v.scale**2)

    @property
    def R(self) -> FloatArray:
        """Weight of the output, original units."""
        return self.r * np.diag(1.0 / self.system.y.scale**2)

    def _horizon(self) -> int:
        """Smallest M with ``4 eta^M lambda_max(P2, P1) < 1`` (Schiller et al., eq. (16)); ``P1 = P2``."""
        return int(np.floor(np.log(4.0) / np.log(1.0 / self.eta))) + 1

    def _verify(self, n_pairs: int, seed: int) -> Verification:
        """Assumption 1's inequality on random pairs in X x w_box x V with the nonlinear f and h."""
        check = dissipation.check_pairs(self.model, self.P, self.eta, [self.Q_w, self.Q_v], self.R, n_pairs, seed)
        return Verification(
            worst_ratio=check.worst_ratio,
            pairs_used=check.pairs,
            pairs_drawn=check.drawn,
            note="ratio = LHS / RHS of Schiller et al. eq. (4)",
        )

    def _details(self) -> dict[str, object]:
        ok = self.certified
        return {
            "system": self.system.name,
            "eta": self.eta,
            "eta_min": self.eta_min,
            "structure": self.structure,
            "Q_w": self.Q_w.tolist() if ok else None,
            "Q_v": self.Q_v.tolist() if ok else None,
            "R": self.R.tolist() if ok else None,
            "w_box": self.w_box.to_dict(),
        }


def certify_delta_ioss(
    system: System,
    eta: float | None = None,
    *,
    structure: str = "full",
    w_bounds: Box | tuple[Any, Any] | None = None,
    w_spread: float = 100.0,
    max_condition: float = DEFAULT_MAX_CONDITION,
    **options: Any,
) -> DeltaIOSS:
    """Certify Schiller et al.'s Assumption 1 with ``W = |x - x~|_P^2`` by their Corollary 3.

    Parameters
    ----------
    system : System
        Needs a bounded X. The output Jacobians should be constant (h affine, as Corollary 3
        requires); otherwise the certificate says the output term is a sampled check only.
    eta : float, optional
        Discount to certify; None minimises it (``eta = min(2 eta_min, (1 + eta_min) / 2)``).
    structure : {"full", "identity"}
        "identity" restricts P to ``p I`` in scaled coordinates, as the paper does.
    w_bounds : Box or (lower, upper), optional
        Range of w to cover; default ``system.w_range``, else ``nominal_w +- w_spread * w.scale``.
    w_spread : float
        Used only without ``w_bounds`` and ``system.w_range``.
    max_condition : float
        Largest cond(P) in scaled coordinates (:data:`~uiest.detectability.certificate.DEFAULT_MAX_CONDITION`);
        a larger bound can buy a smaller eta for larger weights (:meth:`DeltaIOSS.tradeoff`).
    **options
        Passed to :func:`uiest.detectability.dissipation.solve` (parameters, cover, samples, tol, seed).

    """
    start = time.perf_counter()
    if not isinstance(system, System):
        raise OptionError(f"system: expected a uiest.System, got {shown(system)}")
    dissipation.check_options(options, "certify_delta_ioss")
    eta = check_rate(eta, "eta")
    spread = check_real(w_spread, "w_spread", "a finite number > 0")
    if not (np.isfinite(spread) and spread > 0):
        raise OptionError(f"w_spread: expected a finite number > 0, got {w_spread!r}")
    if not system.x.bounds.is_bounded:
        raise ModelError(f"X: a certificate needs a bounded state domain, got {system.x.bounds}")
    if w_bounds is not None:
        w_box = Box.coerce(w_bounds, system.nw, "w_bounds")
    elif system.w_range is not None:
        w_box = system.w_range
    else:
        w_box = lmi.finite_box(Box.unbounded(system.nw), system.nominal_w, spread * system.w.scale)
    if not w_box.is_bounded:
        raise ModelError(f"w_bounds: a delta-IOSS certificate needs a bounded range of w, got {w_box}")
    v_box = lmi.finite_box(system.v.bounds, system.v.bounds.center, system.v.scale)
    u_box = lmi.finite_box(system.u.bounds, system.u.bounds.center, system.u.scale)
    nx, nu, nw, nv = system.nx, system.nu, system.nw, system.nv
    x, u, d = ca.SX.sym("x", nx), ca.SX.sym("u", nu), ca.SX.sym("d", nw + nv)
    model = dissipation.IncrementalModel(
        step=ca.Function("step", [x, u, d], [system.f(x, u, d[:nw])]),
        output=ca.Function("output", [x, d], [system.h(x, d[nw:])]),
        z_box=system.x.bounds,
        u_box=u_box,
        d_box=Box(np.concatenate([w_box.lower, v_box.lower]), np.concatenate([w_box.upper, v_box.upper])),
        z_scale=system.x.scale,
        d_scale=np.concatenate([system.w.scale, system.v.scale]),
        y_scale=system.y.scale,
        channels=(("w", nw), ("v", nv)),
    )
    solution = dissipation.solve(model, mu=eta, structure=structure, max_condition=max_condition, **options)
    recertify = functools.partial(certify_delta_ioss, system, structure=structure, w_bounds=w_box, **options)
    return DeltaIOSS(**solution.certificate_fields(system.x.scale, time.perf_counter() - start), system=system,
                     model=model, q=solution.q, r=solution.r, structure=structure, w_box=w_box,
                     recertify=recertify)  # fmt: skip
