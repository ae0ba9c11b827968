r"""The two-stage MHE-based UISE with a reduced-order model (theo:stab, eq:op_MHE, eq:fullest_new).

Given a :class:`~uiest.reduction.ReducedModel` (``z = T(x) = (z_flat, z_sharp)``,
``z_flat = psi(y, z_sharp, v)``), each step k does two things.

**Stage 1: an MHE on the reduced model eq:sys_red** with past data only::

    z_sharp+ = f_sharp(z_sharp, gamma, u, v),   y = h_sharp(z_sharp, gamma, v),   gamma_j = y_j
    window at time k: nodes z_{k-N_k} .. z_k, data y_j, u_j, v_bar for j = k-N_k .. k-1, N_k = min(N, k)

    J = 2 mu^{N_k} |z_{k-N_k|k} - z_hat_{k-N_k}|_{P_z}^2
        + sum_{j=1}^{N_k} mu^j ( 2 |v_{k-j|k} - v_bar|_{R_v}^2
                                 + |y_{k-j} - h_sharp(z_{k-j|k}, y_{k-j}, v_{k-j|k})|_{R_y}^2 )

subject to ``z_{j+1|k} = f_sharp(z_{j|k}, y_j, u_j, v_{j|k})``, every node in ``z_bounds``
(a box containing the projection of T(X); the paper constrains ``z_{k|k}``),
``v_{j|k}`` in V and ``T^-1(psi(y_j, z_{j|k}, v_{j|k}), z_{j|k})`` in X for the nodes
``j = k-N_k .. k-1`` (``state_constraints=True``; the sides of X that are finite). This is
eq:cost_MHE with the quadratic constants of eq:p-eioss_quadratic:
``P_z = c_x diag(1 / z_scale^2)``, ``R_v = c_v diag(1 / v_scale^2)``,
``R_y = c_y diag(1 / y_scale^2)`` from a :class:`~uiest.detectability.ReducedIOSS` (see
:class:`~uiest.estimators.TwoStageWeights`). Prior rule eq:prior: ``z_hat_0 = T_sharp(x_bar_0)``
and ``z_hat_{k-N_k}`` is the MHE estimate delivered at that time.

**Stage 2: the full state** by eq:fullest with the projection of eq:fullest_new::

    x_hat_k = proj( T^-1( psi(y_k, z_hat_k, v_bar), z_hat_k ) )

Projections (``projection=``):

- ``"clip"`` (default): ``x_hat`` clipped to the box X. As a map on z this is
  ``z -> T(clip(T^-1(z)))``: identity on T(X), continuous, onto T(X), so the remark after
  theo:stab applies (the projection error vanishes with the noise). Cost: one clip (none when
  the point is in X).
- ``"exact"``: the Euclidean projection of eq:fullest_new in scaled z coordinates,
  ``argmin_{x in X} |S^-1 (T(x) - z)|^2`` (S: the widths of T(X) on a grid), solved by a small
  bounded least-squares problem (scipy ``least_squares``, nx unknowns) only when
  ``T^-1(z)`` leaves X; for a linear T the same as clipping only if T is diagonal.
- ``"none"``: eq:fullest unprojected (``x_hat`` may leave X under noise).

**Unknown input.** ``w_hat[k-1]`` is fitted to the consecutive estimates by
:class:`~uiest.estimators.input_fit.InputFit` (least squares ``f(x_hat[k-1], u[k-1], w) =
x_hat[k]``, scaled by ``1 / x_scale``; exact for f affine in w), delivered at step k.

**Missing measurements.** A missing channel of ``y_j`` drops its output residual (as in the
full-order estimators). But ``gamma_j = y_j`` also drives the reduced dynamics and eq:fullest, and
with w unknown nothing else determines ``z_flat_j``. The missing channels of ``gamma_j`` are
therefore filled with the output the estimator predicts at time j:
``h(x_pred_j, v_bar)`` with ``x_pred_j = T^-1(T_flat(f(x_hat_{j-1}, u_{j-1}, w_hat)), z_hat_j)``
(the full model with the last unknown-input estimate; ``x_bar_0`` at j = 0), and that filled
value is used in eq:fullest at time j and stored as the data ``gamma_j`` of later windows.
Outputs psi does not use (the crop's ``y^d``) thus change nothing but the dropped residual; for
outputs psi uses, ``x_hat_j`` and later windows carry the error of the unknown-input guess
(the UISE guarantee does not cover such steps). :attr:`StepEstimate.missing` records them.

**Special cases** (remark after theo:stab): ``n_sharp = 0`` needs no optimisation,
``x_hat_k = proj(T^-1(psi(y_k, v_bar)))`` (status ``"algebraic"``); ``n_flat = 0`` gives
``x_hat_k = proj(T^-1(z_hat_k))`` without using ``y_k``.

**Failures.** A failed window solve (after a cold retry) propagates the reduced model,
``z_hat_k = f_sharp(z_hat_{k-1}, gamma_{k-1}, u_{k-1}, v_bar)`` clipped to ``z_bounds`` (no
unknown input needed), status ``"propagated (<solver status>)"``; ``strict=True`` raises
:class:`~uiest.errors.SolverError` instead.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Mapping
from typing import Any, ClassVar

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike

from uiest.box import FloatArray
from uiest.errors import OptionError, SolverError
from uiest.estimators.base import WindowEstimator
from uiest.estimators.checks import boundary_flag, check_horizon, check_u_prev, check_y
from uiest.estimators.input_fit import InputFit
from uiest.estimators.projection import PROJECTIONS, Projection
from uiest.estimators.results import StepEstimate
from uiest.estimators.weights import ReducedCertificate, TwoStageWeights
from uiest.reduction import ReducedModel
from uiest.window import DEFAULT_BACKEND, WindowModel, WindowProblem, WindowWeights
from uiest.window.model import box_scale


def two_stage_window_weights(weights: TwoStageWeights, length: int) -> WindowWeights:
    """Residual weights of eq:cost_MHE for a window of ``length`` transitions (nodes 0..length-1 measured).

    Node ``i`` (time ``k - length + i``) has ``j = length - i``: output weight ``mu^j R_y``,
    noise weight ``2 mu^j R_v``; the prior weight is ``2 mu^length P_z``.
    """
    mu = weights.mu
    discounts = mu ** (length - np.arange(length, dtype=float))
    return WindowWeights(
        prior=2.0 * mu**length * weights.prior,
        y=discounts[:, None, None] * weights.R_y,
        v=2.0 * discounts[:, None, None] * weights.R_v,
    )


def reduced_window_model(reduced: ReducedModel, *, state_constraints: bool = True) -> WindowModel:
    """eq:sys_red as a :class:`~uiest.window.WindowModel`: state ``z_sharp``, node data ``gamma``, no w.

    With ``state_constraints`` the node constraint ``T^-1(psi(gamma, z, v), z) in X`` of eq:op_MHE.
    """
    s = reduced.system
    n = reduced.n_sharp
    z, u, w, v, d = (ca.SX.sym(name, size) for name, size in (("z", n), ("u", s.nu), ("w", 0), ("v", s.nv),
                                                              ("gamma", s.ny)))  # fmt: skip
    f = ca.Function("f_sharp", [z, u, w, v, d], [reduced.f_sharp(z, d, u, v)], ["x", "u", "w", "v", "d"], ["x_next"])
    h = ca.Function("h_sharp", [z, v, d], [reduced.h_sharp(z, d, v)], ["x", "v", "d"], ["y"])
    x_box = s.x.bounds
    has_x_side = bool(np.isfinite(x_box.lower).any() or np.isfinite(x_box.upper).any())
    node = None
    if state_constraints and has_x_side:
        x = reduced.T_inv(ca.vertcat(reduced.psi(d, z, v), z))
        node = ca.Function("x_of_node", [z, v, d], [x], ["x", "v", "d"], ["c"])
    return WindowModel(
        f=f,
        h=h,
        x_bounds=reduced.z_bounds,
        v_bounds=s.v.bounds,
        y_bounds=s.y.bounds,
        x_scale=box_scale(reduced.z_bounds),
        w_scale=np.ones(0),
        v_scale=s.v.scale,
        y_scale=s.y.scale,
        nominal_w=np.zeros(0),
        node_constraint=node,
        node_bounds=x_box if node is not None else None,
        node_scale=s.x.scale if node is not None else None,
        name=f"{s.name} (reduced)",
    )


class TwoStageUISE(WindowEstimator):
    r"""Two-stage MHE-based UISE (theo:stab): MHE eq:op_MHE on the reduced model, then eq:fullest_new.

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
        Gives ``mu, c_x, R_y, R_v`` and the default horizon ``min_horizon()`` (eq:N_cond).
    weights : TwoStageWeights, optional
        Explicit weights instead (e.g. :meth:`TwoStageWeights.from_scales`); then N is required
        and :attr:`guarantee` says theo:stab does not apply.
        Neither is needed (nor accepted) when ``n_sharp = 0``.
    N : int, optional
        Horizon >= 1; default ``certificate.min_horizon()``.
    x0_prior : array_like (nx,), optional
        Prior ``x_bar_0`` in X (or give it to :meth:`reset` / :meth:`run`).
    v_prior : array_like (nv,), optional
        Noise prior ``v_bar`` in V (default 0); used in the cost and in eq:fullest.
    projection : {"clip", "exact", "none"}
        The projection of eq:fullest_new.
    state_constraints : bool
        Impose ``T^-1(psi(y_j, z_j, v_j), z_j) in X`` at the window's nodes (eq:op_MHE).
    polish : bool
        Refine each window solution by Gauss-Newton steps solved by orthogonal factorisations
        (:mod:`uiest.window.polish`). Off by default, like the other estimators' default: on the
        crop model it takes the noise-free x^{d,1} error from ~5e-8 (ipopt) or ~2e-6 (gn) to
        ~2e-11, for ~2-4 ms per step; with noise it changes nothing visible.
    solver, solver_options, warm_start, strict
        As for :class:`~uiest.estimators.UISE`.

    """

    estimator_name = "TwoStageUISE"
    one_step_ahead: ClassVar[bool] = True

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
        polish: bool = False,
        solver: str = DEFAULT_BACKEND,
        solver_options: Mapping[str, Any] | None = None,
        warm_start: bool = True,
        strict: bool = False,
    ) -> None:
        if not isinstance(reduced, ReducedModel):
            raise OptionError(f"reduced: expected a uiest.reduction.ReducedModel, got {type(reduced).__name__}")
        self.reduced = reduced
        system = reduced.system
        self.z_scale = box_scale(reduced.z_bounds)
        self.certificate = certificate
        self.weights: TwoStageWeights | None = None
        if reduced.n_sharp == 0:
            if certificate is not None or weights is not None:
                raise OptionError(
                    "certificate, weights: n_sharp = 0, the estimate is algebraic (remark after theo:stab) and has "
                    "no cost to weight; pass neither"
                )
            N = 1 if N is None else N  # no window: N only bounds the (empty) history
        else:
            if (certificate is None) == (weights is None):
                raise OptionError("certificate, weights: expected exactly one of them")
            if weights is not None and not isinstance(weights, TwoStageWeights):
                raise OptionError(f"weights: expected a TwoStageWeights, got {type(weights).__name__}")
            resolved = TwoStageWeights.from_certificate(certificate) if certificate is not None else weights
            assert resolved is not None  # exactly one was given
            resolved.check(system, reduced.n_sharp)
            self.weights = resolved
            if N is None:
                if certificate is None:
                    raise OptionError("N: required with explicit weights (no certificate to take min_horizon() from)")
                N = certificate.min_horizon()
        check_horizon(N)
        self.state_constraints = bool(state_constraints)
        self.polish = bool(polish)
        self.window_model = reduced_window_model(reduced, state_constraints=self.state_constraints)
        self.projection = Projection(reduced, projection)
        self._fit = InputFit(system)
        x = ca.SX.sym("x", system.nx)
        self._T_split = ca.Function("T_split", [x], [reduced.T(x)[: reduced.n_flat], reduced.T(x)[reduced.n_flat :]])
        super().__init__(
            system,
            N=N,
            x0_prior=x0_prior,
            v_prior=v_prior,
            solver=solver,
            solver_options=solver_options,
            warm_start=warm_start,
            strict=strict,
        )

    # ------------------------------------------------------------------ hooks of the base class
    def _window_weights(self, length: int) -> WindowWeights:
        assert self.weights is not None  # only called when n_sharp > 0
        return two_stage_window_weights(self.weights, length)

    def _build_problem(self, length: int) -> WindowProblem:
        return WindowProblem(self.window_model, length, list(range(length)), self._window_weights(length))

    def _w_bar(self) -> FloatArray:
        return np.zeros(0)  # the reduced model has no unknown input

    def _w_guess(self) -> FloatArray:
        return np.zeros(0)

    def _clear(self) -> None:
        super()._clear()
        self.projection.used = 0
        self._gamma: deque[FloatArray] = deque(maxlen=self.N)
        self._w_full: FloatArray | None = None
        self.z_hat: FloatArray | None = None
        """The latest reduced-state estimate ``z_hat[k-1]`` (None before the first step)."""

    # ------------------------------------------------------------------ pieces
    def _split(self, x: FloatArray) -> tuple[FloatArray, FloatArray]:
        flat, sharp = self._T_split(x)
        return np.asarray(flat, dtype=float).reshape(-1), np.asarray(sharp, dtype=float).reshape(-1)

    def _full_state(self, gamma: FloatArray, z_sharp: FloatArray) -> FloatArray:
        """eq:fullest with ``v_bar`` (no projection)."""
        red = self.reduced
        z_flat = np.asarray(red.psi(gamma, z_sharp, self.v_prior), dtype=float).reshape(-1)
        return np.asarray(red.T_inv(np.concatenate([z_flat, z_sharp])), dtype=float).reshape(-1)

    def _fill(self, y: FloatArray, z_sharp: FloatArray, u_prev: FloatArray, k: int) -> FloatArray:
        """``y`` with missing channels replaced by the predicted output (module docstring)."""
        missing = np.isnan(y)
        if not missing.any():
            return y
        s = self.system
        if k == 0 or self._x_last is None:
            x_pred = self._x0_prior
        else:
            w = self._w_full if self._w_full is not None else s.nominal_w
            nxt = s.step(self._x_last, u_prev, w)
            x_pred = nxt if np.all(np.isfinite(nxt)) else self._x_last
        assert x_pred is not None
        z_flat, _ = self._split(x_pred)
        x_pred = np.asarray(self.reduced.T_inv(np.concatenate([z_flat, z_sharp])), dtype=float).reshape(-1)
        y_pred = s.output(s.x.bounds.clip(x_pred), self.v_prior)
        return np.where(missing, y_pred, y)

    # ------------------------------------------------------------------ one step
    def step(self, u_prev: ArrayLike | None, y: ArrayLike) -> StepEstimate:
        """Process ``u[k-1]`` and ``y[k]``; return the estimate of ``x[k]``.

        Parameters
        ----------
        u_prev : array_like (nu,) or None
            ``u[k-1]``; None at k = 0 (and when nu = 0).
        y : array_like (ny,)
            ``y[k]``; NaN entries are missing (see the module docstring).

        Returns
        -------
        StepEstimate

        """
        if self._x0_prior is None:
            raise OptionError("x0_prior: required; pass it to the constructor or call reset(x0_prior) first")
        s, red = self.system, self.reduced
        k = self._k
        u_vec = check_u_prev(s, u_prev, k)
        y_vec = check_y(s, y)
        iterations, solve_time, cost, success = 0, 0.0, 0.0, True
        solution, problem, length, start = None, None, 0, k
        if k == 0:
            z_hat = self._split(self._x0_prior)[1]  # eq:prior: z_hat_0 = T_sharp(x_bar_0)
            status = "prior"
        elif red.n_sharp == 0:
            z_hat = np.zeros(0)
            status = "algebraic"
        else:
            assert self.N is not None
            length = min(self.N, k)
            start = k - length
            stored_u = list(self._u)
            u_win = np.array([*stored_u[len(stored_u) - length + 1 :], u_vec], dtype=float).reshape(length, s.nu)
            y_win = np.array(list(self._y)[-length:], dtype=float).reshape(length, s.ny)
            gamma = np.array(list(self._gamma)[-length:], dtype=float).reshape(length, s.ny)
            data = np.vstack([gamma, np.zeros((1, s.ny))])  # node k carries no data (its y is not used)
            prior = self._priors[0]
            entry, attempts = self._solve_window(length, start, prior, u_win, y_win, data)
            problem, solution = entry.problem, attempts[-1]
            iterations = sum(a.iterations for a in attempts)
            solve_time = sum(a.solve_time for a in attempts)
            success = solution.success
            if success:
                z_hat = problem.unpack(solution.z).x[-1].copy()
                status, cost = solution.status, solution.cost
            else:
                if self.strict:
                    raise SolverError(
                        f"step k={k}: the reduced window problem ({length} transitions) was not solved: "
                        f"{' / '.join(a.status for a in attempts)}"
                    )
                assert self.z_hat is not None
                nxt = np.asarray(red.f_sharp(self.z_hat, self._gamma[-1], u_vec, self.v_prior), dtype=float)
                nxt = nxt.reshape(-1)
                z_hat = red.z_bounds.clip(nxt) if np.all(np.isfinite(nxt)) else self.z_hat.copy()
                status, cost = f"propagated ({solution.status})", float("nan")

        # stage 2: eq:fullest_new with the current measurement (missing channels predicted)
        gamma_k = self._fill(y_vec, z_hat, u_vec, k)
        x_hat = self.projection(self._full_state(gamma_k, z_hat))
        status += boundary_flag(s, x_hat, y_vec, self.v_prior)
        if solution is not None and solution.success and problem is not None:
            self._last = (start, problem, solution)
        w_hat, w_index = self._commit_two_stage(k, u_vec, y_vec, gamma_k, z_hat, x_hat)
        return StepEstimate(
            k=k,
            x_hat=x_hat,
            w_hat=w_hat,
            w_index=w_index,
            status=status,
            success=success,
            iterations=iterations,
            solve_time=solve_time,
            cost=cost,
            window=length,
            missing=np.isnan(y_vec),
        )

    def _commit_two_stage(
        self, k: int, u_vec: FloatArray, y_vec: FloatArray, gamma_k: FloatArray, z_hat: FloatArray, x_hat: FloatArray
    ) -> tuple[FloatArray | None, int | None]:
        """Fit ``w_hat[k-1]``, store step k and move to k + 1; returns (w_hat, its time index)."""
        w_hat, w_index = None, None
        if k > 0 and self._x_last is not None:
            guess = self._w_full if self._w_full is not None else self.system.nominal_w
            w_hat, w_index = self._fit(self._x_last, u_vec, x_hat, guess), k - 1
        if k > 0:
            self._u.append(u_vec)
        self._y.append(y_vec)
        self._gamma.append(gamma_k)
        self._priors.append(z_hat.copy())
        self._x_last = x_hat
        self.z_hat = z_hat
        if w_hat is not None:
            self._w_full = w_hat
        self._k = k + 1
        return w_hat, w_index

    def skip(self, u_prev: ArrayLike | None, y: ArrayLike, reason: str) -> StepEstimate:
        """Step k without solving: the full model propagates ``x_hat[k-1]`` (see :meth:`WindowEstimator.skip`)."""
        s, k = self.system, self._k
        u_vec = check_u_prev(s, u_prev, k)
        y_vec = check_y(s, y)
        if k == 0 or self._x_last is None:
            x_hat = self._x0_prior.copy()  # type: ignore[union-attr]
        else:
            w = self._w_full if self._w_full is not None else s.nominal_w
            nxt = s.step(self._x_last, u_vec, w)
            x_hat = s.x.bounds.clip(nxt) if np.all(np.isfinite(nxt)) else self._x_last.copy()
        z_hat = self._split(x_hat)[1]
        gamma_k = np.where(np.isnan(y_vec), s.output(x_hat, self.v_prior), y_vec)
        w_hat, w_index = self._commit_two_stage(k, u_vec, y_vec, gamma_k, z_hat, x_hat)
        return StepEstimate(k, x_hat, w_hat, w_index, f"propagated ({reason})", False, 0, 0.0, float("nan"), 0,
                            np.isnan(y_vec))  # fmt: skip

    # ------------------------------------------------------------------ guarantee
    @property
    def guaranteed(self) -> bool:
        """True for n_sharp = 0, or when a certified certificate gave the weights and ``N >= min_horizon()``."""
        return self.reduced.n_sharp == 0 or super().guaranteed

    @property
    def guarantee(self) -> str:
        """Which guarantee holds (theo:stab, or the remark after it for n_sharp = 0) or why none does."""
        proj = {
            "clip": "; the projection onto X adds an error that vanishes with the noise (eq:fullest_new)",
            "exact": "; the projection onto T(X) adds an error that vanishes with the noise (eq:fullest_new)",
            "none": "",
        }[self.projection.mode]
        if self.reduced.n_sharp == 0:
            return (
                "remark after theo:stab (n_sharp = 0): x_hat = T^-1(psi(y, v_bar)) is a UISE, its error bounded by "
                f"a Lipschitz constant times |v - v_bar|{proj}"
            )
        if self.certificate is None:
            return "none: explicit weights without a reduced i-IOSS certificate (ass:e-ioss), theo:stab does not apply"
        n_min = self.certificate.min_horizon()
        if self.N is not None and n_min > self.N:
            return f"none: N={self.N} < min_horizon()={n_min} (eq:N_cond), theo:stab does not apply"
        assert self.weights is not None
        return (
            f"theo:stab: the reduced model is exponentially i-IOSS with mu={self.weights.mu:.4g}, N={self.N} >= "
            f"min_horizon()={n_min}; the error converges under convergent noise whatever the unknown input{proj}"
        )

    def __repr__(self) -> str:
        mu = "none" if self.weights is None else f"{self.weights.mu:.4g}"
        return (
            f"TwoStageUISE(system={self.system.name!r}, n_flat={self.reduced.n_flat}, n_sharp={self.reduced.n_sharp}, "
            f"N={self.N}, mu={mu}, projection={self.projection.mode!r}, guaranteed={self.guaranteed})"
        )


__all__ = [
    "PROJECTIONS",
    "Projection",
    "TwoStageUISE",
    "reduced_window_model",
    "two_stage_window_weights",
]
