"""The moving-window machinery every optimisation-based estimator shares.

:class:`WindowEstimator` keeps the last ``N`` inputs and measurements and the priors of the
prior rule in bounded deques, builds one :class:`~uiest.window.WindowProblem` per window
length ``N_k = min(N, k)`` (N+1 of them, lazily, cached: windows shorter than N at the start
are separate problems rather than padded ones), warm-starts each solve with the previous
solution shifted by one step (primal and dual), retries a failed solve once from a cold start
and, if that fails too, propagates the previous estimate through the model and records the
failure (``strict=True`` raises :class:`~uiest.errors.SolverError` instead).

Subclasses say which nodes carry a measurement (all of ``k-N_k .. k`` for the UISE and the
FIE, ``k-N_k .. k-1`` for the one-step-ahead standard MHE), which weights the residuals get,
and which box bounds ``w``. The two-stage UISE replaces the problem (:meth:`_build_problem`: its
reduced model as a :class:`~uiest.window.WindowModel`) and :meth:`step`, and reuses the cache,
the warm-started solve with cold retry (:meth:`_solve_window`), :meth:`reset` and :meth:`run`.
:func:`collect_run` gathers an :class:`EstimationResult` from any object with ``step`` (the
linear UIO uses it too). ``polish = True`` (attribute, set before running) refines every window
solution by Gauss-Newton steps (:mod:`uiest.window.polish`).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from numpy.typing import ArrayLike

from uiest.box import Box, FloatArray, as_vector
from uiest.errors import CertificationError, DataError, OptionError, SolverError
from uiest.estimators.checks import (
    boundary_flag,
    check_horizon,
    check_run_data,
    check_u_prev,
    check_y,
    window_bounds,
)
from uiest.estimators.results import NO_DATA, EstimationResult, StepEstimate
from uiest.system import System
from uiest.window import WindowProblem, WindowSolution, WindowSolver, WindowTrajectory, WindowWeights, make_solver
from uiest.window.solvers import BACKENDS
from uiest.window.warmstart import predicted_guess, shifted_guess


@dataclass
class _Cached:
    """A window problem and its solvers (the cold one is built on first need)."""

    problem: WindowProblem
    warm: WindowSolver
    cold: WindowSolver | None = None


class StreamingEstimator:
    """Time index, prior of x[0] and ``reset``, shared by every estimator.

    Subclasses hold ``system``, ``_x0_prior`` and ``_k`` and implement ``_clear()``.
    """

    system: System
    _x0_prior: FloatArray | None
    _k: int

    def _clear(self) -> None:
        raise NotImplementedError

    @property
    def k(self) -> int:
        """Time index of the next call to :meth:`step`."""
        return self._k

    @property
    def x0_prior(self) -> FloatArray | None:
        """The prior of x[0] set by the constructor or :meth:`reset`."""
        return self._x0_prior

    def reset(self, x0_prior: ArrayLike | None = None) -> None:
        """Start over at k = 0 with the prior ``x0_prior`` (shape (nx,), in X; None: keep the current one)."""
        if x0_prior is None:
            if self._x0_prior is None:
                raise OptionError("x0_prior: required (no prior of x[0] was given before)")
        else:
            prior = as_vector(x0_prior, self.system.nx, "x0_prior")
            if not self.system.x.bounds.contains(prior):
                raise DataError(f"x0_prior: expected a point in X = {self.system.x.bounds}, got {prior.tolist()}")
            self._x0_prior = prior
        self._clear()


class WindowEstimator(StreamingEstimator):
    """Base class: streaming ``step``, batch ``run``, failure handling, warm starts.

    Not used directly; see :class:`~uiest.estimators.UISE`, :class:`~uiest.estimators.FIE` and
    :class:`~uiest.estimators.StandardMHE`.
    """

    estimator_name: ClassVar[str] = "window"
    one_step_ahead: ClassVar[bool] = False
    """True: the window at time k uses ``y[k-N_k .. k-1]`` (the estimate is a one-step prediction)."""

    def __init__(
        self,
        system: System,
        *,
        N: int | None,
        x0_prior: ArrayLike | None,
        v_prior: ArrayLike | None,
        solver: str,
        solver_options: Mapping[str, Any] | None,
        warm_start: bool,
        strict: bool,
    ) -> None:
        if not isinstance(system, System):
            raise OptionError(f"system: expected a uiest.System, got {type(system).__name__}")
        self.system = system
        self.N = None if N is None else check_horizon(N)
        if solver not in BACKENDS:
            raise OptionError(f"solver: unknown backend {solver!r}; expected one of {list(BACKENDS)}")
        self.solver = solver
        if solver_options is not None and not isinstance(solver_options, Mapping):
            raise OptionError(f"solver_options: expected a mapping of backend options, got {solver_options!r}")
        self.solver_options = dict(solver_options or {})
        self.warm_start = bool(warm_start)
        self.strict = bool(strict)
        self.polish = getattr(self, "polish", False)
        """Refine window solutions by Gauss-Newton steps (:func:`uiest.window.polish.refine`); set before running."""
        v_bar = np.zeros(system.nv) if v_prior is None else as_vector(v_prior, system.nv, "v_prior")
        if not system.v.bounds.contains(v_bar):
            raise DataError(f"v_prior: expected a point in V = {system.v.bounds}, got {v_bar.tolist()}")
        self.v_prior = v_bar
        self._cache: dict[int, _Cached] = {}
        self._x0_prior: FloatArray | None = None
        self._clear()
        if x0_prior is not None:
            self.reset(x0_prior)

    # ------------------------------------------------------------------ subclass hooks
    def _window_weights(self, length: int) -> WindowWeights:
        raise NotImplementedError

    def _w_box(self) -> Box | None:
        """Bound on the unknown-input estimates (None: unbounded)."""
        return None

    def _w_bar(self) -> FloatArray:
        """Prior of w (used as the guess of new transitions, and in the cost if w is weighted)."""
        return self.system.nominal_w

    @property
    def guarantee(self) -> str:
        """Which theorem's guarantee holds for this configuration, or why none does."""
        return "none"

    @property
    def guaranteed(self) -> bool:
        """Whether the guarantee named in :attr:`guarantee` applies.

        A certified certificate gave the weights and ``N >= certificate.min_horizon()``.
        """
        certificate = getattr(self, "certificate", None)
        horizon = self.N
        return certificate is not None and horizon is not None and certificate.min_horizon() <= horizon

    # ------------------------------------------------------------------ state
    def _clear(self) -> None:
        maxlen = self.N
        self._k = 0
        self._u: deque[FloatArray] = deque(maxlen=maxlen)
        self._y: deque[FloatArray] = deque(maxlen=maxlen)
        self._priors: deque[FloatArray] = deque(maxlen=maxlen)
        self._last: tuple[int, WindowProblem, WindowSolution] | None = None
        self._x_last: FloatArray | None = None
        self._w_last: FloatArray | None = None

    # ------------------------------------------------------------------ problems
    def _build_problem(self, length: int) -> WindowProblem:
        """The window problem with ``length`` transitions (built once per length and cached)."""
        measured = range(length) if self.one_step_ahead else range(length + 1)
        return WindowProblem(self.system, length, list(measured), self._window_weights(length), w_box=self._w_box())

    def _cached(self, length: int) -> _Cached:
        entry = self._cache.get(length)
        if entry is None:
            problem = self._build_problem(length)
            solver = make_solver(
                self.solver, problem, warm_start=self.warm_start, options=self.solver_options, polish=self.polish
            )
            entry = _Cached(problem, solver, None if self.warm_start else solver)
            self._cache[length] = entry
        return entry

    def _cold(self, entry: _Cached) -> WindowSolver:
        if entry.cold is None:
            entry.cold = make_solver(
                self.solver, entry.problem, warm_start=False, options=self.solver_options, polish=self.polish
            )
        return entry.cold

    # ------------------------------------------------------------------ one step
    def step(self, u_prev: ArrayLike | None, y: ArrayLike) -> StepEstimate:
        """Process ``u[k-1]`` and ``y[k]``; return the estimate of ``x[k]``.

        Parameters
        ----------
        u_prev : array_like (nu,) or None
            The known input ``u[k-1]`` that moved the system from k-1 to k; None at k = 0 (and
            when nu = 0).
        y : array_like (ny,)
            The measurement ``y[k]``; NaN entries are missing and their residuals are dropped.
            The one-step-ahead standard MHE stores ``y[k]`` and uses it from step k+1 on.

        Returns
        -------
        StepEstimate

        """
        if self._x0_prior is None:
            raise OptionError("x0_prior: required; pass it to the constructor or call reset(x0_prior) first")
        k = self._k
        u_vec = check_u_prev(self.system, u_prev, k)
        y_vec = check_y(self.system, y)
        length, start = window_bounds(k, self.N)
        stored_u = list(self._u)
        u_win = np.array([*stored_u[len(stored_u) - length + 1 :], u_vec] if length else [], dtype=float)
        u_win = u_win.reshape(length, self.system.nu)
        past = list(self._y)[len(self._y) - length :] if length else []
        y_win = np.array(past if self.one_step_ahead else [*past, y_vec], dtype=float).reshape(-1, self.system.ny)
        prior = self._x0_prior if start == 0 else self._priors[0]
        entry = None
        solution = None
        if len(y_win) == 0:  # the one-step-ahead MHE at k = 0: nothing to fit, the estimate is the prior
            x_hat, w_hat, w_index = prior.copy(), None, None
            status, success, iterations, solve_time, cost = "prior", True, 0, 0.0, 0.0
        elif np.all(np.isnan(y_win)):  # an outage longer than the window: bridge it with the model
            x_hat, w_hat, w_index = self._propagate(u_vec, k)
            status, success, iterations, solve_time, cost = NO_DATA, False, 0, 0.0, float("nan")
        else:
            entry, attempts = self._solve_window(length, start, prior, u_win, y_win)
            problem = entry.problem
            solution = attempts[-1]
            iterations = sum(a.iterations for a in attempts)
            solve_time = sum(a.solve_time for a in attempts)
            success = solution.success
            if success:
                trajectory = problem.unpack(solution.z)
                x_hat = trajectory.x[-1].copy()
                status, cost = solution.status + boundary_flag(self.system, x_hat, y_vec, self.v_prior), solution.cost
                w_hat, w_index = self._reported_w(trajectory, k)
            else:
                if self.strict:
                    raise SolverError(
                        f"step k={k}: the window problem ({length} transitions) was not solved: "
                        f"{' / '.join(a.status for a in attempts)}"
                    )
                x_hat, w_hat, w_index = self._propagate(u_vec, k)
                status, cost = f"propagated ({solution.status})", float("nan")

        if solution is not None and solution.success and entry is not None:
            self._last = (start, entry.problem, solution)
        self._commit(k, u_vec, y_vec, x_hat, w_hat)
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

    def _commit(
        self, k: int, u_vec: FloatArray, y_vec: FloatArray, x_hat: FloatArray, w_hat: FloatArray | None
    ) -> None:
        """Store step k's data and estimate, and move to k + 1."""
        if k > 0:
            self._u.append(u_vec)
        self._y.append(y_vec)
        self._priors.append(self._x0_prior.copy() if k == 0 else x_hat.copy())  # type: ignore[union-attr]
        self._x_last = x_hat
        if w_hat is not None:
            self._w_last = w_hat
        self._k = k + 1

    def skip(self, u_prev: ArrayLike | None, y: ArrayLike, reason: str) -> StepEstimate:
        """Step k without solving: the model propagates the last estimate; ``reason`` goes into the status.

        :func:`collect_run` calls it when :meth:`step` raised unexpectedly, so that a run keeps
        what it computed and goes on.
        """
        if self._x0_prior is None:
            raise OptionError("x0_prior: required; pass it to the constructor or call reset(x0_prior) first")
        k = self._k
        u_vec = check_u_prev(self.system, u_prev, k)
        y_vec = check_y(self.system, y)
        x_hat, w_hat, w_index = self._propagate(u_vec, k)
        self._commit(k, u_vec, y_vec, x_hat, w_hat)
        return StepEstimate(k, x_hat, w_hat, w_index, f"propagated ({reason})", False, 0, 0.0, float("nan"),
                            0, np.isnan(y_vec))  # fmt: skip

    def _reported_w(self, trajectory: WindowTrajectory, k: int) -> tuple[FloatArray | None, int | None]:
        """The newest unknown-input estimate a measurement informs, and its time index."""
        lag = 2 if self.one_step_ahead else 1
        if len(trajectory.w) < lag:
            return None, None
        return trajectory.w[-lag].copy(), k - lag

    def _propagate(self, u_prev: FloatArray, k: int) -> tuple[FloatArray, FloatArray | None, int | None]:
        """After a failed solve: ``x_hat[k] = f(x_hat[k-1], u[k-1], w_last)`` clipped to X (the prior at k = 0)."""
        if k == 0 or self._x_last is None:
            return self._x0_prior.copy(), None, None  # type: ignore[union-attr]
        w = self._w_guess()
        x = self.system.x.bounds.clip(self.system.step(self._x_last, u_prev, w))
        lag = 2 if self.one_step_ahead else 1
        return x, (w.copy() if k - lag >= 0 else None), (k - lag if k - lag >= 0 else None)

    def _solve_window(
        self,
        length: int,
        start: int,
        prior: FloatArray,
        u_win: FloatArray,
        y_win: FloatArray,
        data: FloatArray | None = None,
    ) -> tuple[_Cached, list[WindowSolution]]:
        """Solve the window ``start .. start+length``: warm start from the shifted last solution, one cold retry.

        Returns the cached problem entry and the attempts (the last one counts).
        """
        entry = self._cached(length)
        problem = entry.problem
        p = problem.parameters(
            prior,
            u_win,
            y_win,
            v_bar=np.tile(self.v_prior, (problem.n_meas, 1)),
            w_bar=np.tile(self._w_bar(), (length, 1)),
            data=data,
        )
        z0, duals = self._guess(problem, start, prior, u_win, data)
        attempts = [entry.warm.solve(z0, p, *(duals or (None, None)))]
        if not attempts[-1].success:
            cold_guess = predicted_guess(problem, prior, u_win, self._w_guess(), self.v_prior, data)
            attempts.append(self._cold(entry).solve(cold_guess, p))
        return entry, attempts

    # ------------------------------------------------------------------ guesses
    def _w_guess(self) -> FloatArray:
        return self._w_last if self._w_last is not None else self._w_bar()

    def _guess(
        self, problem: WindowProblem, start: int, prior: FloatArray, u_win: FloatArray, data: FloatArray | None = None
    ) -> tuple[FloatArray, tuple[FloatArray, FloatArray] | None]:
        """The last successful solution shifted onto the new window, else a prediction from the prior."""
        if self._last is not None:
            old_start, old_problem, old_solution = self._last
            shifted = shifted_guess(
                old_problem,
                old_solution,
                problem,
                start - old_start,
                u_win,
                self._w_guess(),
                self.v_prior,
                duals=self.warm_start,
                data=data,
            )
            if shifted is not None:
                return shifted
        return predicted_guess(problem, prior, u_win, self._w_guess(), self.v_prior, data), None

    # ------------------------------------------------------------------ batch
    def run(self, u: ArrayLike | None, y: ArrayLike, *, x0_prior: ArrayLike | None = None) -> EstimationResult:
        """Estimate ``x[0..K]`` from ``u (K, nu)`` and ``y (K+1, ny)``, starting from a reset.

        Parameters
        ----------
        u : array_like (K, nu) or None
            Known inputs (None when nu = 0).
        y : array_like (K+1, ny)
            Measurements; NaN entries are missing.
        x0_prior : array_like (nx,), optional
            Prior of x[0]; default: the one given before.

        Returns
        -------
        EstimationResult

        """
        u_arr, y_arr = check_run_data(self.system, u, y)
        self.reset(x0_prior)
        return collect_run(self, u_arr, y_arr)


def collect_run(estimator: Any, u_arr: FloatArray, y_arr: FloatArray) -> EstimationResult:
    """Call ``estimator.step`` for k = 0..K on checked data and gather an :class:`EstimationResult`.

    ``estimator`` needs ``system``, ``step(u_prev, y) -> StepEstimate``, ``estimator_name``, ``N``
    and ``guarantee``; the caller has reset it.
    """
    K = y_arr.shape[0] - 1
    s = estimator.system
    x_hat = np.empty((K + 1, s.nx))
    w_hat = np.full((K, s.nw), np.nan)
    status: list[str] = []
    success = np.zeros(K + 1, dtype=bool)
    iterations = np.zeros(K + 1, dtype=np.int64)
    solve_time = np.zeros(K + 1)
    cost = np.zeros(K + 1)
    window = np.zeros(K + 1, dtype=np.int64)
    for k in range(K + 1):
        u_prev = None if k == 0 else u_arr[k - 1]
        try:
            est = estimator.step(u_prev, y_arr[k])
        except (OptionError, CertificationError):  # the configuration is wrong: no step will do better
            raise
        except Exception as exc:  # recorded; the run keeps what it computed and goes on
            if getattr(estimator, "strict", False) or not hasattr(estimator, "skip"):
                raise
            est = estimator.skip(u_prev, y_arr[k], f"{type(exc).__name__}: {exc}")
        x_hat[k] = est.x_hat
        if est.w_hat is not None and est.w_index is not None:
            w_hat[est.w_index] = est.w_hat
        status.append(est.status)
        success[k], iterations[k], solve_time[k] = est.success, est.iterations, est.solve_time
        cost[k], window[k] = est.cost, est.window
    return EstimationResult(
        t=np.arange(K + 1) * s.dt,
        x_hat=x_hat,
        w_hat=w_hat,
        status=np.array(status),
        success=success,
        iterations=iterations,
        solve_time=solve_time,
        cost=cost,
        window=window,
        missing=np.isnan(y_arr),
        estimator=estimator.estimator_name,
        horizon=estimator.N,
        guarantee=estimator.guarantee,
        names={"x": s.x.names, "w": s.w.names},
        time_unit=s.time_unit,
    )
