r"""The two-stage MHE-based UISE with a reduced-order model (Theorem 4.8, Eq. (30), Eq. (35)).

Theorem and equation numbers are those of Guo et al. (see the theory map).

Given a :class:`~uiest.reduction.ReducedModel` (``z = T(x) = (z_flat, z_sharp)``,
``z_flat = psi(y, z_sharp, v)``), each step k does two things.

**Stage 1: an MHE on the reduced model Eq. (21)** with past data only::

    z_sharp+ = f_sharp(z_sharp, gamma, u, v),   y = h_sharp(z_sharp, gamma, v),   gamma_j = y_j
    window at time k: nodes z_{k-N_k} .. z_k, data y_j, u_j, v_bar for j = k-N_k .. k-1, N_k = min(N, k)

    J = 2 mu^{N_k} |z_{k-N_k|k} - z_hat_{k-N_k}|_{P_z}^2
        + sum_{j=1}^{N_k} mu^j ( 2 |v_{k-j|k} - v_bar|_{R_v}^2
                                 + |y_{k-j} - h_sharp(z_{k-j|k}, y_{k-j}, v_{k-j|k})|_{R_y}^2 )

subject to ``z_{j+1|k} = f_sharp(z_{j|k}, y_j, u_j, v_{j|k})``, every node in ``z_bounds``
(a box containing the projection of T(X); the paper constrains ``z_{k|k}``),
``v_{j|k}`` in V and ``T^-1(psi(y_j, z_{j|k}, v_{j|k}), z_{j|k})`` in X for the nodes
``j = k-N_k .. k-1`` (``state_constraints=True``; the sides of X that are finite). This is
Eq. (28) with the quadratic constants of Eq. (27):
``P_z = c_x diag(1 / z_scale^2)``, ``R_v = c_v diag(1 / v_scale^2)``,
``R_y = c_y diag(1 / y_scale^2)`` from a :class:`~uiest.detectability.ReducedIOSS` (see
:class:`~uiest.estimators.TwoStageWeights`). Prior rule Eq. (29): ``z_hat_0 = T_sharp(x_bar_0)``
and ``z_hat_{k-N_k}`` is the MHE estimate delivered at that time.

**Stage 2: the full state** by Eq. (26) with the projection of Eq. (35)::

    x_hat_k = proj( T^-1( psi(y_k, z_hat_k, v_bar), z_hat_k ) )

Projections (``projection=``):

- ``"clip"`` (default): ``x_hat`` clipped to the box X. As a map on z this is
  ``z -> T(clip(T^-1(z)))``: identity on T(X), continuous, onto T(X), so the remark after
  Theorem 4.8 applies (the projection error vanishes with the noise). Cost: one clip (none when
  the point is in X).
- ``"exact"``: the Euclidean projection of Eq. (35) in scaled z coordinates,
  ``argmin_{x in X} |S^-1 (T(x) - z)|^2`` (S: the widths of T(X) on a grid), solved by a small
  bounded least-squares problem (scipy ``least_squares``, nx unknowns) only when
  ``T^-1(z)`` leaves X; for a linear T the same as clipping only if T is diagonal.
- ``"none"``: Eq. (26) unprojected (``x_hat`` may leave X under noise).

**Unknown input.** ``w_hat[k-1]`` is fitted to the consecutive estimates by
:class:`~uiest.estimators.input_fit.InputFit` (least squares ``f(x_hat[k-1], u[k-1], w) =
x_hat[k]``, scaled by ``1 / x_scale``; exact for f affine in w), delivered at step k.

**Missing measurements.** A missing channel of ``y_j`` drops its output residual (as in the
full-order estimators). But ``gamma_j = y_j`` also drives the reduced dynamics and Eq. (26), and
with w unknown nothing else determines ``z_flat_j``. The missing channels of ``gamma_j`` are
therefore filled with the output the estimator predicts at time j:
``h(x_pred_j, v_bar)`` with ``x_pred_j = T^-1(T_flat(f(x_hat_{j-1}, u_{j-1}, w_hat)), z_hat_j)``
(the full model with the last unknown-input estimate; ``x_bar_0`` at j = 0), and that filled
value is used in Eq. (26) at time j and stored as the data ``gamma_j`` of later windows.
Outputs psi does not use (the crop's ``y^d``) thus change nothing but the dropped residual; for
outputs psi uses, ``x_hat_j`` and later windows carry the error of the unknown-input guess
(the UISE guarantee does not cover such steps). :attr:`StepEstimate.missing` records them.

**Special cases** (Remark 4.9): ``n_sharp = 0`` needs no optimisation,
``x_hat_k = proj(T^-1(psi(y_k, v_bar)))`` (outcome ``ALGEBRAIC``); ``n_flat = 0`` gives
``x_hat_k = proj(T^-1(z_hat_k))`` without using ``y_k``.

**Failures.** A failed window solve (after a cold retry) propagates the reduced model,
``z_hat_k = f_sharp(z_hat_{k-1}, gamma_{k-1}, u_{k-1}, v_bar)`` clipped to ``z_bounds`` (no
unknown input needed), outcome ``FAILED`` with the solver's status; ``strict=True`` raises
:class:`~uiest.errors.SolverError` instead.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Any

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike

from uiest.box import FloatArray
from uiest.checks import any_true, check_flag, check_int
from uiest.errors import OptionError
from uiest.estimators.base import WindowEstimator
from uiest.estimators.bounds import noise_quadratic, reduction_bound, two_stage_rate, two_stage_z_bound
from uiest.estimators.design_search import estimator_options, search_two_stage
from uiest.estimators.input_fit import InputFit
from uiest.estimators.projection import Projection
from uiest.estimators.weights import ReducedCertificate, TwoStageWeights, certificate_z_scale, resolve_weights
from uiest.guarantee import Guarantee
from uiest.reduction import ReducedModel
from uiest.scales import data_scales
from uiest.theory import ALGEBRAIC_TWO_STAGE, TWO_STAGE_GUARANTEE, TWO_STAGE_HORIZON
from uiest.window import WindowModel, WindowTrajectory
from uiest.window.buffered import BufferedFunction

__all__ = ["TwoStageUISE", "reduced_data_scales"]


def reduced_data_scales(reduced: ReducedModel, x0_prior: ArrayLike | None) -> ReducedModel:
    """``reduced`` with its system's scales from data (:func:`~uiest.scales.data_scales`); itself where none change."""
    system = data_scales(reduced.system, x0_prior)
    return reduced if system is reduced.system else dataclasses.replace(reduced, system=system)


class TwoStageUISE(WindowEstimator):
    r"""Two-stage MHE-based UISE (Theorem 4.8 of Guo et al.): MHE Eq. (30) on the reduced model, then Eq. (35).

    Index convention::

        x[k+1] = f(x[k], u[k], w[k]),  y[k] = h(x[k], v[k]),  z = T(x) = (z_flat, z_sharp),  N_k = min(N, k)
        z_hat[k]   = z^*_{k|k}  from  u[k-N_k .. k-1], y[k-N_k .. k-1]   (MHE, past data only)
        x_hat[k]   = proj(T^-1(psi(y[k], z_hat[k], v_bar), z_hat[k]))    (current measurement used here only)
        w_hat[k-1] = least-squares fit of f(x_hat[k-1], u[k-1], w) = x_hat[k]

    See the module docstring for the cost, constraints, projection, missing data and failures.

    Parameters
    ----------
    reduced : ReducedModel
        The system with its reduction (T, psi), e.g. ``crop_growth.reduction()``.
    certificate : ReducedIOSS, optional
        Gives ``mu, c_x, R_y, R_v`` and the default horizon ``min_horizon()`` (Eq. (31)).
    weights : TwoStageWeights, optional
        Explicit weights instead (e.g. :meth:`TwoStageWeights.from_scales`); then N is required
        and :attr:`guarantee` says Theorem 4.8 does not apply.
        Neither is needed (nor accepted) when ``n_sharp = 0``.
    N : int, optional
        Horizon >= 1; default ``certificate.min_horizon()``.
    x0_prior : array_like (nx,), optional
        Prior ``x_bar_0`` in X (or give it to :meth:`reset` / :meth:`run`).
    v_prior : array_like (nv,), optional
        Noise prior ``v_bar`` in V (default 0); used in the cost and in Eq. (26).
    projection : {"clip", "exact", "none"}
        The projection of Eq. (35).
    state_constraints : bool
        Impose ``T^-1(psi(y_j, z_j, v_j), z_j) in X`` at the window's nodes (Eq. (30)). A certificate from
        :func:`~uiest.detectability.certify_reduced_model` that covers only such points (its ``to_dict()["domain"]``)
        carries Theorem 4.8 only with them.
    **options
        As for :class:`~uiest.estimators.UISE`. ``polish=True`` refines each window solution where the data
        barely determine a direction (design notes: window solvers).

    """

    estimator_name = "TwoStageUISE"
    theorem = TWO_STAGE_GUARANTEE
    one_step_ahead = True

    def __init__(
        self,
        reduced: ReducedModel,
        *,
        certificate: ReducedCertificate | None = None,
        weights: TwoStageWeights | None = None,
        N: int | None = None,
        x0_prior: ArrayLike | None = None,
        v_prior: ArrayLike | None = None,
        projection: str = "clip",
        state_constraints: bool = True,
        **options: Any,
    ) -> None:
        if not isinstance(reduced, ReducedModel):
            raise OptionError(f"reduced: expected a uiest.reduction.ReducedModel, got {type(reduced).__name__}")
        reduced = reduced_data_scales(reduced, x0_prior)
        self.reduced = reduced
        self.design_report: Any = None
        """The :class:`~uiest.estimators.design_search.Design` when built by :meth:`design`, else None."""
        system = reduced.system
        self.weights: TwoStageWeights | None = None
        self.certificate = certificate
        if reduced.n_sharp == 0:
            if certificate is not None or weights is not None:
                raise OptionError(
                    f"certificate, weights: n_sharp = 0, the estimate is algebraic ({ALGEBRAIC_TWO_STAGE}) and has "
                    "no cost to weight; pass neither"
                )
            N = check_int(1 if N is None else N, "N", low=1)  # no window: N only bounds the (empty) history
        else:
            self.weights, self.certificate, N = resolve_weights(
                TwoStageWeights, certificate, weights, N, lambda w: w.check(system, reduced.n_sharp)
            )
        self.state_constraints = check_flag(state_constraints, "state_constraints")
        self.projection = Projection(reduced, projection)
        self._fit = InputFit(system)
        self._filled = self._filled_before = False  # this step's and the last step's outputs filled (_fill)
        g, zs, vs = ca.SX.sym("gamma", system.ny), ca.SX.sym("z_sharp", reduced.n_sharp), ca.SX.sym("v", system.nv)
        flat = reduced.psi(g, zs, vs)
        self._psi_uses = np.array([bool(ca.depends_on(flat, g[j])) for j in range(system.ny)], dtype=bool)
        """Which outputs psi uses: only their missing channels hold the input (module docstring)."""
        x = ca.SX.sym("x", system.nx)
        self._T_sharp = ca.Function("T_sharp", [x], [reduced.T(x)[reduced.n_flat :]])
        # Eq. (26) (before the projection) as one buffered call: T^-1(psi(gamma, z_sharp, v), z_sharp)
        gamma, v = ca.MX.sym("gamma", system.ny), ca.MX.sym("v", system.nv)
        z_sharp = ca.MX.sym("z_sharp", reduced.n_sharp)
        x_full = reduced.T_inv(ca.vertcat(reduced.psi(gamma, z_sharp, v), z_sharp))
        self._unreduce = BufferedFunction(ca.Function("unreduce", [gamma, z_sharp, v], [x_full]))
        super().__init__(system, WindowModel.from_reduced(reduced, state_constraints=self.state_constraints),
                         schedule=None if self.weights is None else self.weights.schedule(), N=N,
                         x0_prior=x0_prior, v_prior=v_prior, options=options)  # fmt: skip

    @classmethod
    def design(cls, reduced: ReducedModel, *, x0_prior: ArrayLike, **design_options: Any) -> TwoStageUISE:
        """A certified two-stage UISE whose mu and N are chosen for accuracy (:func:`uiest.design.design_two_stage`).

        As :meth:`UISE.design <uiest.estimators.UISE.design>`; the chosen design is :attr:`design_report`.
        """
        if not isinstance(reduced, ReducedModel):
            raise OptionError(f"reduced: expected a uiest.reduction.ReducedModel, got {type(reduced).__name__}")
        reduced = reduced_data_scales(reduced, x0_prior)
        design = search_two_stage(cls, reduced, x0_prior, **design_options)
        est = cls(reduced, certificate=design.certificate, N=design.ranked_horizon, x0_prior=x0_prior,
                  **estimator_options(design_options))  # fmt: skip
        est.design_report = design
        return est

    @property
    def z_hat(self) -> FloatArray | None:
        """The latest reduced-state estimate ``z_hat[k-1]`` (None before the first step)."""
        return self._node_last

    def _clear(self) -> None:
        super()._clear()
        self.projection.used = 0
        self._filled = self._filled_before = False

    # ------------------------------------------------------------------ hooks of the template
    def _node_of(self, x: FloatArray) -> FloatArray:
        """Eq. (29): ``z_hat_0 = T_sharp(x_bar_0)``."""
        return np.asarray(self._T_sharp(x), dtype=float).reshape(-1)

    def _node_state(self, window: WindowTrajectory, j: int, data: FloatArray) -> FloatArray:
        return self._full_state(window.x[j], data)

    def _full_state(self, node: FloatArray, data: FloatArray) -> FloatArray:
        """Eq. (35) with ``v_bar``: ``proj(T^-1(psi(gamma, z_sharp, v_bar), z_sharp))``."""
        (x,) = self._unreduce(data, node, self.v_prior)
        return self.projection(x.copy())

    def _to_state(
        self, node: FloatArray, y: FloatArray, u_prev: FloatArray, k: int, window: WindowTrajectory | None
    ) -> tuple[FloatArray, FloatArray]:
        gamma = self._fill(y, node, u_prev, k)
        return self._full_state(node, gamma), gamma

    def _w_estimate(
        self, window: WindowTrajectory | None, x_hat: FloatArray, u_prev: FloatArray, k: int
    ) -> tuple[FloatArray | None, int | None]:
        """:class:`InputFit` of ``w_hat[k-1]`` to ``x_hat[k-1]`` and ``x_hat[k]``; none after a filled step.

        ``x_hat[k-1]`` filled with the held input and ``x_hat[k]`` from the data: the fit would put the whole gap's
        drift into one step (5 times the input on a three-output model), so that step has no estimate (NaN).
        """
        if k == 0 or self._x_last is None or (self._filled_before and not self._filled):
            return None, None
        guess = self._w_last if self._w_last is not None else self.system.nominal_w
        return self._fit(self._x_last, u_prev, x_hat, guess), k - 1

    def _held_in_post_map(self) -> bool:
        return self._filled

    def _fill(self, y: FloatArray, z_sharp: FloatArray, u_prev: FloatArray, k: int) -> FloatArray:
        """``y`` with missing channels replaced by the predicted output (module docstring)."""
        missing = np.isnan(y)
        if not any_true(missing):  # every step's path: one test
            self._filled_before, self._filled = self._filled, False
            return y
        self._filled_before, self._filled = self._filled, any_true(missing & self._psi_uses)
        s, red = self.system, self.reduced
        x_pred = self._x0_prior if self._x_last is None else self._x_last
        assert x_pred is not None
        if k > 0 and self._x_last is not None:
            nxt = s.step(self._x_last, u_prev, self._w_last if self._w_last is not None else s.nominal_w)
            x_pred = nxt if np.all(np.isfinite(nxt)) else self._x_last
        z_flat = np.asarray(red.T(x_pred), dtype=float).reshape(-1)[: red.n_flat]
        x_pred = np.asarray(red.T_inv(np.concatenate([z_flat, z_sharp])), dtype=float).reshape(-1)
        return np.where(missing, s.output(s.x.bounds.clip(x_pred), self.v_prior), y)

    # ------------------------------------------------------------------ guarantee
    @property
    def guarantee(self) -> Guarantee:
        """Theorem 4.8's bound on ``z_sharp`` carried to each state through Eq. (26), or why it does not apply.

        :func:`~uiest.estimators.bounds.reduction_bound` with the Jacobians of
        ``x = T^-1(psi(gamma, z_sharp, v), z_sharp)``: states where they vary have no bound (NaN;
        the map's Lipschitz constant is not computed), and so has every state with the "exact"
        projection (non-expansive only in its own metric). Clipping to X never increases a
        state's error (the true state lies in X).
        """
        red, system = self.reduced, self.system
        if red.n_sharp == 0:
            theorem, c_x, rate, z_settled = ALGEBRAIC_TWO_STAGE, 1.0, 0.0, 0.0
            z_scale = np.zeros(0)
        else:
            theorem = self.theorem
            missing = self._horizon_missing("reduced e-IOSS", TWO_STAGE_HORIZON)
            lifted = getattr(getattr(self.certificate, "model", None), "lift", None) is not None
            if not missing and not self.state_constraints and lifted:
                missing = ("state_constraints=False: the certificate covers only nodes whose full state lies in X "
                           "(its domain), and the window's nodes are then not held there")  # fmt: skip
            if missing:
                return self._no_guarantee(theorem, missing)
            assert self.weights is not None and self.N is not None and self.certificate is not None
            c_x, mu = float(self.certificate.c_x), self.weights.mu
            noise = noise_quadratic(self.weights.R_v, system.v.bounds, self.v_prior)
            rate, z_settled = two_stage_rate(mu, c_x, self.N), two_stage_z_bound(mu, c_x, self.N, noise)
            scale = certificate_z_scale(self.certificate)
            assert scale is not None
            z_scale = scale
        J_z, J_v = self._map_gains
        bound, settling = reduction_bound(J_z, J_v, z_scale, red.z_bounds.width, system.v.bounds, self.v_prior, c_x,
                                          rate, z_settled)  # fmt: skip
        note = "x depends nonlinearly on (z_sharp, v) there; the map's Lipschitz constant is not computed"
        if self.projection.mode == "exact":
            bound = np.full(system.nx, np.nan)
            note = "the exact projection is non-expansive only in its own metric, not per state"
        mu_text = "" if self.weights is None else f"mu={self.weights.mu:.4g}, N={self.N}; "
        assumes = (
            f"{mu_text}noise in V around v_prior {np.round(self.v_prior, 12).tolist()}, the true state in X, every "
            f"output measured and every window problem solved to optimality, projection {self.projection.mode!r}; "
            "any unknown input"
        )
        return self._holds(theorem, bound, settling, assumes, note if not np.all(np.isfinite(bound)) else "")

    @functools.cached_property
    def _map_gains(self) -> tuple[FloatArray, FloatArray]:
        """Jacobians (nx, n_sharp), (nx, nv) of Eq. (26)'s ``x(gamma, z_sharp, v)``; NaN rows where they vary."""
        red, system = self.reduced, self.system
        symbols: list[Any]  # SX, or MX for MX maps: casadi's stubs type each, and no call takes the union
        symbols = [ca.SX.sym(name, n) for name, n in (("gamma", system.ny), ("z", red.n_sharp), ("v", system.nv))]
        try:
            x = red.T_inv(ca.vertcat(red.psi(*symbols), symbols[1]))
        except (NotImplementedError, RuntimeError, TypeError):  # MX maps: the same with MX symbols
            symbols = [ca.MX.sym(name, n) for name, n in (("gamma", system.ny), ("z", red.n_sharp), ("v", system.nv))]
            x = red.T_inv(ca.vertcat(red.psi(*symbols), symbols[1]))
        arguments = ca.vertcat(*symbols)
        J = ca.jacobian(x, ca.vertcat(symbols[1], symbols[2]))
        varying = np.array([ca.depends_on(J[i, :], arguments) for i in range(system.nx)], dtype=bool)
        value = np.asarray(ca.Function("dx", symbols, [J])(*(np.zeros(s.numel()) for s in symbols)), dtype=float)
        value = value.reshape(system.nx, red.n_sharp + system.nv)
        value[varying] = np.nan
        return value[:, : red.n_sharp], value[:, red.n_sharp :]

    def __repr__(self) -> str:
        mu = "none" if self.weights is None else f"{self.weights.mu:.4g}"
        return (
            f"TwoStageUISE(system={self.system.name!r}, n_flat={self.reduced.n_flat}, n_sharp={self.reduced.n_sharp}, "
            f"N={self.N}, mu={mu}, projection={self.projection.mode!r}, guarantee={str(self.guarantee)!r})"
        )
