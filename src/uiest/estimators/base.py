"""The one template every window estimator follows (UISE, FIE, standard MHE, two-stage UISE).

A step at time k: the window's data (``u``, ``y`` and, for the two-stage UISE, node data),
the prior of its first node (the estimate delivered when that node was the newest, the
prior rule), then one of

- no measured node yet (a one-step-ahead estimator at k = 0): the prior, outcome ``PRIOR``;
- a window model without state (two-stage, ``n_sharp = 0``): nothing to solve, ``ALGEBRAIC``;
- no measurement in the whole window (an outage longer than N): the model propagates the last
  estimate, ``PROPAGATED``;
- else the window problem, warm-started from the shifted last solution, retried once from a
  cold start: ``SOLVED``, or, if both fail, ``FAILED`` with the solver's status recorded and the
  model propagating the last estimate (``strict=True`` raises :class:`~uiest.errors.SolverError`
  instead);

then the *post-map* from the window's newest node to ``x_hat[k]`` (identity for the full-order
estimators; the two-stage UISE's projection, Eq. (35) of Guo et al.), the unknown-input estimate, the step's health
fields (:class:`~uiest.results.StepEstimate`: states at X's sides, the held input, ...) and the commit.
A run (:func:`collect_run`) warns (:class:`~uiest.errors.BoundWarning`) when a state's estimate lies at
a side of X in more than 5 % of the steps.
The window problem has one weight schedule (:class:`~uiest.estimators.weights.Schedule`),
passed as parameters, so a problem is built once per window length ``N_k = min(N, k)``.
Subclasses say which window model, which schedule, which nodes are measured and the post-map.

:class:`WindowOptions` holds how the problems are solved (backend, its options, warm start,
strictness, Gauss-Newton polishing) and the fixed lag of the smoothed estimate; change them
with :meth:`WindowEstimator.configure` (which drops the cached solvers).
"""

from __future__ import annotations

import contextlib
import dataclasses
import pickle
import time
import warnings
from collections import deque
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field, fields
from types import MappingProxyType
from typing import Any, ClassVar

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike, NDArray

from uiest.box import Box, FloatArray, as_vector
from uiest.checks import all_true, any_true, check_flag, user_stacklevel
from uiest.errors import BoundWarning, CertificationError, DataError, FailureWarning, OptionError, SolverError
from uiest.estimators.checks import held_on_boundary, window_bounds
from uiest.estimators.history import RowHistory
from uiest.estimators.horizon import InformationHorizon, information_horizon
from uiest.estimators.weights import Schedule
from uiest.guarantee import Guarantee
from uiest.health import BoundTest, Outcome, at_bound, bound_message, failure_message, input_bound_message
from uiest.results import HEALTH_FIELDS, EstimationResult, StepEstimate
from uiest.run_data import check_run_data, check_u_prev, check_y
from uiest.system import System
from uiest.window import DEFAULT_BACKEND, WindowModel, WindowProblem, WindowSolution, WindowSolver, make_solver
from uiest.window.backends import BACKENDS, MULTIPLIER_BACKENDS
from uiest.window.problem import WIDE, WindowTrajectory, WindowWeights
from uiest.window.size import check_horizon
from uiest.window.warmstart import predicted_guess, shifted_guess


@dataclass(frozen=True, kw_only=True)
class WindowOptions:
    """How an estimator solves its window problems, and the lag of its smoothed estimate.

    Every window estimator takes these either as keywords (``UISE(system, ..., solver="ipopt", lag=2)``) or as
    one object (``UISE(system, ..., window=WindowOptions(solver="ipopt", lag=2))``); they are checked here.

    Attributes
    ----------
    solver : str
        ``"gn"`` (Gauss-Newton SQP with IPOPT as its fallback), ``"ipopt"`` (the paper's
        solver), ``"rti"`` (one Gauss-Newton step per sample) or ``"gn-riccati"`` (Gauss-Newton with each QP
        solved by a stage-wise Riccati interior point, compiled by numba on its first use).
    solver_options : mapping
        Backend options (IPOPT options over :data:`uiest.window.IPOPT_DEFAULTS`, or keyword
        arguments of :class:`~uiest.window.gauss_newton.GaussNewtonSolver`).
    warm_start : bool
        Pass the shifted previous solution's multipliers to the backend (IPOPT's primal-dual warm start; the
        Gauss-Newton backends take none). Every backend starts from the shifted previous solution.
    strict : bool
        Raise :class:`~uiest.errors.SolverError` when a window problem is not solved.
    polish : bool
        Refine each window solution by Gauss-Newton steps (:mod:`uiest.window.polish`).
    lag : int
        ``d >= 0``: each step also delivers the window's estimate of ``x[k-d]`` (a fixed-lag
        smoother; ``EstimationResult.x_lag``). At most N.

    """

    solver: str = DEFAULT_BACKEND
    solver_options: Mapping[str, Any] = field(default_factory=dict)
    warm_start: bool = True
    strict: bool = False
    polish: bool = False
    lag: int = 0

    def __post_init__(self) -> None:
        if self.solver not in BACKENDS:
            raise OptionError(f"solver: unknown backend {self.solver!r}; expected one of {list(BACKENDS)}")
        if not isinstance(self.solver_options, Mapping):
            raise OptionError(f"solver_options: expected a mapping of backend options, got {self.solver_options!r}")
        object.__setattr__(self, "solver_options", MappingProxyType(dict(self.solver_options)))
        for name in ("warm_start", "strict", "polish"):
            object.__setattr__(self, name, check_flag(getattr(self, name), name))
        if isinstance(self.lag, bool) or not isinstance(self.lag, int | np.integer) or self.lag < 0:
            raise OptionError(f"lag: expected an integer >= 0, got {self.lag!r}")

    def __reduce__(self) -> tuple[Any, ...]:
        """Pickled (and deep-copied) by its fields, ``solver_options`` as a dict (a read-only view does not pickle)."""
        values = {f.name: getattr(self, f.name) for f in fields(self)}
        return (_window_options, (type(self), {**values, "solver_options": dict(self.solver_options)}))

    @classmethod
    def build(cls, values: Mapping[str, Any]) -> WindowOptions:
        """Options from keyword arguments, or the one given as ``window``; unknown names raise OptionError."""
        known = [f.name for f in fields(cls)]
        if "window" in values:
            window = values["window"]
            if not isinstance(window, WindowOptions):
                raise OptionError(f"window: expected a WindowOptions, got {type(window).__name__}")
            others = sorted(set(values) - {"window"})
            if others:
                raise OptionError(f"window: given together with {others}; put them in the WindowOptions")
            return window
        unknown = sorted(set(values) - set(known))
        if unknown:
            raise OptionError(f"options: unknown {unknown}; expected some of {known} (or window=WindowOptions(...))")
        return cls(**values)


@contextlib.contextmanager
def _casadi_context(kind: str) -> Iterator[None]:
    """CasADi's global (un)pickle context inside, and the one the caller may have entered restored after it.

    CasADi sets its context to None on leaving one, which would break a user's own context around the pickling.
    """
    local, name = getattr(ca.casadi, "_thread_local", None), f"casadi_{kind}_ctx"
    outer = getattr(local, name, None)
    with ca.global_pickle_context() if kind == "pickle" else ca.global_unpickle_context():
        yield
    if local is not None:
        setattr(local, name, outer)


def _window_options(cls: type[WindowOptions], values: dict[str, Any]) -> WindowOptions:
    """A pickled :class:`WindowOptions` built again from its fields."""
    return cls(**values)


@dataclass
class _Cached:
    """A window problem, its weights' part of ``p``, its v and w priors, its solvers (the cold one built on need)."""

    problem: WindowProblem
    weights: FloatArray
    v_bar: FloatArray
    w_bar: FloatArray
    warm: WindowSolver
    cold: WindowSolver | None = None
    parameters: FloatArray | None = None
    """The last window's ``p`` (its data replaced each step: the priors and weights stay)."""


class StreamingEstimator:
    """Time index, prior of x[0] and ``reset``, shared by every estimator.

    Subclasses hold ``system``, ``_x0_prior`` and ``_k`` and implement ``_clear()``.
    """

    system: System
    _x0_prior: FloatArray | None
    _k: int
    estimator_name: ClassVar[str]
    """The estimator's name in messages, results and reprs (each concrete estimator sets it)."""
    theorem: ClassVar[str] = "none"
    """The user-facing name of the theorem behind :attr:`guarantee`."""

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

    @property
    def guarantee(self) -> Guarantee:
        """What this configuration's theorem guarantees, per state in its units, or why none does."""
        return self._no_guarantee(self.theorem, "no theorem covers this estimator")

    @property
    def guaranteed(self) -> bool:
        """The theorem applies and bounds every state below X's width (:attr:`guarantee` ``.informative``).

        False as well when the theorem applies but its bound is vacuous for some state (no smaller than X's width
        there): ``guarantee.applies`` and ``guarantee.verdict`` tell the two apart.
        """
        return self.guarantee.informative

    def _no_guarantee(self, theorem: str, reason: str) -> Guarantee:
        x = self.system.x
        return Guarantee(theorem=theorem, applies=False, reason=reason, x_width=x.bounds.width, names=x.names,
                         units=x.units, **self._horizon_fields())  # fmt: skip

    def _horizon_fields(self) -> dict[str, Any]:
        """The guarantee's horizon fields (:class:`~uiest.guarantee.Guarantee`); none without a window."""
        return {}

    def _holds(self, theorem: str, bound: FloatArray, settling: int | None, assumes: str, note: str = "",
               condition: str = "") -> Guarantee:  # fmt: skip
        """The theorem's guarantee with a bound per state (NaN: none for that state, ``note`` says why).

        ``condition``: a hypothesis the text must name ("holds while ...").
        """
        x = self.system.x
        if not note and not np.all(np.isfinite(bound)):
            note = "the noise range V is unbounded"
        return Guarantee(theorem=theorem, applies=True, x_width=x.bounds.width, names=x.names, units=x.units,
                         error_bound=bound, settling_steps=settling, bound_note=note, condition=condition,
                         assumes=f"{assumes}; settling counted from an initial error up to X's width in every "
                         "state", **self._horizon_fields())  # fmt: skip

    def _require_prior(self) -> FloatArray:
        if self._x0_prior is None:
            raise OptionError("x0_prior: required; pass it to the constructor or call reset(x0_prior) first")
        return self._x0_prior


GAP_WEIGHT = 1e-6
"""A window with missing outputs (UISE, FIE) penalises each unknown input's departure from where the last window
left it by this fraction of the curvature the next node's outputs put on it (:meth:`_gap_weights`): directions
the missing outputs alone saw are otherwise flat, and a solver may put them anywhere in X (a state 9.6 off in an
X of width 20, an input estimate 8.9 off); along the determined directions it moves the optimum by about this
fraction of the input's change."""

NO_PROBLEM = frozenset({Outcome.PRIOR, Outcome.ALGEBRAIC})
"""Outcomes of steps that had no window problem to solve (their cost is 0)."""

HOLD_RTOL = 1e-9
"""Relative rank tolerance of :meth:`WindowEstimator._hold_unseen_input` (linear_strong_detectability's default)."""


class WindowEstimator(StreamingEstimator):
    """The window-estimator template (module docstring); not used directly."""

    estimator_name: ClassVar[str] = "window"
    one_step_ahead: ClassVar[bool] = False
    """True: the window at time k measures ``y[k-N_k .. k-1]`` (its newest node is a prediction)."""
    free_input: ClassVar[bool] = False
    """The newest unknown input is unpenalised and the nodes are the states (UISE, FIE): a y[k] that misses the
    outputs it reaches leaves x[k] free along its direction (:meth:`_hold_unseen_input`)."""
    status_note: str = ""
    """Why a forced estimator carries no guarantee (" [no guarantee: ...]"; its :attr:`guarantee` says so)."""
    _last: tuple[int, WindowProblem, WindowSolution, WindowTrajectory | None] | None
    """The newest solved window: (its first time index, its problem, its solution, the solution unpacked or None);
    None before one."""

    def __getstate__(self) -> dict[str, Any]:
        """The estimator's attributes, pickled in CasADi's pickle context (its window problems hold SX expressions).

        So a window estimator pickles and deep-copies mid-run, and the copy goes on as the original would.
        """
        with _casadi_context("pickle"):
            return {"attributes": pickle.dumps(self.__dict__)}

    def __setstate__(self, state: dict[str, Any]) -> None:
        with _casadi_context("unpickle"):
            self.__dict__.update(pickle.loads(state["attributes"]))

    def __init__(
        self,
        system: System,
        model: WindowModel,
        *,
        schedule: Schedule | None,
        N: int | None,
        x0_prior: ArrayLike | None,
        v_prior: ArrayLike | None,
        options: Mapping[str, Any],
        w_box: Box | None = None,
        w_prior: FloatArray | None = None,
        start_schedules: Sequence[Schedule] = (),
    ) -> None:
        self.information_horizon: InformationHorizon | None = (
            None if schedule is None else information_horizon(schedule, model, one_step_ahead=self.one_step_ahead)
        )
        """Where the window's oldest cost terms fall below double precision (None: a model without state)."""
        if N is not None:
            N = check_horizon(N, "N", model)
            self.requested_N: int | None = N
            """The horizon asked for; :attr:`N` is the one used (capped at the information horizon)."""
            N = N if self.information_horizon is None else self.information_horizon.cap(N)
        else:
            self.requested_N = None
        self.system, self.model, self.schedule, self.N = system, model, schedule, N
        self.start_schedules = tuple(start_schedules)
        """``start_schedules[s]``: the weights of the window that starts at time s; later ones: :attr:`schedule`."""
        self.w_box = w_box
        self.w_prior = model.nominal_w if w_prior is None else w_prior
        v_bar = np.zeros(system.nv) if v_prior is None else as_vector(v_prior, system.nv, "v_prior")
        if not system.v.bounds.contains(v_bar):
            raise DataError(f"v_prior: expected a point in V = {system.v.bounds}, got {v_bar.tolist()}")
        self.v_prior = v_bar
        self._x_at_bound = BoundTest(system.x.bounds, system.x.scale)
        self._window_at_bound = BoundTest(model.x_bounds, model.x_scale)
        self._options = self._checked(WindowOptions.build(options))
        self._cache: dict[int | tuple[int, str], _Cached] = {}
        self._x0_prior: FloatArray | None = None
        self._clear()
        if x0_prior is not None:
            self.reset(x0_prior)

    def reset(self, x0_prior: ArrayLike | None = None) -> None:
        """Start over at k = 0 (see :meth:`StreamingEstimator.reset`); warns when X's scales dwarf the prior."""
        super().reset(x0_prior)
        if x0_prior is not None:
            magnitude = max(float(np.max(np.abs(self._require_prior()), initial=0.0)), 1.0)
            ratio = float(np.max(self.system.x.scale)) / magnitude
            if ratio > WIDE:
                warnings.warn(
                    f"x_scale: the largest state scale ({np.max(self.system.x.scale):.3g}, X's width unless given) "
                    f"is {ratio:.3g} times the prior's magnitude; a window solve resolves about 1e-8 of a scale. Give "
                    "scales for the accuracy you need (System.with_scales, or x_scale= when building the system)",
                    UserWarning,
                    stacklevel=user_stacklevel(),
                )

    # ------------------------------------------------------------------ options
    @property
    def options(self) -> WindowOptions:
        """How the window problems are solved (read-only; see :meth:`configure`)."""
        return self._options

    def configure(self, **changes: Any) -> None:
        """Change options (``solver``, ``solver_options``, ``warm_start``, ``strict``, ``polish``, ``lag``).

        The cached solvers are dropped, so the change applies from the next step on.
        """
        if "window" in changes:  # a whole WindowOptions replaces the current one (given alone, as in build)
            self._options = self._checked(WindowOptions.build(changes))
        else:
            self._options = self._checked(WindowOptions.build({**_as_dict(self._options), **changes}))
        self._cache.clear()
        self._last = None

    def _checked(self, options: WindowOptions) -> WindowOptions:
        if self.N is not None and options.lag > self.N:
            raise OptionError(
                f"lag: expected 0 <= lag <= N = {self.N} (the window holds x[k-N .. k]), got {options.lag}"
            )
        return options

    # ------------------------------------------------------------------ guarantee
    @property
    def horizon_capped(self) -> bool:
        """Whether :attr:`N` (the window used) is shorter than the one asked for, at the information horizon."""
        return self.requested_N is not None and self.N is not None and self.requested_N > self.N

    def _horizon_fields(self) -> dict[str, Any]:
        info = self.information_horizon
        return {
            "horizon": self.N,
            "requested_horizon": self.requested_N,
            "information_horizon": None if info is None else info.horizon,
        }

    def _horizon_missing(self, certificate_kind: str, horizon_eq: str) -> str:
        """Why the weights and N do not meet the theorem (no certificate, N below ``min_horizon()``); "" if they do."""
        certificate = getattr(self, "certificate", None)
        if certificate is None:
            return f"explicit weights without a {certificate_kind} certificate"
        n_min = certificate.min_horizon()
        if self.N is not None and n_min > self.N:
            if self.horizon_capped:
                return (f"the weights' information horizon N={self.N} is below min_horizon()={n_min} ({horizon_eq}): "
                        "a longer window would not help; weights spanning fewer orders of magnitude would")  # fmt: skip
            return f"N={self.N} < min_horizon()={n_min}, too short for {horizon_eq}"
        return ""

    # ------------------------------------------------------------------ state
    def _clear(self) -> None:
        for entry in self._cache.values():  # the problems and solvers stay built; what solves left is forgotten
            for solver in (entry.warm, entry.cold):
                if solver is not None:
                    solver.reset()
        maxlen = self.N
        self._k = 0
        self._u = RowHistory(self.system.nu, maxlen)
        self._y = RowHistory(self.system.ny, maxlen)
        self._data = RowHistory(self.model.nd, maxlen)
        self._priors: deque[FloatArray] = deque(maxlen=maxlen)
        self._last = None
        self._x_last: FloatArray | None = None
        self._node_last: FloatArray | None = None
        self._w_last: FloatArray | None = None

    # ------------------------------------------------------------------ hooks of the subclasses
    def _node_of(self, x: FloatArray) -> FloatArray:
        """The window model's state of a full state (the prior of the first window)."""
        return x

    def _to_state(
        self, node: FloatArray, y: FloatArray, u_prev: FloatArray, k: int, window: WindowTrajectory | None
    ) -> tuple[FloatArray, FloatArray]:
        """The post-map: ``(x_hat[k], node data of k)`` from the newest node, ``y[k]`` and the window."""
        return node, np.zeros(0)

    def _node_state(self, window: WindowTrajectory, j: int, data: FloatArray) -> FloatArray:
        """The full state of window node ``j`` (negative: from the newest) with its node data (lagged estimates)."""
        return window.x[j]

    def _held_in_post_map(self) -> bool:
        """The last :meth:`_to_state` held the unknown input (filled missing outputs with its last estimate)."""
        return False

    def _w_estimate(
        self, window: WindowTrajectory | None, x_hat: FloatArray, u_prev: FloatArray, k: int
    ) -> tuple[FloatArray | None, int | None]:
        """The newest unknown-input estimate a measurement informs, and its time index."""
        back = 2 if self.one_step_ahead else 1
        if k < back:
            return None, None
        if window is None:
            return self._w_guess().copy(), k - back
        return window.w[-back].copy(), k - back

    # ------------------------------------------------------------------ problems
    def _cached(self, length: int, gap: bool = False) -> _Cached:
        """The window problem of ``length`` transitions and its solvers; ``gap``: with :data:`GAP_WEIGHT` on w."""
        key: int | tuple[int, str] = (length, "gap") if gap else length
        entry = self._cache.get(key)
        if entry is None:
            assert self.schedule is not None  # models with state have weights
            measured = list(range(length if self.one_step_ahead else length + 1))
            weights = self.schedule.window(length, measured)
            if gap:  # the structure; each solve passes weights at its own gain
                weights = self._gap_weights(weights, length, 1.0)
            problem = WindowProblem(self.model, length, measured, weights, w_box=self.w_box)
            opts = self._options
            warm = make_solver(opts.solver, problem, warm_start=opts.warm_start, options=dict(opts.solver_options),
                               polish=opts.polish)  # fmt: skip
            v_bar, w_bar = np.tile(self.v_prior, (problem.n_meas, 1)), np.tile(self.w_prior, (length, 1))
            entry = _Cached(
                problem, problem.weight_vector(weights), v_bar, w_bar, warm, None if opts.warm_start else warm
            )
            self._cache[key] = entry
        return entry

    def _gap_weights(self, weights: WindowWeights, length: int, gain: float) -> WindowWeights:
        """``weights`` with w[j] pulled to ``w_bar`` by ``GAP_WEIGHT`` of the curvature node j+1's output puts on it.

        That curvature is the node's mean scaled output weight times ``gain`` (:meth:`_input_gain`).
        """
        y_scale, w_scale = self.model.y_scale, self.model.w_scale
        scaled_y = np.einsum("mii->m", weights.y * np.outer(y_scale, y_scale)) / max(self.model.ny, 1)
        level = GAP_WEIGHT * gain * scaled_y[1 : length + 1]
        return dataclasses.replace(weights, w=level[:, None, None] * np.diag(1.0 / w_scale**2)[None])

    def _input_gain(self, window: WindowTrajectory, u_last: FloatArray) -> float:
        """``|G|^2``, G the scaled ``C B_w`` of the window's newest transition: the output's sensitivity to the input.

        In scales; 1 where it is not finite or zero (a square root at a side of X, an input that vanishes there).
        """
        G = self._newest_input_effect(window, u_last) * self.model.w_scale / self.model.y_scale[:, None]
        gain = float(np.linalg.norm(G, 2)) ** 2
        return gain if np.isfinite(gain) and gain > 0.0 else 1.0

    def _newest_input_effect(self, window: WindowTrajectory, u_last: FloatArray) -> FloatArray:
        """``C B_w`` (ny, nw): the output Jacobian at the window's newest node times the input Jacobian before it."""
        s = self.system
        return s.linearize(window.x[-1], u_last, window.w[-1]).C @ s.linearize(window.x[-2], u_last, window.w[-1]).B_w

    def _cold(self, entry: _Cached) -> WindowSolver:
        if entry.cold is None:
            opts = self._options
            entry.cold = make_solver(opts.solver, entry.problem, warm_start=False, options=dict(opts.solver_options),
                                     polish=opts.polish)  # fmt: skip
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
            One-step-ahead estimators store ``y[k]`` and use it in the window from step k+1 on.

        Returns
        -------
        StepEstimate

        """
        x0_prior = self._require_prior()
        k = self._k
        u_vec = check_u_prev(self.system, u_prev, k)
        y_vec = check_y(self.system, y)
        length, start = window_bounds(k, self.N)
        u_win = self._u.last_and(length - 1, u_vec) if length else np.zeros((0, self.system.nu))
        y_win = self._y.last(length) if self.one_step_ahead else self._y.last_and(length, y_vec)
        prior = self._node_of(x0_prior) if start == 0 else self._priors[0]
        attempts: list[WindowSolution] = []
        window, held = None, False
        if len(y_win) == 0:
            node, outcome = prior.copy(), Outcome.PRIOR
        elif self.model.nx == 0:  # nothing to estimate by optimisation (two-stage, n_sharp = 0)
            node, outcome, length = np.zeros(0), Outcome.ALGEBRAIC, 0
        elif all_true(np.isnan(y_win)):  # an outage longer than the window: bridge it with the model
            node, outcome = self._propagate(u_vec), Outcome.PROPAGATED
        else:
            data = self._window_data(length)
            own = self.start_schedules[start] if start < len(self.start_schedules) else None
            entry, attempts = self._solve_window(length, prior, u_win, y_win, data, own)
            solution = attempts[-1]
            if solution.success:
                unpacked = entry.problem.unpack(solution.z)
                for part in (unpacked.x, unpacked.w, unpacked.v):  # the next step's guess shifts it: kept as it is
                    part.setflags(write=False)
                window, held = self._hold_unseen_input(unpacked, u_vec, y_vec)
                node, outcome = window.x[-1].copy(), Outcome.SOLVED
                if held:  # later windows start from the held values: their optimum is flat there too
                    solution = dataclasses.replace(solution, z=entry.problem.pack(window))
                self._last = (start, entry.problem, solution, None if held else unpacked)
            elif self._options.strict:
                raise SolverError(
                    f"step k={k}: the window problem ({length} transitions) was not solved: "
                    f"{' / '.join(a.status for a in attempts)}"
                )
            else:
                node, outcome = self._propagate(u_vec), Outcome.FAILED
        return self._finish(k, u_vec, y_vec, node, outcome, attempts, window, length, held=held)

    def _hold_unseen_input(
        self, window: WindowTrajectory, u_vec: FloatArray, y_vec: FloatArray
    ) -> tuple[WindowTrajectory, bool]:
        """The window with the part of the newest unknown input that y[k]'s missing outputs alone would see held.

        With ``G = C B_w`` (output Jacobian at x[k] times the input Jacobian at x[k-1]), the input
        directions that ``G`` sees but its observed rows do not are free in the window's optimum:
        they are set to the last estimate's, the rest kept, and x[k] predicted from x[k-1] with the
        result. Ranks by ``HOLD_RTOL`` of G's largest singular value. Returns (window, whether it held).
        """
        missing = np.isnan(y_vec)
        if not (self.free_input and any_true(missing) and len(window.w)):
            return window, False
        G = self._newest_input_effect(window, u_vec)
        values = np.linalg.svd(G, compute_uv=False)
        if not values.size or values[0] == 0.0:
            return window, False
        tol = HOLD_RTOL * values[0]
        unseen = np.eye(G.shape[1])  # the null space of the observed rows
        if (~missing).any():
            _, seen_values, seen_vt = np.linalg.svd(G[~missing])
            unseen = seen_vt[int(np.sum(seen_values > tol)) :].T
        if not unseen.shape[1]:
            return window, False
        _, reach, directions = np.linalg.svd(G @ unseen)
        held = unseen @ directions[: int(np.sum(reach > tol))].T  # of those, what all rows would see
        if not held.size:
            return window, False
        w = window.w.copy()
        w[-1] = w[-1] + held @ (held.T @ (self._w_guess() - w[-1]))
        data = self._data[-1] if self.model.nd else np.zeros(0)
        x_new = self.model.step(window.x[-2], u_vec, w[-1], self.v_prior, data)
        if not np.all(np.isfinite(x_new)):
            return window, False
        x = window.x.copy()
        x[-1] = self.model.x_bounds.clip(x_new)
        return WindowTrajectory(x, w, window.v), True

    def _finish(
        self,
        k: int,
        u_vec: FloatArray,
        y_vec: FloatArray,
        node: FloatArray,
        outcome: Outcome,
        attempts: list[WindowSolution],
        window: WindowTrajectory | None,
        length: int,
        *,
        held: bool = False,
        reason: str = "",
    ) -> StepEstimate:
        """Post-map, unknown-input estimate, lagged estimate, health fields; store step k and move to k + 1."""
        x_hat, data_k = self._to_state(node, y_vec, u_vec, k, window)
        held = held or self._held_in_post_map()
        w_hat, w_index = self._w_estimate(window, x_hat, u_vec, k)
        x_lag = self._lagged(window, x_hat, data_k, k)
        self._commit(k, u_vec, y_vec, node, data_k, x_hat, w_hat)
        last = attempts[-1] if attempts else None
        states_at_bound = self._x_at_bound(x_hat)
        solved = outcome is Outcome.SOLVED
        window_held = window is not None and self._window_at_bound.any(window.x)
        return StepEstimate(
            k=k,
            x_hat=x_hat,
            w_hat=w_hat,
            w_index=w_index,
            outcome=outcome,
            iterations=sum([a.iterations for a in attempts]),
            solve_time=sum([a.solve_time for a in attempts]),
            cost=last.cost if solved and last is not None else (0.0 if outcome in NO_PROBLEM else float("nan")),
            window=length,
            missing=np.isnan(y_vec),
            at_bound=states_at_bound,
            solver_status=last.status if last is not None else "",
            fallback=bool(last is not None and last.fallback),
            primary_status=last.primary_status if last is not None else "",
            reason=reason,
            held_input=held,
            on_boundary=any_true(states_at_bound) and held_on_boundary(self.system, x_hat, y_vec, self.v_prior),
            window_at_bound=window_held,
            trajectory=window,
            x_lag=x_lag,
        )

    def _lagged(
        self, window: WindowTrajectory | None, x_hat: FloatArray, data_k: FloatArray, k: int
    ) -> FloatArray | None:
        """The window's estimate of ``x[k-lag]`` (None before time lag; NaN without a window solution)."""
        lag = self._options.lag
        if lag == 0:
            return x_hat
        if k < lag:
            return None
        if window is None or len(window.x) <= lag:
            return np.full(self.system.nx, np.nan)
        data = self._data[-lag] if self.model.nd else np.zeros(0)
        return self._node_state(window, -1 - lag, data)

    def _commit(
        self,
        k: int,
        u_vec: FloatArray,
        y_vec: FloatArray,
        node: FloatArray,
        data_k: FloatArray,
        x_hat: FloatArray,
        w_hat: FloatArray | None,
    ) -> None:
        if k > 0:
            self._u.append(u_vec)
        self._y.append(y_vec)
        self._data.append(data_k)
        self._priors.append(node.copy())
        self._node_last, self._x_last = node, x_hat
        if w_hat is not None:
            self._w_last = w_hat
        self._k = k + 1

    def skip(self, u_prev: ArrayLike | None, y: ArrayLike, reason: str) -> StepEstimate:
        """Step k without solving: the model propagates the last estimate; outcome ``ERROR`` with ``reason``.

        :func:`collect_run` calls it when :meth:`step` raised unexpectedly, so that a run keeps
        what it computed and goes on.
        """
        self._require_prior()
        k = self._k
        u_vec = check_u_prev(self.system, u_prev, k)
        y_vec = check_y(self.system, y)
        node = self._propagate(u_vec)
        try:
            return self._finish(k, u_vec, y_vec, node, Outcome.ERROR, [], None, 0, reason=reason)
        except Exception:
            x_hat = self._x0_prior if self._x_last is None else self._x_last
            assert x_hat is not None
            data_k = np.where(np.isnan(y_vec), self.system.output(x_hat, self.v_prior), y_vec)[: self.model.nd]
            self._commit(k, u_vec, y_vec, node, data_k, x_hat, None)
            return StepEstimate(
                k=k,
                x_hat=x_hat.copy(),
                w_hat=None,
                w_index=None,
                outcome=Outcome.ERROR,
                iterations=0,
                solve_time=0.0,
                cost=float("nan"),
                window=0,
                missing=np.isnan(y_vec),
                at_bound=at_bound(self.system.x.bounds, x_hat, self.system.x.scale),
                reason=reason,
            )

    def _propagate(self, u_prev: FloatArray) -> FloatArray:
        """The model's step from the last node (the prior at k = 0), clipped to its bounds; held if not finite."""
        if self._node_last is None:
            return self._node_of(self._require_prior()).copy()
        data = self._data[-1] if self.model.nd else np.zeros(0)
        nxt = self.model.step(self._node_last, u_prev, self._w_guess(), self.v_prior, data)
        return self.model.x_bounds.clip(nxt) if np.all(np.isfinite(nxt)) else self._node_last.copy()

    def _window_data(self, length: int) -> FloatArray | None:
        """Node data of the window (the stored data of k-N_k .. k-1, zeros at node k); None without."""
        if not self.model.nd:
            return None
        return np.concatenate((self._data.last(length), np.zeros((1, self.model.nd))))

    def _solve_window(
        self,
        length: int,
        prior: FloatArray,
        u_win: FloatArray,
        y_win: FloatArray,
        data: FloatArray | None,
        own: Schedule | None = None,
    ) -> tuple[_Cached, list[WindowSolution]]:
        """Warm start from the shifted last solution, one cold retry; returns the entry and the attempts.

        ``own``: this window's weights where they are not :attr:`schedule`'s (:attr:`start_schedules`).
        """
        gap = self.free_input and length > 0 and not self.one_step_ahead and any_true(np.isnan(y_win))
        entry = self._cached(length, gap)
        problem = entry.problem
        z0, duals = self._guess(problem, length, prior, u_win, data)
        w_bar, weights = entry.w_bar, entry.weights
        schedule = own or self.schedule
        assert schedule is not None  # models with state have weights
        if own is not None and not gap:
            measured = range(length if self.one_step_ahead else length + 1)
            weights = problem.weight_vector(own.window(length, measured))
        if gap:  # the flat inputs stay where the last window left them
            start = problem.unpack(z0)
            w_bar = start.w
            gain = self._input_gain(start, u_win[-1])
            weights = problem.weight_vector(self._gap_weights(schedule.window(length, range(length + 1)), length,
                                                              gain))  # fmt: skip
        if gap or own is not None or entry.parameters is None:
            p = problem.parameters(prior, u_win, y_win, v_bar=entry.v_bar, w_bar=w_bar, data=data, weights=weights)
            if not gap and own is None:
                entry.parameters = p.copy()
        else:
            p = problem.with_data(entry.parameters, prior, u_win, y_win, data)
        attempts = [entry.warm.solve(z0, p, *(duals or (None, None)))]
        if not attempts[-1].success:
            cold_guess = predicted_guess(problem, prior, u_win, self._w_guess(), self.v_prior, data)
            attempts.append(self._cold(entry).solve(cold_guess, p))
        return entry, attempts

    # ------------------------------------------------------------------ guesses
    def _w_guess(self) -> FloatArray:
        return self._w_last if self._w_last is not None and self.model.nw else self.w_prior

    def _guess(
        self, problem: WindowProblem, length: int, prior: FloatArray, u_win: FloatArray, data: FloatArray | None
    ) -> tuple[FloatArray, tuple[FloatArray, FloatArray] | None]:
        """The last successful solution shifted onto the new window, else a prediction from the prior."""
        if self._last is not None:
            old_start, old_problem, old_solution, old_trajectory = self._last
            shift = self._k - length - old_start
            shifted = shifted_guess(old_problem, old_solution, problem, shift, u_win, self._w_guess(), self.v_prior,
                                    duals=self._takes_multipliers(), data=data,
                                    old_trajectory=old_trajectory)  # fmt: skip
            if shifted is not None:
                return shifted
        return predicted_guess(problem, prior, u_win, self._w_guess(), self.v_prior, data), None

    def _takes_multipliers(self) -> bool:
        """Whether the shifted multipliers are passed to the backend (``warm_start``, a backend that takes them)."""
        return self._options.warm_start and self._options.solver in MULTIPLIER_BACKENDS

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


def _as_dict(options: WindowOptions) -> dict[str, Any]:
    return {f.name: getattr(options, f.name) for f in fields(options)}


def collect_run(estimator: Any, u_arr: FloatArray, y_arr: FloatArray) -> EstimationResult:
    """Call ``estimator.step`` for k = 0..K on checked data and gather an :class:`EstimationResult`.

    ``estimator`` needs ``system``, ``step(u_prev, y) -> StepEstimate``, ``estimator_name``, ``N``
    and ``guarantee``; the caller has reset it. ``x_lag[j]`` is the estimate of ``x[j]`` delivered at
    step ``j + lag`` (NaN for the last ``lag`` rows). Warns (:class:`~uiest.errors.BoundWarning`,
    :func:`uiest.health.bound_message`) when a state's estimate lies at a side of X in more than 5 %
    of the steps, and (:func:`uiest.health.input_bound_message`) when an unknown input's estimate lies at a side of
    the estimator's ``w_domain`` (where it has one: the smooth-input MHE's W) in more than 5 % of them.
    """
    K = y_arr.shape[0] - 1
    s = estimator.system
    options = getattr(estimator, "options", None)
    lag = options.lag if options is not None else 0
    strict = options.strict if options is not None else True
    x_hat = np.empty((K + 1, s.nx))
    x_lag = np.full((K + 1, s.nx), np.nan)
    w_hat = np.full((K, s.nw), np.nan)
    outcome: list[str] = []
    iterations = np.zeros(K + 1, dtype=np.int64)
    solve_time, cost, cpu_time = np.zeros(K + 1), np.zeros(K + 1), np.zeros(K + 1)
    window = np.zeros(K + 1, dtype=np.int64)
    states_at_bound = np.zeros((K + 1, s.nx), dtype=bool)
    health: dict[str, list[Any]] = {name: [] for name in HEALTH_FIELDS}
    for k in range(K + 1):
        u_prev = None if k == 0 else u_arr[k - 1]
        start = time.thread_time()
        try:
            est = estimator.step(u_prev, y_arr[k])
        except (OptionError, CertificationError):  # the configuration is wrong: no step will do better
            raise
        except Exception as exc:  # recorded; the run keeps what it computed and goes on
            if strict or not hasattr(estimator, "skip"):
                raise
            est = estimator.skip(u_prev, y_arr[k], f"{type(exc).__name__}: {exc}")
        cpu_time[k] = time.thread_time() - start
        x_hat[k] = est.x_hat
        if est.x_lag is not None:
            x_lag[k - lag] = est.x_lag
        if est.w_hat is not None and est.w_index is not None:
            w_hat[est.w_index] = est.w_hat
        outcome.append(est.outcome.value)
        iterations[k], solve_time[k] = est.iterations, est.solve_time
        cost[k], window[k] = est.cost, est.window
        states_at_bound[k] = est.at_bound
        for name, values in health.items():
            values.append(getattr(est, name))
    message = bound_message(estimator.estimator_name, states_at_bound, x_hat, s.x.bounds, s.x.names,
                            constrained=isinstance(estimator, WindowEstimator))  # fmt: skip
    if message is not None:
        warnings.warn(message, BoundWarning, stacklevel=user_stacklevel())
    message = failure_message(estimator.estimator_name, outcome)
    if message is not None:
        warnings.warn(message, FailureWarning, stacklevel=user_stacklevel())
    W = getattr(estimator, "w_domain", None)  # an estimator whose model bounds the unknown input
    if W is not None:
        message = input_bound_message(estimator.estimator_name, at_bound(W, w_hat, s.w.scale), w_hat, W, s.w.names)
        if message is not None:
            warnings.warn(message, BoundWarning, stacklevel=user_stacklevel())
    return EstimationResult(
        t=np.arange(K + 1) * s.dt,
        x_hat=x_hat,
        w_hat=w_hat,
        outcome=np.array(outcome),
        iterations=iterations,
        solve_time=solve_time,
        cost=cost,
        window=window,
        missing=np.isnan(y_arr),
        estimator=estimator.estimator_name,
        horizon=estimator.N,
        guarantee=estimator.guarantee.for_run(_breaks_assumptions(outcome, y_arr), outside=health["on_boundary"]),
        names={"x": s.x.names, "w": s.w.names},
        time_unit=s.time_unit,
        x_lag=x_lag if lag else None,
        lag=lag,
        one_step_ahead=bool(getattr(estimator, "one_step_ahead", False)),
        at_bound=states_at_bound,
        **{name: np.array(values, dtype=HEALTH_FIELDS[name]) for name, values in health.items()},
        cpu_time=cpu_time,
    )


def _breaks_assumptions(outcome: list[str], y: FloatArray) -> NDArray[np.bool_]:
    """(K+1,) bool: the steps whose data or solve break what a guarantee's bound assumes.

    Every output measured, every window solved: a missing output, or an outcome other than solved, updated, the
    prior or algebraic.
    """
    unbroken = {Outcome.SOLVED.value, Outcome.UPDATED.value, Outcome.PRIOR.value, Outcome.ALGEBRAIC.value}
    return np.isnan(y).any(axis=1) | np.array([value not in unbroken for value in outcome], dtype=bool)


__all__ = ["StreamingEstimator", "WindowEstimator", "WindowOptions", "collect_run"]
