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
and which box bounds ``w``.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from numpy.typing import ArrayLike

from uiest.box import Box, FloatArray, as_vector
from uiest.errors import DataError, OptionError, SolverError
from uiest.estimators.results import EstimationResult, StepEstimate
from uiest.system import System
from uiest.window import WindowProblem, WindowSolution, WindowSolver, WindowTrajectory, WindowWeights, make_solver
from uiest.window.solvers import BACKENDS


def check_horizon(N: Any) -> int:
    """Return N as an int >= 1 or raise OptionError naming ``N``."""
    if isinstance(N, bool) or not isinstance(N, int | np.integer) or N < 1:
        raise OptionError(f"N: expected an integer horizon >= 1, got {N!r}")
    return int(N)


@dataclass
class _Cached:
    """A window problem and its solvers (the cold one is built on first need)."""

    problem: WindowProblem
    warm: WindowSolver
    cold: WindowSolver | None = None


class WindowEstimator:
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
            raise OptionError(f"solver_options: expected a mapping of IPOPT options, got {solver_options!r}")
        self.solver_options = dict(solver_options or {})
        self.warm_start = bool(warm_start)
        self.strict = bool(strict)
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
        """Whether the guarantee named in :attr:`guarantee` applies."""
        return False

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

    # ------------------------------------------------------------------ problems
    def _cached(self, length: int) -> _Cached:
        entry = self._cache.get(length)
        if entry is None:
            measured = range(length) if self.one_step_ahead else range(length + 1)
            problem = WindowProblem(
                self.system, length, list(measured), self._window_weights(length), w_box=self._w_box()
            )
            solver = make_solver(self.solver, problem, warm_start=self.warm_start, options=self.solver_options)
            entry = _Cached(problem, solver, None if self.warm_start else solver)
            self._cache[length] = entry
        return entry

    def _cold(self, entry: _Cached) -> WindowSolver:
        if entry.cold is None:
            entry.cold = make_solver(self.solver, entry.problem, warm_start=False, options=self.solver_options)
        return entry.cold

    # ------------------------------------------------------------------ input checks
    def _check_u_prev(self, u_prev: ArrayLike | None, k: int) -> FloatArray:
        nu = self.system.nu
        if k == 0:
            if u_prev is not None and np.size(u_prev) != 0:
                raise DataError("u_prev: expected None at k = 0 (no transition precedes the first measurement)")
            return np.zeros(nu)
        if u_prev is None:
            if nu == 0:
                return np.zeros(0)
            raise DataError(f"u_prev: expected the known input u[{k - 1}] of shape ({nu},), got None")
        return as_vector(u_prev, nu, "u_prev")

    def _check_y(self, y: ArrayLike) -> FloatArray:
        ny = self.system.ny
        try:
            arr = np.asarray(y, dtype=float)
        except (TypeError, ValueError) as exc:
            raise DataError(f"y: expected {ny} real numbers (NaN = missing), got {y!r}") from exc
        if arr.ndim == 0 and ny == 1:
            arr = arr.reshape(1)
        if arr.shape != (ny,):
            raise DataError(f"y: expected shape ({ny},), got shape {arr.shape}")
        if np.any(np.isinf(arr)):
            raise DataError(f"y: expected finite values or NaN (missing), got {arr.tolist()}")
        return arr.copy()

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
        u_vec = self._check_u_prev(u_prev, k)
        y_vec = self._check_y(y)
        length = k if self.N is None else min(self.N, k)
        start = k - length
        stored_u = list(self._u)
        u_win = np.array([*stored_u[len(stored_u) - length + 1 :], u_vec] if length else [], dtype=float)
        u_win = u_win.reshape(length, self.system.nu)
        past = list(self._y)[len(self._y) - length :] if length else []
        y_win = np.array(past if self.one_step_ahead else [*past, y_vec], dtype=float).reshape(-1, self.system.ny)
        if y_win.size and np.all(np.isnan(y_win)):
            last = k - 1 if self.one_step_ahead else k
            raise DataError(f"y: every measurement in the window {start}..{last} of step k={k} is missing (NaN)")
        prior = self._x0_prior if start == 0 else self._priors[0]

        if len(y_win) == 0:  # the one-step-ahead MHE at k = 0: nothing to fit, the estimate is the prior
            x_hat, w_hat, w_index = prior.copy(), None, None
            status, success, iterations, solve_time, cost = "prior", True, 0, 0.0, 0.0
            solution = None
        else:
            entry = self._cached(length)
            problem = entry.problem
            p = problem.parameters(
                prior,
                u_win,
                y_win,
                v_bar=np.tile(self.v_prior, (problem.n_meas, 1)),
                w_bar=np.tile(self._w_bar(), (length, 1)),
            )
            z0, duals = self._guess(problem, start, prior, u_win)
            attempts = [entry.warm.solve(z0, p, *(duals or (None, None)))]
            if not attempts[-1].success:
                attempts.append(self._cold(entry).solve(self._cold_guess(problem, prior, u_win), p))
            solution = attempts[-1]
            iterations = sum(a.iterations for a in attempts)
            solve_time = sum(a.solve_time for a in attempts)
            success = solution.success
            if success:
                trajectory = problem.unpack(solution.z)
                x_hat = trajectory.x[-1].copy()
                status, cost = solution.status, solution.cost
                w_hat, w_index = self._reported_w(trajectory, k)
            else:
                if self.strict:
                    raise SolverError(
                        f"step k={k}: the window problem ({length} transitions) was not solved: "
                        f"{' / '.join(a.status for a in attempts)}"
                    )
                x_hat, w_hat, w_index = self._propagate(u_vec, k)
                status, cost = f"propagated ({solution.status})", float("nan")

        # commit
        if k > 0:
            self._u.append(u_vec)
        self._y.append(y_vec)
        self._priors.append(self._x0_prior.copy() if k == 0 else x_hat.copy())
        if solution is not None and solution.success:
            self._last = (start, entry.problem, solution)
        self._x_last = x_hat
        if w_hat is not None:
            self._w_last = w_hat
        self._k = k + 1
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
        w = self._w_last if self._w_last is not None else self._w_bar()
        x = self.system.x.bounds.clip(self.system.step(self._x_last, u_prev, w))
        lag = 2 if self.one_step_ahead else 1
        return x, (w.copy() if k - lag >= 0 else None), (k - lag if k - lag >= 0 else None)

    # ------------------------------------------------------------------ guesses
    def _predict(self, problem: WindowProblem, x: FloatArray, w: FloatArray, u_win: FloatArray, first: int) -> None:
        """Fill ``x[first+1:]`` by simulating from ``x[first]`` (clipped into X)."""
        box = problem.x_box
        for i in range(first, problem.length):
            nxt = np.asarray(self.system.f(x[i], u_win[i], w[i]), dtype=float).reshape(-1)
            x[i + 1] = box.clip(nxt) if np.all(np.isfinite(nxt)) else x[i]

    def _cold_guess(self, problem: WindowProblem, prior: FloatArray, u_win: FloatArray) -> FloatArray:
        nx = self.system.nx
        x = np.empty((problem.length + 1, nx))
        x[0] = prior
        w_guess = self._w_last if self._w_last is not None else self._w_bar()
        w = np.tile(w_guess, (problem.length, 1))
        if problem.w_box is not None:
            w = problem.w_box.clip(w)
        self._predict(problem, x, w, u_win, 0)
        v = np.tile(self.v_prior, (problem.n_meas, 1))
        return problem.pack(WindowTrajectory(x, w, v))

    def _guess(
        self, problem: WindowProblem, start: int, prior: FloatArray, u_win: FloatArray
    ) -> tuple[FloatArray, tuple[FloatArray, FloatArray] | None]:
        """The previous solution shifted to the new window (new nodes predicted), and shifted multipliers."""
        last = self._last
        if last is None:
            return self._cold_guess(problem, prior, u_win), None
        old_start, old_problem, old_solution = last
        d = start - old_start
        n_x = min(old_problem.length + 1 - d, problem.length + 1)  # state nodes both windows hold
        if d < 0 or n_x < 1:
            return self._cold_guess(problem, prior, u_win), None
        old = old_problem.unpack(old_solution.z)
        L, M = problem.length, problem.n_meas
        n_w = min(max(n_x - 1, 0), L)
        n_v = min(max(old_problem.n_meas - d, 0), M)
        x = np.empty((L + 1, self.system.nx))
        x[:n_x] = old.x[d : d + n_x]
        w_fill = old.w[-1] if old_problem.length else (self._w_last if self._w_last is not None else self._w_bar())
        w = np.tile(w_fill, (L, 1))
        w[:n_w] = old.w[d : d + n_w]
        v = np.tile(self.v_prior, (M, 1))
        v[:n_v] = old.v[d : d + n_v]
        self._predict(problem, x, w, u_win, n_x - 1)
        z0 = problem.pack(WindowTrajectory(x, w, v))
        if not self.warm_start:
            return z0, None
        lam_x = np.zeros(problem.n_var)
        for new_index, old_index, count in (
            (problem.x_index, old_problem.x_index, n_x),
            (problem.w_index, old_problem.w_index, n_w),
            (problem.v_index, old_problem.v_index, n_v),
        ):
            if count:
                lam_x[new_index[:count]] = old_solution.lam_x[old_index[d : d + count]]
        nx, ny = self.system.nx, self.system.ny
        lam_g = np.zeros(problem.n_con)
        old_dyn = old_solution.lam_g[: old_problem.n_dyn].reshape(old_problem.length, nx)
        lam_g[: n_w * nx] = old_dyn[d : d + n_w].ravel()
        if problem.has_output_constraints and old_problem.has_output_constraints and n_v:
            old_out = old_solution.lam_g[old_problem.n_dyn :].reshape(old_problem.n_meas, ny)
            lam_g[problem.n_dyn : problem.n_dyn + n_v * ny] = old_out[d : d + n_v].ravel()
        return z0, (lam_x, lam_g)

    # ------------------------------------------------------------------ batch
    def _check_run_data(self, u: ArrayLike | None, y: ArrayLike) -> tuple[FloatArray, FloatArray]:
        s = self.system
        try:
            y_arr = np.asarray(y, dtype=float)
        except (TypeError, ValueError) as exc:
            raise DataError(f"y: expected an array of shape (K+1, {s.ny}), got {type(y).__name__}") from exc
        if y_arr.ndim != 2 or y_arr.shape[1] != s.ny or y_arr.shape[0] < 1:
            raise DataError(f"y: expected shape (K+1, {s.ny}) with K+1 >= 1, got {y_arr.shape}")
        if np.any(np.isinf(y_arr)):
            raise DataError("y: expected finite values or NaN (missing), got +-inf")
        K = y_arr.shape[0] - 1
        if u is None:
            if s.nu:
                raise DataError(f"u: required, the system has nu={s.nu} known inputs; expected shape ({K}, {s.nu})")
            u_arr = np.zeros((K, 0))
        else:
            try:
                u_arr = np.asarray(u, dtype=float)
            except (TypeError, ValueError) as exc:
                raise DataError(f"u: expected an array of shape ({K}, {s.nu}), got {type(u).__name__}") from exc
            if u_arr.size == 0 and s.nu == 0:
                u_arr = np.zeros((K, 0))
            if u_arr.ndim != 2 or u_arr.shape[1] != s.nu:
                raise DataError(f"u: expected shape (K, {s.nu}), got {u_arr.shape}")
            if u_arr.shape[0] != K:
                raise DataError(
                    f"u, y: length mismatch, u has {u_arr.shape[0]} rows and y has {K + 1}; "
                    f"expected u (K, nu) with y (K+1, ny)"
                )
            if not np.all(np.isfinite(u_arr)):
                bad = int(np.argwhere(~np.isfinite(u_arr))[0][0])
                raise DataError(f"u: expected finite values, got {u_arr[bad].tolist()} at k={bad}")
        # every window must hold a measurement
        has = (~np.isnan(y_arr)).any(axis=1).astype(int)
        counts = np.concatenate([[0], np.cumsum(has)])
        for k in range(K + 1):
            length = k if self.N is None else min(self.N, k)
            first, last = k - length, (k - 1 if self.one_step_ahead else k)
            if last >= first and counts[last + 1] - counts[first] == 0:
                raise DataError(f"y: every measurement in the window {first}..{last} of step k={k} is missing (NaN)")
        return u_arr, y_arr

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
        u_arr, y_arr = self._check_run_data(u, y)
        self.reset(x0_prior)
        K = y_arr.shape[0] - 1
        s = self.system
        x_hat = np.empty((K + 1, s.nx))
        w_hat = np.full((K, s.nw), np.nan)
        status: list[str] = []
        success = np.zeros(K + 1, dtype=bool)
        iterations = np.zeros(K + 1, dtype=np.int64)
        solve_time = np.zeros(K + 1)
        cost = np.zeros(K + 1)
        window = np.zeros(K + 1, dtype=np.int64)
        for k in range(K + 1):
            est = self.step(None if k == 0 else u_arr[k - 1], y_arr[k])
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
            estimator=self.estimator_name,
            horizon=self.N,
            guarantee=self.guarantee,
            names={"x": s.x.names, "w": s.w.names},
            time_unit=s.time_unit,
        )
