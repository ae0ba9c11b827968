"""Result containers: frozen dataclasses of time-first arrays.

:class:`Trajectory` (a simulated or measured record), and what the estimators return:
:class:`StepEstimate` per step, :class:`EstimationResult` per run.
"""

from __future__ import annotations

import re
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field
from os import PathLike
from pathlib import Path
from types import MappingProxyType
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from uiest.box import FloatArray
from uiest.checks import real_array, shown
from uiest.errors import DataError
from uiest.guarantee import Guarantee
from uiest.health import FAILURES, Outcome, status_text
from uiest.sampling import on_time_grid, warn_absent, warn_text_as_missing
from uiest.system import System

if TYPE_CHECKING:
    import pandas as pd

    from uiest.window.problem import WindowTrajectory

__all__ = ["HEALTH_FIELDS", "EstimationResult", "StepEstimate", "Trajectory", "count_names", "read_record"]


_NOT_GIVEN: NDArray[Any] = np.zeros(0)
_NOT_GIVEN.setflags(write=False)


def _not_given() -> NDArray[Any]:
    """The default of a per-step field that ``__post_init__`` fills in (told apart by identity, as None is)."""
    return _NOT_GIVEN


def _freeze(array: FloatArray, name: str) -> FloatArray:
    out = real_array(array, name, "an array of real numbers")
    out.setflags(write=False)
    return out


class _PicklableNames:
    """Pickling for frozen records whose ``names`` is a read-only mapping (sent to worker processes)."""

    def __getstate__(self) -> dict[str, Any]:
        state = dict(self.__dict__)
        state["names"] = dict(state["names"])
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        for key, value in state.items():
            if isinstance(value, np.ndarray):
                value.setflags(write=False)
            object.__setattr__(self, key, MappingProxyType(value) if key == "names" else value)


@dataclass(frozen=True, eq=False, kw_only=True)
class Trajectory(_PicklableNames):
    """A simulated trajectory of ``x[k+1] = f(x[k], u[k], w[k]), y[k] = h(x[k], v[k])``.

    Index convention: ``u[k]`` and ``w[k]`` act between ``k`` and ``k+1``; ``x[k]``, ``v[k]``,
    ``y[k]`` belong to time ``t[k] = k dt``.

    Attributes
    ----------
    t : ndarray, shape (K+1,)
    x : ndarray, shape (K+1, nx)
    u : ndarray, shape (K, nu)
    w : ndarray, shape (K, nw)
    v : ndarray, shape (K+1, nv)
    y : ndarray, shape (K+1, ny)
    names : mapping from "x", "u", "w", "v", "y" to the component names
    system_name : str
    seed : int or None
        The seed the noise was drawn with.
    x_outside : ndarray, shape (K+1,) of bool
        Where the state left the domain X (estimators constrain their estimates to X).
    v_outside : ndarray, shape (K+1,) of bool
        Where the noise left its domain V.

    """

    t: FloatArray
    x: FloatArray
    u: FloatArray
    w: FloatArray
    v: FloatArray
    y: FloatArray
    names: Mapping[str, tuple[str, ...]] = field(default_factory=dict)
    system_name: str = "system"
    seed: int | None = None
    time_unit: str = "s"
    x_outside: NDArray[np.bool_] = field(default_factory=_not_given)
    v_outside: NDArray[np.bool_] = field(default_factory=_not_given)

    def __post_init__(self) -> None:
        for name in ("t", "x", "u", "w", "v", "y"):
            object.__setattr__(self, name, _freeze(getattr(self, name), name))
        if self.t.ndim != 1 or self.t.size < 1:
            raise DataError(f"t: expected shape (K+1,) with K+1 >= 1, got {self.t.shape}")
        samples = self.t.size
        for name in ("x", "u", "w", "v", "y"):
            arr, rows = getattr(self, name), samples - 1 if name in ("u", "w") else samples
            if arr.ndim != 2 or arr.shape[0] != rows:
                wanted = f"({'K' if rows < samples else 'K+1'}, n{name})"
                raise DataError(f"{name}: expected shape {wanted} with K+1 = len(t) = {samples}, got {arr.shape}")
        for name in ("x_outside", "v_outside"):
            value = getattr(self, name)
            given = value is not None and value is not _NOT_GIVEN
            flags = np.array(value, dtype=bool) if given else np.zeros(self.t.shape[0], dtype=bool)
            if flags.shape != self.t.shape:
                raise DataError(f"{name}: expected shape {self.t.shape} (one flag per time index), got {flags.shape}")
            flags.setflags(write=False)
            object.__setattr__(self, name, flags)
        object.__setattr__(self, "names", MappingProxyType({k: tuple(v) for k, v in self.names.items()}))

    @property
    def steps(self) -> int:
        """Number of transitions K."""
        return int(self.u.shape[0])

    @property
    def has_states(self) -> bool:
        """Whether the record holds true states (a simulation, or measured truth columns)."""
        return bool(self.x.size) and not np.all(np.isnan(self.x))

    @classmethod
    def from_pandas(cls, frame: pd.DataFrame, system: Any) -> Trajectory:
        """A measured or simulated record of ``system`` from a table, one row per time index k = 0..K.

        Columns are named by the system's signals (``system.y.names`` etc., as :meth:`to_pandas`
        writes them). Required: every output (NaN = missing) and, when ``nu > 0``, every known
        input in rows 0..K-1 (the last row's u is not used). Optional: ``t`` (numbers in the
        model's time unit, spaced by dt; default ``k dt``), the states, unknown inputs and noise
        (NaN when absent: measured data has no truth). Rows are placed by ``t``, else by an index
        named ``k``: samples absent from either are kept as missing (rows of NaN, with a warning;
        :func:`uiest.sampling.on_time_grid`), and a table with neither is taken as contiguous, with
        a warning. A time column under another name (``time``, ``timestamp``, ...) is refused when
        ``t`` is absent, since without times a dropped row would shift every later sample; other
        columns are ignored with a warning.
        """
        if not isinstance(system, System):
            raise DataError(f"system: expected a uiest.System (uiest.models.get(name).build() for a name), got "
                            f"{shown(system)}")  # fmt: skip
        import pandas as pd  # imported when used: pandas takes most of `import uiest`'s time otherwise

        if not isinstance(frame, pd.DataFrame):
            raise DataError(f"frame: expected a pandas DataFrame, got {type(frame).__name__}")
        if len(frame) < 1:
            raise DataError("frame: expected at least one row (time index k = 0)")
        _check_columns(frame, system)
        frame, filled = on_time_grid(frame, system)
        rows = len(frame)
        arrays: dict[str, FloatArray] = {}
        for sig in system.signals:
            present = [n for n in sig.names if n in frame.columns]
            required = sig.kind == "y" or (sig.kind == "u" and sig.size > 0)
            if required and len(present) < sig.size:
                missing = [n for n in sig.names if n not in frame.columns]
                raise DataError(f"frame: missing {sig.kind} columns {missing} (has {list(frame.columns)})")
            if present and len(present) < sig.size:
                raise DataError(f"frame: {sig.kind} columns must be all present or all absent, got only {present}")
            if present:
                _check_numbers(frame, sig.names, sig.kind)
            data = (
                real_array(frame[list(sig.names)].to_numpy(), f"frame[{sig.kind}]", "real numbers")
                if present else np.full((rows, sig.size), np.nan)
            )  # fmt: skip
            arrays[sig.kind] = data[:-1] if sig.kind in ("u", "w") else data
        if not np.all(np.isfinite(arrays["u"])):
            bad = int(np.argwhere(~np.isfinite(arrays["u"]))[0][0])
            why = "is absent from the record (a gap in k or t)" if bad in filled else f"has {arrays['u'][bad]}"
            raise DataError(f"frame: the known input u must be given at every k < K; row {bad} {why}")
        warn_absent(filled, "t" if "t" in frame.columns else "k")
        t = frame["t"].to_numpy(dtype=float) if "t" in frame.columns else np.arange(rows, dtype=np.float64) * system.dt
        names = {sig.kind: sig.names for sig in system.signals}
        return cls(t=t, x=arrays["x"], u=arrays["u"], w=arrays["w"], v=arrays["v"], y=arrays["y"], names=names,
                   system_name=system.name, time_unit=system.time_unit)  # fmt: skip

    def to_pandas(self) -> pd.DataFrame:
        """One row per time index k = 0..K (u and w are NaN in the last row: no transition), then the flags."""
        import pandas as pd  # imported when used: pandas takes most of `import uiest`'s time otherwise

        columns: dict[str, FloatArray] = {"t": self.t}
        for kind in ("x", "u", "w", "v", "y"):
            data = getattr(self, kind)
            if kind in ("u", "w"):
                data = np.vstack([data, np.full((1, data.shape[1]), np.nan)])
            names = self.names.get(kind) or tuple(f"{kind}[{i}]" for i in range(data.shape[1]))
            for i, name in enumerate(names):
                columns[name] = data[:, i]
        frame = pd.DataFrame(columns)
        frame[FLAG_COLUMNS[0]] = self.x_outside
        frame[FLAG_COLUMNS[1]] = self.v_outside
        frame.index.name = "k"
        return frame


FLAG_COLUMNS = ("x_outside", "v_outside")
"""The flags :meth:`Trajectory.to_pandas` writes after the signals."""
TIME_NAMES = ("time", "timestamp", "datetime", "date", "time_s", "t_s", "seconds")
"""Column names (lower case) taken for a time column that should be ``t``."""


def _check_numbers(frame: pd.DataFrame, names: tuple[str, ...], kind: str) -> None:
    """DataError naming the first cell of the columns ``names`` that is not a real number (its column and row)."""
    import pandas as pd  # loaded already: ``frame`` is a DataFrame

    for name in names:
        column = frame[name]
        if column.dtype.kind in "iuf":
            continue
        numbers = pd.to_numeric(column, errors="coerce")
        bad = numbers.isna() & column.notna()
        bad |= column.map(lambda value: isinstance(value, bool | np.bool_ | complex)).astype(bool)
        if bad.any():
            row = bad.to_numpy().nonzero()[0][0]
            value = column.iloc[row]
            raise DataError(f"frame[{kind}]: expected real numbers, got {value!r} ({type(value).__name__}) in column "
                            f"{name!r} at row {row} (k = {frame.index[row]})")  # fmt: skip


def _check_columns(frame: pd.DataFrame, system: Any) -> None:
    """Refuse a time column not named ``t`` (when ``t`` is absent); warn about columns that are no signal."""
    known = {name for sig in system.signals for name in sig.names} | {"t", *FLAG_COLUMNS}
    repeated = sorted({str(c) for c in frame.columns[frame.columns.duplicated()]})
    repeated += [
        str(c) for c in frame.columns if re.fullmatch(r"(.+)\.\d+", str(c)) and str(c).rsplit(".", 1)[0] in known
    ]
    if repeated:
        raise DataError(
            f"frame: columns {repeated} repeat a signal's column (a CSV reader renames a repeated y to y.1); "
            "expected one column per signal"
        )
    ignored = [column for column in frame.columns if column not in known]
    if "t" not in frame.columns:
        timelike = [column for column in ignored if str(column).strip().lower() in TIME_NAMES]
        if timelike:
            raise DataError(
                f"frame: a time column must be named 't' (numbers in the model's time unit, spaced by dt), got "
                f"{timelike[0]!r}: rename it so that gaps are caught, or drop it to take the rows as k = 0, 1, ..."
            )
    if ignored:
        warnings.warn(f"frame: columns {ignored} are not signals of {system.name!r} and are ignored", UserWarning,
                      stacklevel=3)  # fmt: skip


def _frozen(value: Any, dtype: Any) -> NDArray[Any]:
    arr = np.array(value, dtype=dtype)
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True, eq=False, kw_only=True)
class StepEstimate:
    """The result of one ``step(u_prev, y)`` at time k.

    Attributes
    ----------
    k : int
        Time index of the estimate.
    x_hat : ndarray (nx,)
        Estimate of ``x[k]``.
    w_hat : ndarray (nw,) or None
        The unknown-input estimate delivered at this step, for time ``w_index``; None when the
        window holds no transition informed by a measurement.
    w_index : int or None
        Time index of ``w_hat`` (``k-1`` for the UISE and FIE, ``k-2`` for the one-step-ahead MHE).
    outcome : Outcome
        What happened (:class:`~uiest.health.Outcome`: solved, failed, propagated, updated, ...).
    iterations : int
        Solver iterations (all attempts).
    solve_time : float
        Wall-clock seconds spent in the solver (all attempts).
    cost : float
        Optimal cost of the window problem (NaN after a failure).
    window : int
        Number of transitions ``N_k`` of the window.
    missing : ndarray (ny,) of bool
        Which channels of ``y[k]`` were missing (NaN).
    at_bound : ndarray (nx,) of bool
        Which states of ``x_hat`` lie on or beyond a finite side of X (:func:`uiest.health.at_bound`).
    solver_status : str
        The return status of the solver that produced the window solution (IPOPT's
        ``return_status``, or the Gauss-Newton backend's ``"Converged"``, ``"Stalled"``, ...); after a
        fallback, IPOPT's. ``""`` when no problem was solved.
    fallback : bool
        The Gauss-Newton backend did not converge and IPOPT solved the window (``solver_status``
        is IPOPT's, ``primary_status`` why Gauss-Newton handed over).
    primary_status : str
        After a fallback, the Gauss-Newton backend's reason (``"gn QP_failed"``, ...); else ``""``.
    reason : str
        The exception the step raised (outcome ``ERROR``) or why a filter's update was skipped
        (``UPDATE_SKIPPED``); else ``""``.
    held_input : bool
        ``y[k]`` missed outputs the newest unknown input reaches, and the part of that input only
        they would see was held at its last estimate (UISE, FIE).
    on_boundary : bool
        Some state of ``x_hat`` is at a side of X and the predicted output misses ``y[k]`` by more
        than 10 noise bounds: the constraint, not the data, holds the estimate there (the true state
        may have left X).
    window_at_bound : bool
        Some node of the window solution lies at a side of the window model's box (X; the reduced
        state's box for the two-stage UISE): the constraint shaped the window, even where ``x_hat``
        itself is inside.
    evaluated_inside : bool
        A filter's model was not finite at the estimate or a sigma point and was evaluated at
        states projected into X (EKF, UKF).
    trajectory : WindowTrajectory or None
        The solved window in the window model's coordinates (nodes ``k-N_k .. k``; the reduced
        state for the two-stage UISE); None when no problem was solved.
    x_lag : ndarray (nx,) or None
        The window's estimate of ``x[k-lag]`` (the estimator's ``options.lag``; ``x_hat`` when
        lag = 0, None for k < lag, NaN without a window solution).

    """

    k: int
    x_hat: FloatArray
    w_hat: FloatArray | None
    w_index: int | None
    outcome: Outcome
    iterations: int
    solve_time: float
    cost: float
    window: int
    missing: NDArray[np.bool_]
    at_bound: NDArray[np.bool_]
    solver_status: str = ""
    fallback: bool = False
    primary_status: str = ""
    reason: str = ""
    held_input: bool = False
    on_boundary: bool = False
    window_at_bound: bool = False
    evaluated_inside: bool = False
    trajectory: WindowTrajectory | None = None
    x_lag: FloatArray | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "outcome", Outcome(self.outcome))

    @property
    def success(self) -> bool:
        """The step did not fail (``not outcome.failed``)."""
        return not self.outcome.failed

    @property
    def status(self) -> str:
        """One line for display, derived from the fields (:func:`uiest.health.status_text`; states as ``x[i]``)."""
        return status_text(
            self.outcome, solver_status=self.solver_status, primary_status=self.primary_status, reason=self.reason,
            held_input=self.held_input, at_bound_names=tuple(f"x[{i}]" for i in np.flatnonzero(self.at_bound)),
            on_boundary=self.on_boundary, evaluated_inside=self.evaluated_inside,
        )  # fmt: skip


def count_names(x_names: tuple[str, ...] | list[str]) -> list[str]:
    """The keys of :meth:`EstimationResult.counts` for states named ``x_names``, in order."""
    return ["steps", "failures", "fallbacks", "at_bound", *(f"at_bound_{name}" for name in x_names), "held",
            "propagated", "on_boundary", "window_at_bound"]  # fmt: skip


HEALTH_FIELDS: dict[str, Any] = {
    "solver_status": str,
    "fallback": bool,
    "primary_status": str,
    "reason": str,
    "held_input": bool,
    "on_boundary": bool,
    "window_at_bound": bool,
    "evaluated_inside": bool,
}
"""The per-step fields of :class:`EstimationResult` beside the outcome and ``at_bound``, with their dtypes."""


@dataclass(frozen=True, eq=False, kw_only=True)
class EstimationResult(_PicklableNames):
    """A whole run of an estimator over ``u (K, nu)``, ``y (K+1, ny)``.

    Index convention: ``x_hat[k]`` estimates ``x[k]``; ``w_hat[k]`` estimates ``w[k]``, which
    acts between ``k`` and ``k+1``. Rows of ``w_hat`` that no window informs are NaN (for the
    one-step-ahead standard MHE the last one). Per-step fields are time-first with K+1 rows, one per
    :class:`StepEstimate` (see there for their meaning).

    Attributes
    ----------
    t : ndarray (K+1,)
        Times ``k * dt``.
    x_hat : ndarray (K+1, nx)
    w_hat : ndarray (K, nw)
    outcome : ndarray (K+1,) of str
        Each step's :class:`~uiest.health.Outcome` (its value; ``outcome == Outcome.FAILED`` compares).
    iterations : ndarray (K+1,) of int
    solve_time : ndarray (K+1,)
        Wall-clock seconds in the solver per step.
    cost : ndarray (K+1,)
        Optimal window cost per step.
    window : ndarray (K+1,) of int
        ``N_k`` per step.
    missing : ndarray (K+1, ny) of bool
        Missing measurements (NaN in y).
    estimator : str
        Name of the estimator (``"UISE"``, ``"FIE"``, ``"StandardMHE"``).
    horizon : int or None
        N (for the FIE, where its window stops growing; None if it never does).
    guarantee : Guarantee
        The estimator's guarantee (:class:`~uiest.guarantee.Guarantee`) as this run met it: whether its theorem
        applies, the error bound per state, where the run suspended it (missing outputs, unsolved windows) and
        its text.
    names : mapping
        Component names of "x" and "w".
    time_unit : str
    x_lag : ndarray (K+1, nx) or None
        Fixed-lag estimates: row j estimates ``x[j]`` from the window at step ``j + lag`` (the
        last ``lag`` rows NaN); None when lag = 0.
    lag : int
    one_step_ahead : bool
        ``x_hat[k]`` is predicted from the measurements up to ``y[k-1]`` (the standard MHE, the two-stage UISE):
        its error includes what the unknown input ``w[k-1]`` did, which no earlier output shows.
    at_bound : ndarray (K+1, nx) of bool
        States on or beyond a finite side of X (default: none).
    solver_status, primary_status, reason : ndarray (K+1,) of str
    fallback, held_input, on_boundary, window_at_bound, evaluated_inside : ndarray (K+1,) of bool
        As in :class:`StepEstimate` (default: ``""`` and False).
    cpu_time : ndarray (K+1,)
        CPU seconds of the calling thread (``time.thread_time``) spent in each whole step: the solver
        and the estimator's own work around it (NaN where not measured). Unlike wall-clock time it does
        not count what other processes take from a shared machine.

    """

    t: FloatArray
    x_hat: FloatArray
    w_hat: FloatArray
    outcome: NDArray[np.str_]
    iterations: NDArray[np.int64]
    solve_time: FloatArray
    cost: FloatArray
    window: NDArray[np.int64]
    missing: NDArray[np.bool_]
    estimator: str
    horizon: int | None
    guarantee: Guarantee
    names: Mapping[str, tuple[str, ...]] = field(default_factory=dict)
    time_unit: str = "s"
    x_lag: FloatArray | None = None
    lag: int = 0
    one_step_ahead: bool = False
    at_bound: NDArray[np.bool_] = field(default_factory=_not_given)
    solver_status: NDArray[np.str_] = field(default_factory=_not_given)
    fallback: NDArray[np.bool_] = field(default_factory=_not_given)
    primary_status: NDArray[np.str_] = field(default_factory=_not_given)
    reason: NDArray[np.str_] = field(default_factory=_not_given)
    held_input: NDArray[np.bool_] = field(default_factory=_not_given)
    on_boundary: NDArray[np.bool_] = field(default_factory=_not_given)
    window_at_bound: NDArray[np.bool_] = field(default_factory=_not_given)
    evaluated_inside: NDArray[np.bool_] = field(default_factory=_not_given)
    cpu_time: FloatArray = field(default_factory=_not_given)

    def __post_init__(self) -> None:
        if not isinstance(self.guarantee, Guarantee):
            raise DataError(f"guarantee: expected a uiest.guarantee.Guarantee, got {type(self.guarantee).__name__}")
        for name, dtype in (
            ("t", float),
            ("x_hat", float),
            ("w_hat", float),
            ("outcome", str),
            ("iterations", np.int64),
            ("solve_time", float),
            ("cost", float),
            ("window", np.int64),
            ("missing", bool),
        ):
            object.__setattr__(self, name, _frozen(getattr(self, name), dtype))
        rows = self.t.shape[0]
        unknown = sorted(set(self.outcome.tolist()) - {o.value for o in Outcome})
        if self.outcome.shape != (rows,) or unknown:
            raise DataError(f"outcome: expected ({rows},) values of uiest.health.Outcome, got shape "
                            f"{self.outcome.shape} with {unknown or 'known values'}")  # fmt: skip
        for name, dtype in (("at_bound", bool), *HEALTH_FIELDS.items()):
            value = getattr(self, name)
            shape = self.x_hat.shape if name == "at_bound" else (rows,)
            given = value is not None and value is not _NOT_GIVEN
            arr = _frozen(value, dtype) if given else np.zeros(shape, dtype=dtype)
            if not given:
                arr.setflags(write=False)
            if arr.shape != shape:
                raise DataError(f"{name}: expected shape {shape} (time-first, one row per step), got {arr.shape}")
            object.__setattr__(self, name, arr)
        given = self.cpu_time is not None and self.cpu_time is not _NOT_GIVEN
        cpu = _frozen(self.cpu_time, float) if given else np.full(rows, np.nan)
        if cpu.shape != (rows,):
            raise DataError(f"cpu_time: expected shape ({rows},) (one value per step), got {cpu.shape}")
        cpu.setflags(write=False)
        object.__setattr__(self, "cpu_time", cpu)
        if self.x_lag is not None:
            object.__setattr__(self, "x_lag", _frozen(self.x_lag, float))
        object.__setattr__(self, "names", MappingProxyType({k: tuple(v) for k, v in self.names.items()}))

    @property
    def steps(self) -> int:
        """Number of transitions K."""
        return int(self.w_hat.shape[0])

    @property
    def success(self) -> NDArray[np.bool_]:
        """(K+1,) bool: the steps that did not fail (``not Outcome.failed``)."""
        return ~np.isin(self.outcome, [o.value for o in FAILURES])

    @property
    def status(self) -> NDArray[np.str_]:
        """(K+1,) str: each step's status line for display, derived from the fields (never parse it)."""
        names = self._x_names()
        return np.array([
            status_text(
                self.outcome[k], solver_status=self.solver_status[k], primary_status=self.primary_status[k],
                reason=self.reason[k], held_input=bool(self.held_input[k]),
                at_bound_names=tuple(names[i] for i in np.flatnonzero(self.at_bound[k])),
                on_boundary=bool(self.on_boundary[k]), evaluated_inside=bool(self.evaluated_inside[k]),
            )
            for k in range(self.t.shape[0])
        ], dtype=np.str_)  # fmt: skip

    @property
    def failures(self) -> int:
        """Steps that failed (:attr:`Outcome.failed`: failed solves, errors, skipped updates, divergence)."""
        return int(np.count_nonzero(~self.success))

    @property
    def fallbacks(self) -> int:
        """Steps whose window the Gauss-Newton backend handed to IPOPT."""
        return int(np.count_nonzero(self.fallback))

    @property
    def held_steps(self) -> int:
        """Steps that held part of the newest unknown input at its last estimate (``held_input``)."""
        return int(np.count_nonzero(self.held_input))

    @property
    def propagated_steps(self) -> int:
        """Steps without any measurement in their window, bridged by the model (outcome ``PROPAGATED``)."""
        return int(np.count_nonzero(self.outcome == Outcome.PROPAGATED))

    @property
    def at_bound_steps(self) -> NDArray[np.int64]:
        """(nx,) int: for each state, the steps whose estimate lies on or beyond a side of X."""
        return self.at_bound.sum(axis=0).astype(np.int64)

    def counts(self) -> dict[str, int]:
        """The step counts of the run, for tables (one row per run).

        ``steps`` (K+1), ``failures``, ``fallbacks``, ``at_bound`` (steps with some state at a side
        of X), ``at_bound_<state>`` for each state, ``held``, ``propagated``, ``on_boundary`` and
        ``window_at_bound``.
        """
        values = [int(self.t.shape[0]), self.failures, self.fallbacks, int(np.count_nonzero(self.at_bound.any(axis=1))),
                  *(int(n) for n in self.at_bound_steps), self.held_steps, self.propagated_steps,
                  int(np.count_nonzero(self.on_boundary)), int(np.count_nonzero(self.window_at_bound))]  # fmt: skip
        return dict(zip(count_names(self._x_names()), values, strict=True))

    def _x_names(self) -> tuple[str, ...]:
        return self.names.get("x") or tuple(f"x[{i}]" for i in range(self.x_hat.shape[1]))

    def error(self, x: FloatArray) -> FloatArray:
        """``x - x_hat`` for the true states ``x (K+1, nx)``."""
        arr = real_array(x, "x", f"the true states, an array of shape {self.x_hat.shape} (a Trajectory's .x)")
        if arr.shape != self.x_hat.shape:
            raise DataError(f"x: expected shape {self.x_hat.shape}, got {arr.shape}")
        return arr - self.x_hat

    def to_pandas(self) -> pd.DataFrame:
        """One row per k = 0..K: t, estimates (``<name>_hat``), then the status line and the per-step fields.

        ``status`` (the display line), ``outcome``, ``success``, ``solver_status``, ``fallback``,
        ``primary_status``, ``reason``, ``held_input``, ``on_boundary``, ``window_at_bound``,
        ``evaluated_inside``, ``<state>_at_bound``, ``iterations``, ``solve_time``, ``cpu_time``, ``cost``, the window
        length, the number of missing outputs and, with a lag, the lagged estimates ``<state>_lag`` of
        ``x[k-lag]``. The unknown-input columns are NaN in the last row (no transition after K).
        """
        import pandas as pd  # imported when used: pandas takes most of `import uiest`'s time otherwise

        columns: dict[str, object] = {"t": self.t}
        x_names = self._x_names()
        w_names = self.names.get("w") or tuple(f"w[{i}]" for i in range(self.w_hat.shape[1]))
        for i, name in enumerate(x_names):
            columns[f"{name}_hat"] = self.x_hat[:, i]
        w_full = np.vstack([self.w_hat, np.full((1, self.w_hat.shape[1]), np.nan)])
        for i, name in enumerate(w_names):
            columns[f"{name}_hat"] = w_full[:, i]
        columns.update(status=self.status, outcome=self.outcome, success=self.success)
        columns.update({name: getattr(self, name) for name in HEALTH_FIELDS})
        columns.update({f"{name}_at_bound": self.at_bound[:, i] for i, name in enumerate(x_names)})
        columns.update(
            iterations=self.iterations,
            solve_time=self.solve_time,
            cpu_time=self.cpu_time,
            cost=self.cost,
            window=self.window,
            missing=self.missing.sum(axis=1),
        )
        if self.x_lag is not None:
            columns.update({f"{name}_lag": self.x_lag[:, i] for i, name in enumerate(x_names)})
        frame = pd.DataFrame(columns)
        frame.index.name = "k"
        return frame


def read_record(path: Any, system: Any) -> Trajectory:
    """:meth:`Trajectory.from_pandas` of a CSV or Parquet file (a ``k`` column, from ``to_pandas``, is the index).

    Gaps in ``k`` or ``t`` are missing samples (rows of NaN); a file with neither is taken as contiguous (a warning).
    A CSV cell of text that pandas reads as missing (``n/a``, ``NA``, ``null``, ...; not an empty cell or ``nan``) is a
    missing sample too, with a warning per column (:func:`uiest.sampling.warn_text_as_missing`).
    """
    import pandas as pd  # imported when used: pandas takes most of `import uiest`'s time otherwise

    if not isinstance(path, str | PathLike):
        raise DataError(f"path: expected a file path (str or os.PathLike), got {type(path).__name__} {path!r:.60}")
    file = Path(path)
    if not file.is_file():
        raise DataError(f"data: no file at {file}")
    try:
        if file.suffix.lower() == ".csv":
            frame = pd.read_csv(file)
        elif file.suffix.lower() in (".parquet", ".pq"):
            frame = pd.read_parquet(file)
        else:
            raise DataError(f"data: expected a .csv or .parquet file, got {file.name}")
    except DataError:
        raise
    except Exception as exc:  # a damaged file: name it
        raise DataError(f"data: could not read {file} ({type(exc).__name__}: {exc})") from exc
    record = Trajectory.from_pandas(frame.set_index("k").sort_index() if "k" in frame.columns else frame, system)
    if file.suffix.lower() == ".csv":
        warn_text_as_missing(file, frame, system)
    return record
