r"""The practitioner's baselines: an EKF and a UKF with the unknown input as a random walk or an integrated one.

The state is augmented with the unknown input ``d`` (time-first, the UISE's index convention)::

    x[k+1] = f(x[k], u[k], d[k]) + e_x[k],   d[k+1] = d[k] + e_d[k],   y[k] = h(x[k], v[k])
    Cov(e_x) = Q_x (``x_variance``),  Cov(e_d) = Q_w (``w_variance``, the random walk's step variance),
    Cov(v) = Sigma_v (``v_covariance``; default: V's uniform variance width^2/12, or v's scale^2)

or, with ``input_model="integrated random walk"`` (:mod:`uiest.input_model`), with d and its rate r::

    d[k+1] = d[k] + r[k],   r[k+1] = r[k] + e_r[k],   Cov(e_r) = Q_w (``w_variance``)

Each step predicts ``z = (x, d)`` (or ``(x, d, r)``) with ``u[k-1]`` and updates it with ``y[k]``
(missing channels dropped), so ``x_hat[k]`` uses ``y[0..k]`` as the UISE does. The measurement noise
enters as ``R = D Sigma_v D^T`` with ``D = dh/dv`` at ``(x_hat, v_bar)``. ``w_hat[k-1]`` is the estimate
of ``d[k-1]``, the input that moved ``x[k-1]`` to ``x[k]``, from ``y[0..k]``: the noise of the input's step
after k-1 is independent of ``y[..k]``, so it is the input state's posterior mean at k carried back one step
(d's posterior mean for a random walk, ``d - r`` for an integrated one).

- :class:`EKF`: Jacobians from CasADi; ``P+ = F P F^T + Q``, Kalman update in Joseph form.
- :class:`UKF`: the unscented transform (Wan and van der Merwe's scaled sigma points, ``alpha``,
  ``beta``, ``kappa``) with additive noises; exact for linear models.

Where the model is not finite at the estimate or at a sigma point (a square root of a level below
zero, an exponential that overflows), the prediction or update is evaluated again with the state
parts projected onto X (the filter's "inside X" retry, ``StepEstimate.evaluated_inside``); only if
that fails too is the update skipped (outcome ``UPDATE_SKIPPED``) or the last estimate kept (``KEPT``).
An estimate outside X by more than X's width is ``DIVERGED`` (a failure).

Neither has a guarantee when the unknown input is unbounded or fast: a random walk (or an integrated one) is
the prior they assume. :meth:`KalmanFilter.fit` picks the input model, ``w_variance`` and a factor on the prior's
covariances by the likelihood of the innovations on the record itself (the prediction-error method,
:mod:`uiest.likelihood`, :mod:`uiest.filter_fit`); :meth:`KalmanFilter.tuned` picks ``w_variance`` by the state
error on a separate simulated record with its true states.
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike, NDArray

from uiest.box import FloatArray, as_vector
from uiest.checks import check_real
from uiest.covariance import as_covariance, noise_variance, prior_variance
from uiest.errors import DataError, OptionError
from uiest.estimators.base import StreamingEstimator, collect_run
from uiest.filter_fit import FilterFit, check_models, check_prior_factors, fit_filter
from uiest.guarantee import Guarantee
from uiest.health import Outcome, at_bound, quiet_bound_warnings
from uiest.input_model import InputModel
from uiest.likelihood import (
    GRID_EXTENSION,
    LikelihoodProfile,
    ProfileShape,
    Score,
    check_grid,
    innovation_log_density,
)
from uiest.results import EstimationResult, StepEstimate, Trajectory
from uiest.run_data import check_run_data, check_u_prev, check_y
from uiest.system import System
from uiest.window.buffered import BufferedFunction

EDGE_GAIN = 1.01
"""``tuned`` warns about an end of its grid only when the neighbour's RMS is above this times the end's (below it
the error is flat there, and an end of the grid is as good as beyond it)."""
INSIDE_MARGIN = 1e-6
"""The inside-X retry evaluates the model this fraction of X's width (x's scale on a half-open axis) inside its
finite sides (a square root or a logarithm at a side has an infinite derivative there)."""


@dataclass(frozen=True, kw_only=True)
class Tuning:
    """What :meth:`KalmanFilter.tuned` tried (``w_variance = factor * w.scale^2``).

    ``rms`` is the scaled state RMS (inf for a filter that diverged: an estimate beyond X by more than
    its width, or not finite), ``failed`` the failed steps, ``diverged`` the diverged steps of each.
    """

    factors: FloatArray
    rms: FloatArray
    failed: NDArray[np.int_] | None = None
    diverged: NDArray[np.int_] | None = None

    @property
    def chosen(self) -> float:
        """The factor with the smallest error."""
        return float(self.factors[int(np.nanargmin(self.rms))])


class KalmanFilter(StreamingEstimator):
    """What the EKF and the UKF share: the augmented model, noises, the step loop (module docstring).

    Parameters
    ----------
    system : System
    w_variance : float or array_like (nw,) or (nw, nw)
        Covariance of the random walk's step ``e_d`` (scalars broadcast).
    x_variance : float or array_like, optional
        Covariance of the state noise ``e_x`` (default 0).
    v_covariance : array_like, optional
        Covariance of v (default: ``width^2 / 12`` over V's finite sides, ``scale^2`` elsewhere).
    x0_prior : array_like (nx,), optional
        Mean of x[0] (or give it to :meth:`reset` / :meth:`run`).
    P0 : array_like, optional
        Covariance of x[0] (default ``diag(x.scale^2 / 12)``: uniform over a box one scale wide).
    w0, W0 : array_like, optional
        Mean and covariance of d[0] (default: the nominal w and ``diag(w.scale^2)``).
    input_model : InputModel or str, optional
        The unknown input's model (:class:`~uiest.input_model.InputModel`): ``"random walk"`` (default) or
        ``"integrated random walk"`` (the state then carries d and its rate r; ``w_variance`` is the rate's step
        variance).
    W0_rate : array_like, optional
        Covariance of r[0], whose mean is 0 (integrated random walk only; default ``W0``).

    """

    N = None
    theorem = "no theorem (Kalman filter, random-walk unknown input)"
    v_prior: FloatArray
    tuning: Tuning | None = None
    """The tuning record when built by :meth:`tuned`, else None."""
    likelihood: LikelihoodProfile | None = None
    """The chosen model's variance profile when built by :meth:`fit`, else None."""
    filter_fit: FilterFit | None = None
    """Every input model's likelihood profiles when built by :meth:`fit`, else None."""

    def __init__(
        self,
        system: System,
        *,
        w_variance: ArrayLike,
        x_variance: ArrayLike | None = None,
        v_covariance: ArrayLike | None = None,
        x0_prior: ArrayLike | None = None,
        P0: ArrayLike | None = None,
        w0: ArrayLike | None = None,
        W0: ArrayLike | None = None,
        input_model: InputModel | str = InputModel.RANDOM_WALK,
        W0_rate: ArrayLike | None = None,
    ) -> None:
        if not isinstance(system, System):
            raise OptionError(f"system: expected a uiest.System, got {type(system).__name__}")
        self.system = s = system
        V = s.v.bounds
        self.v_prior = np.where(np.isfinite(V.center), V.center, 0.0)
        self.input_model = _input_model(input_model)
        n = s.nx + self.input_model.order * s.nw
        self._A_in = self.input_model.transition(s.nw)
        self._back = np.linalg.inv(self._A_in)[: s.nw]  # the input state at k -> the estimate of d[k-1]
        self.Q = np.zeros((n, n))
        self.Q[: s.nx, : s.nx] = as_covariance(x_variance, s.nx, np.zeros(s.nx), "x_variance")
        self.Q[s.nx :, s.nx :] = self.input_model.noise(as_covariance(w_variance, s.nw, np.zeros(s.nw), "w_variance"))
        self.Sigma_v = as_covariance(v_covariance, s.nv, noise_variance(s), "v_covariance")
        self.P0 = as_covariance(P0, s.nx, prior_variance(s), "P0")
        self.w0 = s.nominal_w if w0 is None else as_vector(w0, s.nw, "w0")
        self.W0 = as_covariance(W0, s.nw, s.w.scale**2, "W0")
        self.W0_rate = self.W0 if W0_rate is None else as_covariance(W0_rate, s.nw, s.w.scale**2, "W0_rate")
        x, u, d, v = (ca.SX.sym(n, m) for n, m in (("x", s.nx), ("u", s.nu), ("d", s.nw), ("v", s.nv)))
        fx, hx = s.f(x, u, d), s.h(x, v)
        # evaluated through CasADi's buffers: dense outputs, entries in column-major order
        self._f = BufferedFunction(
            ca.Function("f_aug", [x, u, d], [ca.densify(fx), ca.densify(ca.jacobian(fx, ca.vertcat(x, d)))])
        )
        self._h = BufferedFunction(
            ca.Function("h_aug", [x, v], [ca.densify(e) for e in (hx, ca.jacobian(hx, x), ca.jacobian(hx, v))])
        )
        self._x0_prior = None
        self._clear()
        if x0_prior is not None:
            self.reset(x0_prior)

    def _clear(self) -> None:
        self._k = 0
        self._z: FloatArray | None = None
        self._P: FloatArray | None = None
        self._log_likelihood = 0.0
        self._unscored = 0

    @property
    def log_likelihood(self) -> float:
        r"""The Gaussian log-likelihood of the innovations of the steps so far (0 before the first).

        ``sum_k -1/2 (log det(2 pi S[k]) + e[k]' S[k]^-1 e[k])`` with ``e[k] = y[k] - y_pred[k]`` over the
        observed channels of each step and ``S[k]`` the filter's own innovation covariance (from the prior at
        k = 0). Steps without measurements add nothing; steps whose update failed are counted in
        :attr:`unscored_steps` instead.
        """
        return self._log_likelihood

    @property
    def unscored_steps(self) -> int:
        """Steps with measurements whose innovation is missing from :attr:`log_likelihood` (the update failed)."""
        return self._unscored

    @property
    def covariance(self) -> FloatArray | None:
        """The posterior covariance of ``(x[k], d[k])`` after step k (None before the first)."""
        return self._P

    # ------------------------------------------------------------------ the filter
    def _predict(self, z: FloatArray, P: FloatArray, u: FloatArray, inside: bool) -> tuple[FloatArray, FloatArray]:
        """Mean and covariance of z[k+1]; ``inside``: the model evaluated at states projected onto X."""
        raise NotImplementedError

    def _update(
        self, z: FloatArray, P: FloatArray, y: FloatArray, observed: FloatArray, inside: bool
    ) -> tuple[FloatArray, FloatArray, float]:
        """Posterior mean, covariance and the innovation's log-density given the observed channels of y.

        The density is :func:`~uiest.likelihood.innovation_log_density`; ``inside`` as for :meth:`_predict`.
        """
        raise NotImplementedError

    def _prior(self, x0: FloatArray) -> FloatArray:
        """The mean of z at k = 0: ``(x0, w0)`` and a zero rate for an integrated random walk."""
        n = self.system.nw * (self.input_model.order - 1)
        return np.concatenate([x0, self.w0, np.zeros(n)])

    def _prior_covariance(self) -> FloatArray:
        """The covariance of z at k = 0: ``P0``, ``W0`` and (integrated random walk) ``W0_rate`` on the diagonal."""
        s, n = self.system, len(self.Q)
        P = np.zeros((n, n))
        P[: s.nx, : s.nx], P[s.nx : s.nx + s.nw, s.nx : s.nx + s.nw] = self.P0, self.W0
        if self.input_model is InputModel.INTEGRATED_RANDOM_WALK:
            P[s.nx + s.nw :, s.nx + s.nw :] = self.W0_rate
        return P

    def _inside(self, x: FloatArray) -> FloatArray:
        """States (..., nx) projected into X, ``INSIDE_MARGIN`` of its width (x's scale if infinite) from its sides."""
        X = self.system.x.bounds
        margin = INSIDE_MARGIN * np.where(np.isfinite(X.width), X.width, self.system.x.scale)
        return np.clip(x, X.lower + margin, X.upper - margin)

    def _noise(self, dh_dv: FloatArray, observed: FloatArray) -> FloatArray:
        """``R = D Sigma_v D^T`` of the observed channels; ``dh_dv``: D's entries (column-major), :attr:`_h`'s third."""
        D = dh_dv.reshape(self.system.nv, self.system.ny).T[observed]
        return D @ self.Sigma_v @ D.T

    def step(self, u_prev: ArrayLike | None, y: ArrayLike) -> StepEstimate:
        """Predict with ``u[k-1]`` (k > 0), update with ``y[k]``; return the estimate of ``x[k]``."""
        x0 = self._require_prior()
        start = time.perf_counter()
        s, k = self.system, self._k
        u_vec = check_u_prev(s, u_prev, k)
        y_vec = check_y(s, y)
        inside = False
        if k == 0 or self._z is None or self._P is None:
            z = self._prior(x0)
            P = self._prior_covariance()
        else:
            z, P = self._predict(self._z, self._P, u_vec, False)
            if not _finite(z, P):
                z, P = self._predict(self._z, self._P, u_vec, True)
                inside = True
        observed = ~np.isnan(y_vec)
        outcome, reason = Outcome.UPDATED, ""
        term = np.nan
        if not observed.any():
            outcome = Outcome.PROPAGATED
        elif _finite(z, P):
            try:
                z_new, P_new, term = self._update(z, P, y_vec, observed, False)
                if not _finite(z_new, P_new):
                    z_new, P_new, term = self._update(z, P, y_vec, observed, True)
                    inside = True
                if not _finite(z_new, P_new):
                    raise np.linalg.LinAlgError("the update is not finite")
                z, P = z_new, P_new
            except np.linalg.LinAlgError as exc:  # keep the prediction, as for a missing measurement
                outcome, reason, term = Outcome.UPDATE_SKIPPED, str(exc), np.nan
        if not _finite(z, P):
            if self._z is None or self._P is None:  # both None before the first step, both set after it
                raise DataError(f"step k={k}: the prior gives no finite estimate")
            z, P, outcome, inside = self._z, self._P, Outcome.KEPT, False
        X = s.x.bounds
        if np.any(np.abs(z[: s.nx] - X.clip(z[: s.nx])) > X.width):
            outcome = Outcome.DIVERGED
        if observed.any():
            if outcome == Outcome.UPDATED and np.isfinite(term):
                self._log_likelihood += term
            else:
                self._unscored += 1
        self._z, self._P, self._k = z, 0.5 * (P + P.T), k + 1
        return StepEstimate(
            k=k,
            x_hat=z[: s.nx].copy(),
            w_hat=self._back @ z[s.nx :] if k > 0 else None,
            w_index=k - 1 if k > 0 else None,
            outcome=outcome,
            iterations=0,
            solve_time=time.perf_counter() - start,
            cost=0.0,
            window=0,
            missing=~observed,
            at_bound=at_bound(X, z[: s.nx], s.x.scale),
            reason=reason,
            evaluated_inside=inside,
        )

    def run(self, u: ArrayLike | None, y: ArrayLike, *, x0_prior: ArrayLike | None = None) -> EstimationResult:
        """Estimate ``x[0..K]`` from ``u (K, nu)`` and ``y (K+1, ny)``, starting from a reset."""
        u_arr, y_arr = check_run_data(self.system, u, y)
        self.reset(x0_prior)
        return collect_run(self, u_arr, y_arr)

    @classmethod
    def tuned(
        cls,
        system: System,
        training: Trajectory,
        *,
        x0_prior: ArrayLike,
        variances: ArrayLike | None = None,
        **keywords: Any,
    ) -> KalmanFilter:
        """The filter whose ``w_variance`` gives the smallest state error on ``training`` (a separate record).

        ``variances`` (scalars, times ``w.scale^2``) default to ``10^-8 .. 10^2`` (21 values); the
        error is the RMS of ``(x_hat - x) / x.scale``. The result's :attr:`tuning` lists them all. A filter
        that diverged on the training record (an estimate beyond X by more than its width, or not finite) is
        never chosen; when all did, OptionError (a ``P0`` too wide for the model's nonlinearity, say).
        Warns (``UserWarning``) when the chosen filter failed steps of the training record (an update
        skipped or the estimate kept), when its scaled RMS exceeds 1, or when the choice is at an end of the
        grid and better than its neighbour by more than ``EDGE_GAIN`` (beyond the grid lies a better filter).
        """
        if not isinstance(training, Trajectory) or not np.all(np.isfinite(training.x)):
            raise DataError(
                "training: expected a simulated Trajectory with its states, got "
                + (type(training).__name__ if not isinstance(training, Trajectory) else "a record without them")
            )
        grid = np.logspace(-8, 2, 21) if variances is None else check_grid(variances)
        rms, failed = np.full(grid.shape, np.inf), np.zeros(grid.shape, dtype=int)
        diverged = np.zeros(grid.shape, dtype=int)
        for i, q in enumerate(grid):
            with quiet_bound_warnings():  # the grid's filters are scored, not shown
                result = cls(system, w_variance=q * system.w.scale**2, x0_prior=x0_prior, **keywords).run(
                    training.u if system.nu else None, training.y
                )
            failed[i] = np.count_nonzero(~np.asarray(result.success))
            diverged[i] = np.count_nonzero(result.outcome == Outcome.DIVERGED)
            diverged[i] += np.count_nonzero(~np.all(np.isfinite(result.x_hat), axis=1))
            if not diverged[i]:
                rms[i] = np.sqrt(np.mean((result.error(training.x) / system.x.scale) ** 2))
        if not np.any(np.isfinite(rms)):
            raise OptionError(
                f"P0: every {cls.__name__} of the variance grid diverged on the training record (an estimate beyond "
                "X by more than its width, or not finite); give a smaller P0 (the default is X's uniform variance)"
            )
        tuning = Tuning(factors=grid, rms=rms, failed=failed, diverged=diverged)
        best = int(np.nanargmin(rms))
        if failed[best]:
            warnings.warn(f"{cls.__name__}.tuned: the chosen filter failed {failed[best]} of {len(training.y)} "
                          "training steps (an update skipped or the estimate kept); a smaller P0 may help", UserWarning,
                          stacklevel=2)  # fmt: skip
        elif rms[best] > 1.0:
            warnings.warn(f"{cls.__name__}.tuned: the chosen filter's scaled RMS error on the training record is "
                          f"{rms[best]:.3g} (> 1: beyond X's size); a smaller P0 may help", UserWarning,
                          stacklevel=2)  # fmt: skip
        elif variances is None and best in (0, grid.size - 1) and rms[1 if best == 0 else -2] > EDGE_GAIN * rms[best]:
            warnings.warn(f"{cls.__name__}.tuned: the chosen variance {grid[best]:g} w.scale^2 is at an end of the "
                          "default grid; give variances= beyond it", UserWarning, stacklevel=2)  # fmt: skip
        estimator = cls(system, w_variance=tuning.chosen * system.w.scale**2, x0_prior=x0_prior, **keywords)
        estimator.tuning = tuning
        return estimator

    def score(self, u: ArrayLike | None, y: ArrayLike) -> Score:
        """Run over the record from the prior given before; its :attr:`log_likelihood`, unscored and diverged steps.

        A step that raised, or whose update failed, is unscored; an estimate beyond X by more than its width, or not
        finite, counts as diverged (:class:`~uiest.likelihood.Score`).
        """
        u_arr, y_arr = check_run_data(self.system, u, y)
        self.reset()
        with quiet_bound_warnings():  # scored, not shown
            result = collect_run(self, u_arr, y_arr)
        errors = np.count_nonzero(result.outcome == Outcome.ERROR)
        diverged = np.count_nonzero(result.outcome == Outcome.DIVERGED)
        diverged += np.count_nonzero(~np.all(np.isfinite(result.x_hat), axis=1))
        return Score(
            log_likelihood=self.log_likelihood, unscored=self.unscored_steps + int(errors), diverged=int(diverged)
        )

    @classmethod
    def fit(
        cls,
        system: System,
        u: ArrayLike | None,
        y: ArrayLike,
        *,
        x0_prior: ArrayLike,
        variances: ArrayLike | None = None,
        input_models: Sequence[InputModel | str] | InputModel | str | None = None,
        prior_factors: ArrayLike | None = None,
        **keywords: Any,
    ) -> KalmanFilter:
        """The filter whose input model, variance and prior factor maximise the likelihood of its innovations.

        The prediction-error method (:mod:`uiest.likelihood`, :mod:`uiest.filter_fit`): no true states needed,
        only ``u (K, nu)`` (None when nu = 0) and ``y (K+1, ny)`` (NaN: missing, dropped per step).

        Parameters
        ----------
        system : System
        u : array_like (K, nu) or None
        y : array_like (K+1, ny)
        x0_prior : array_like (nx,)
        variances : array_like, optional
            Factors ``q`` of ``w.scale^2`` to try (default :data:`~uiest.likelihood.DEFAULT_GRID`, grown by up to
            :data:`~uiest.likelihood.GRID_EXTENSION` points beyond an end where the likelihood is largest), refined
            around the best interior point.
        input_models : InputModel or str, or a sequence of them, optional
            The unknown input's models to compare (default: every :class:`~uiest.input_model.InputModel`).
        prior_factors : array_like, optional
            Factors on the prior's covariances ``P0``, ``W0`` and ``W0_rate`` (given or default) to try
            (default :data:`~uiest.filter_fit.PRIOR_GRID`); ``[1]`` holds them as given.
        **keywords
            For the filter (``x_variance``, ``v_covariance``, ``P0``, ...; not ``input_model``), held fixed. The
            profile is only as good as ``v_covariance`` (default: V's uniform variance), which sets the
            innovations' scale.

        Returns
        -------
        KalmanFilter
            At the chosen model, variance and prior; its :attr:`likelihood` is the chosen model's variance profile
            (:class:`~uiest.likelihood.LikelihoodProfile`: every log-likelihood evaluated, the 95 % interval, its
            shape) and :attr:`filter_fit` every model's profiles (:class:`~uiest.filter_fit.FilterFit`). A filter
            that diverged or failed an update on the record is never chosen; when every one of a search did,
            OptionError. Warns (``UserWarning``) when the chosen variance's profile is flat over the whole grid
            (the record does not determine it) or largest at an end of the grid (grown, for the default one).

        """
        if "input_model" in keywords:
            raise OptionError("input_model: fit compares input models; give input_models= to choose among them")
        u_arr, y_arr = check_run_data(system, u, y)
        if not np.any(np.isfinite(y_arr[1:])):
            raise DataError(
                f"y: expected a measurement after k = 0 (the input's variance acts from one sample to the next), got "
                f"a record of K = {len(y_arr) - 1} transitions with none"
            )
        grid, factors, models = check_grid(variances), check_prior_factors(prior_factors), check_models(input_models)
        priors = {m: cls(system, w_variance=0.0, input_model=m, **keywords) for m in models}

        def build(model: InputModel, q: float, c: float) -> KalmanFilter:
            base = priors[model]
            options = {**keywords, "P0": c * base.P0, "W0": c * base.W0, "W0_rate": c * base.W0_rate}
            return cls(system, w_variance=q * system.w.scale**2, x0_prior=x0_prior, input_model=model, **options)

        found = fit_filter(lambda m, q, c: build(m, q, c).score(u_arr, y_arr), models=models, variances=grid,
                           prior_factors=factors, scale=system.w.scale,
                           extend=GRID_EXTENSION if variances is None else 0)  # fmt: skip
        best = found.best
        profile = best.variance
        if profile.shape is ProfileShape.FLAT or profile.at_end:
            warnings.warn(f"{cls.__name__}.fit: {profile.summary()}", UserWarning, stacklevel=2)
        estimator = build(best.input_model, profile.chosen, best.prior_factor)
        estimator.likelihood = profile
        estimator.filter_fit = found
        return estimator

    @property
    def guarantee(self) -> Guarantee:
        """None: no theorem bounds the error for an unbounded unknown input."""
        return self._no_guarantee(
            self.theorem,
            f"the {self.estimator_name} assumes the unknown input is {_article(self.input_model)} "
            f"{self.input_model.value} (its error grows with how far w departs from one); no bound holds for an "
            "unbounded unknown input",
        )

    def __repr__(self) -> str:
        return (
            f"{self.estimator_name}(system={self.system.name!r}, input_model={self.input_model.value!r}, "
            f"w_variance={np.diag(self.Q)[len(self.Q) - self.system.nw :]}, "
            f"guarantee={str(self.guarantee)!r})"
        )


class EKF(KalmanFilter):
    """Extended Kalman filter on the augmented model (see :class:`KalmanFilter` for the parameters)."""

    estimator_name = "EKF"

    def _predict(self, z: FloatArray, P: FloatArray, u: FloatArray, inside: bool) -> tuple[FloatArray, FloatArray]:
        s = self.system
        x_next, J = self._f(self._inside(z[: s.nx]) if inside else z[: s.nx], u, z[s.nx : s.nx + s.nw])
        F = np.zeros_like(P)
        F[: s.nx, : s.nx + s.nw] = J.reshape(s.nx + s.nw, s.nx).T
        F[s.nx :, s.nx :] = self._A_in
        z_next = np.concatenate([x_next, self._A_in @ z[s.nx :]])
        return z_next, F @ P @ F.T + self.Q

    def _update(
        self, z: FloatArray, P: FloatArray, y: FloatArray, observed: FloatArray, inside: bool
    ) -> tuple[FloatArray, FloatArray, float]:
        s = self.system
        if inside:  # the estimate projected into X, as for the prediction
            z = np.concatenate([self._inside(z[: s.nx]), z[s.nx :]])
        y_pred, C, dh_dv = self._h(z[: s.nx], self.v_prior)
        H = np.zeros((int(observed.sum()), len(z)))
        H[:, : s.nx] = C.reshape(s.nx, s.ny).T[observed]
        innovation = y[observed] - y_pred[observed]
        R = self._noise(dh_dv, observed)
        S = H @ P @ H.T + R
        K = np.linalg.solve(S, H @ P).T
        I_KH = np.eye(len(z)) - K @ H
        return z + K @ innovation, I_KH @ P @ I_KH.T + K @ R @ K.T, innovation_log_density(innovation, S)


class UKF(KalmanFilter):
    """Unscented Kalman filter on the augmented model.

    ``alpha``, ``beta``, ``kappa``: the scaled sigma points (default 1, 2, 0: points at
    ``sqrt(n)`` standard deviations, exact for linear models); other parameters as
    :class:`KalmanFilter`.
    """

    estimator_name = "UKF"

    def __init__(
        self, system: System, *, alpha: float = 1.0, beta: float = 2.0, kappa: float = 0.0, **keywords: Any
    ) -> None:
        super().__init__(system, **keywords)
        n = len(self.Q)
        alpha = check_real(alpha, "alpha", "a number in (0, 1]")
        if not 0.0 < alpha <= 1.0:
            raise OptionError(f"alpha: expected a number in (0, 1], got {alpha}")
        lam = alpha**2 * (n + check_real(kappa, "kappa", "a number")) - n
        if n + lam <= 0:
            raise OptionError(f"kappa: expected n + lambda > 0, got {n + lam}")
        self._spread = np.sqrt(n + lam)
        self._wm = np.full(2 * n + 1, 0.5 / (n + lam))
        self._wm[0] = lam / (n + lam)
        self._wc = self._wm.copy()
        self._wc[0] += 1.0 - alpha**2 + check_real(beta, "beta", "a number")
        m = 2 * n + 1
        sizes = {"x": system.nx, "u": system.nu, "d": system.nw, "v": system.nv}
        x, u, d, v = (ca.MX.sym(name, size, m) for name, size in sizes.items())
        # the model at all sigma points at once, through CasADi's buffers: column j of each input and output is point j
        self._f_points = BufferedFunction(ca.Function("f_points", [x, u, d], [ca.densify(system.f.map(m)(x, u, d))]))
        self._h_points = BufferedFunction(ca.Function("h_points", [x, v], [ca.densify(system.h.map(m)(x, v))]))

    def _points(self, z: FloatArray, P: FloatArray, inside: bool) -> FloatArray:
        """Sigma points (2n+1, n): z and ``z +- spread * columns of chol(P)`` (``inside``: states projected onto X)."""
        try:
            L = np.linalg.cholesky(P)
        except np.linalg.LinAlgError:  # semidefinite: a symmetric square root
            vals, vecs = np.linalg.eigh(P)
            L = vecs * np.sqrt(np.clip(vals, 0.0, None))
        step = self._spread * L.T
        points = np.vstack([z, z + step, z - step])
        if inside:
            points[:, : self.system.nx] = self._inside(points[:, : self.system.nx])
        return points

    def _moments(self, points: FloatArray) -> tuple[FloatArray, FloatArray]:
        mean = self._wm @ points
        dev = points - mean
        return mean, (self._wc[:, None] * dev).T @ dev

    def _predict(self, z: FloatArray, P: FloatArray, u: FloatArray, inside: bool) -> tuple[FloatArray, FloatArray]:
        s = self.system
        chi = self._points(z, P, inside)
        m = len(chi)
        d = chi[:, s.nx : s.nx + s.nw]
        (x_next,) = self._f_points(chi[:, : s.nx].ravel(), np.tile(u, m), d.ravel())
        mean, cov = self._moments(np.hstack([x_next.reshape(m, s.nx), chi[:, s.nx :] @ self._A_in.T]))
        return mean, cov + self.Q

    def _update(
        self, z: FloatArray, P: FloatArray, y: FloatArray, observed: FloatArray, inside: bool
    ) -> tuple[FloatArray, FloatArray, float]:
        s = self.system
        chi = self._points(z, P, inside)
        m = len(chi)
        (ys,) = self._h_points(chi[:, : s.nx].ravel(), np.tile(self.v_prior, m))
        ys = ys.reshape(m, s.ny)[:, observed]
        y_mean = self._wm @ ys
        dy, dz = ys - y_mean, chi - self._wm @ chi
        dh_dv = self._h(self._inside(z[: s.nx]) if inside else z[: s.nx], self.v_prior)[2]
        S = (self._wc[:, None] * dy).T @ dy + self._noise(dh_dv, observed)
        Pzy = (self._wc[:, None] * dz).T @ dy
        K = np.linalg.solve(S, Pzy.T).T
        innovation = y[observed] - y_mean
        return z + K @ innovation, P - K @ S @ K.T, innovation_log_density(innovation, S)


def _article(model: InputModel) -> str:
    return "an" if model.value[0] in "aeiou" else "a"


def _input_model(value: InputModel | str) -> InputModel:
    try:
        return InputModel(value)
    except ValueError:
        raise OptionError(f"input_model: expected one of {[m.value for m in InputModel]}, got {value!r}") from None


def _finite(z: FloatArray, P: FloatArray) -> bool:
    return bool(np.isfinite(z).all() and np.isfinite(P).all())


__all__ = ["EKF", "UKF", "KalmanFilter", "Tuning"]
