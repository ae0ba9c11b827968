"""Result containers: frozen dataclasses of time-first arrays.

:class:`Trajectory` (a simulated or measured record), and what the estimators return:
:class:`StepEstimate` per step, :class:`EstimationResult` per run.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from uiest.box import FloatArray
from uiest.checks import real_array
from uiest.errors import DataError
from uiest.guarantee import Guarantee

if TYPE_CHECKING:
    from uiest.window.problem import WindowTrajectory


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


@dataclass(frozen=True, eq=False)
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
    x_outside: NDArray[np.bool_] | None = None
    v_outside: NDArray[np.bool_] | None = None

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
            flags = np.zeros(self.t.shape[0], dtype=bool) if value is None else np.array(value, dtype=bool)
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
        (NaN when absent: measured data has no truth). A time column under another name
        (``time``, ``timestamp``, ...) is refused when ``t`` is absent, since without times a
        dropped row would shift every later sample; other columns are ignored with a warning.
        """
        if not isinstance(frame, pd.DataFrame):
            raise DataError(f"frame: expected a pandas DataFrame, got {type(frame).__name__}")
        rows = len(frame)
        if rows < 1:
            raise DataError("frame: expected at least one row (time index k = 0)")
        _check_columns(frame, system)
        arrays: dict[str, FloatArray] = {}
        for sig in system.signals:
            present = [n for n in sig.names if n in frame.columns]
            required = sig.kind == "y" or (sig.kind == "u" and sig.size > 0)
            if required and len(present) < sig.size:
                missing = [n for n in sig.names if n not in frame.columns]
                raise DataError(f"frame: missing {sig.kind} columns {missing} (has {list(frame.columns)})")
            if present and len(present) < sig.size:
                raise DataError(f"frame: {sig.kind} columns must be all present or all absent, got only {present}")
            data = (
                real_array(frame[list(sig.names)].to_numpy(), f"frame[{sig.kind}]", "real numbers")
                if present else np.full((rows, sig.size), np.nan)
            )  # fmt: skip
            arrays[sig.kind] = data[:-1] if sig.kind in ("u", "w") else data
        if not np.all(np.isfinite(arrays["u"])):
            bad = int(np.argwhere(~np.isfinite(arrays["u"]))[0][0])
            raise DataError(f"frame: the known input u must be given at every k < K; row {bad} has {arrays['u'][bad]}")
        has_t = "t" in frame.columns
        if has_t and not pd.api.types.is_numeric_dtype(frame["t"]):
            raise DataError(
                f"frame[t]: expected numbers in the model's time unit ({system.time_unit!r}) spaced by dt = "
                f"{system.dt}, got {frame['t'].dtype} values such as {frame['t'].iloc[0]!r}; convert timestamps to "
                "elapsed time"
            )
        t = real_array(frame["t"].to_numpy(), "frame[t]", "times") if has_t else np.arange(rows) * system.dt
        if has_t and rows > 1:
            steps = np.diff(t)
            if not (np.all(np.isfinite(t)) and np.allclose(steps, system.dt, rtol=1e-6, atol=1e-9 * abs(system.dt))):
                raise DataError(
                    f"frame[t]: expected finite times spaced by the model's dt = {system.dt}, got steps from "
                    f"{np.nanmin(steps):.6g} to {np.nanmax(steps):.6g} (resample the data, or build the model with "
                    "its sampling time)"
                )
        names = {sig.kind: sig.names for sig in system.signals}
        return cls(t=t, names=names, system_name=system.name, time_unit=system.time_unit, **arrays)

    def to_pandas(self) -> pd.DataFrame:
        """One row per time index k = 0..K (u and w are NaN in the last row: no transition), then the flags."""
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


def _check_columns(frame: pd.DataFrame, system: Any) -> None:
    """Refuse a time column not named ``t`` (when ``t`` is absent); warn about columns that are no signal."""
    known = {name for sig in system.signals for name in sig.names} | {"t", *FLAG_COLUMNS}
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


NO_DATA = "propagated (no data)"
"""Status of a step whose whole window had no measurement: the model bridged it."""

BOUNDARY_FLAG = "[on the boundary of X"
"""Start of the status suffix of an estimate held on the boundary of X (see ``checks.boundary_flag``)."""


@dataclass(frozen=True, eq=False)
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
    status : str
        Solver status (``"prior"`` when no problem had to be solved; ``"propagated (...)"`` after a
        failed solve, with the solver's status in brackets).
    success : bool
        Whether the window problem was solved.
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
    status: str
    success: bool
    iterations: int
    solve_time: float
    cost: float
    window: int
    missing: NDArray[np.bool_]
    trajectory: WindowTrajectory | None = None
    x_lag: FloatArray | None = None


@dataclass(frozen=True, eq=False)
class EstimationResult(_PicklableNames):
    """A whole run of an estimator over ``u (K, nu)``, ``y (K+1, ny)``.

    Index convention: ``x_hat[k]`` estimates ``x[k]``; ``w_hat[k]`` estimates ``w[k]``, which
    acts between ``k`` and ``k+1``. Rows of ``w_hat`` that no window informs are NaN (for the
    one-step-ahead standard MHE the last one).

    Attributes
    ----------
    t : ndarray (K+1,)
        Times ``k * dt``.
    x_hat : ndarray (K+1, nx)
    w_hat : ndarray (K, nw)
    status : ndarray (K+1,) of str
        Per-step solver status (see :class:`StepEstimate`).
    success : ndarray (K+1,) of bool
    iterations : ndarray (K+1,) of int
    solve_time : ndarray (K+1,)
        Seconds per step.
    cost : ndarray (K+1,)
        Optimal window cost per step.
    window : ndarray (K+1,) of int
        ``N_k`` per step.
    missing : ndarray (K+1, ny) of bool
        Missing measurements (NaN in y).
    estimator : str
        Name of the estimator (``"UISE"``, ``"FIE"``, ``"StandardMHE"``).
    horizon : int or None
        N (None for the FIE).
    guarantee : Guarantee
        The estimator's guarantee (:class:`~uiest.guarantee.Guarantee`): whether its theorem
        applies, the error bound per state and its text.
    names : mapping
        Component names of "x" and "w".
    time_unit : str
    x_lag : ndarray (K+1, nx) or None
        Fixed-lag estimates: row j estimates ``x[j]`` from the window at step ``j + lag`` (the
        last ``lag`` rows NaN); None when lag = 0.
    lag : int

    """

    t: FloatArray
    x_hat: FloatArray
    w_hat: FloatArray
    status: NDArray[np.str_]
    success: NDArray[np.bool_]
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

    def __post_init__(self) -> None:
        for name, dtype in (
            ("t", float),
            ("x_hat", float),
            ("w_hat", float),
            ("status", str),
            ("success", bool),
            ("iterations", np.int64),
            ("solve_time", float),
            ("cost", float),
            ("window", np.int64),
            ("missing", bool),
        ):
            object.__setattr__(self, name, _frozen(getattr(self, name), dtype))
        if self.x_lag is not None:
            object.__setattr__(self, "x_lag", _frozen(self.x_lag, float))
        object.__setattr__(self, "names", MappingProxyType({k: tuple(v) for k, v in self.names.items()}))

    @property
    def steps(self) -> int:
        """Number of transitions K."""
        return int(self.w_hat.shape[0])

    @property
    def failures(self) -> int:
        """Steps whose window problem was not solved (estimate propagated); outage steps excluded."""
        return int(np.count_nonzero(~self.success & (self.status != "prior") & (self.status != NO_DATA)))

    @property
    def bridged(self) -> int:
        """Steps of an outage longer than the window, bridged by the model (status ``NO_DATA``)."""
        return int(np.count_nonzero(self.status == NO_DATA))

    @property
    def on_boundary(self) -> FloatArray:
        """(K+1,) bool: estimates held on the boundary of X with a large output residual (see the status)."""
        return np.char.find(self.status.astype(str), BOUNDARY_FLAG) >= 0

    def error(self, x: FloatArray) -> FloatArray:
        """``x - x_hat`` for the true states ``x (K+1, nx)``."""
        arr = real_array(x, "x", f"the true states, an array of shape {self.x_hat.shape} (a Trajectory's .x)")
        if arr.shape != self.x_hat.shape:
            raise DataError(f"x: expected shape {self.x_hat.shape}, got {arr.shape}")
        return arr - self.x_hat

    def to_pandas(self) -> pd.DataFrame:
        """One row per k = 0..K: t, estimates (``<name>_hat``), status, success, iterations, solve_time, cost.

        Then the window length, the number of missing outputs and, with a lag, the lagged estimates
        ``<state>_lag`` of ``x[k-lag]``. The unknown-input columns are NaN in the last row (no
        transition after K).
        """
        columns: dict[str, object] = {"t": self.t}
        x_names = self.names.get("x") or tuple(f"x[{i}]" for i in range(self.x_hat.shape[1]))
        w_names = self.names.get("w") or tuple(f"w[{i}]" for i in range(self.w_hat.shape[1]))
        for i, name in enumerate(x_names):
            columns[f"{name}_hat"] = self.x_hat[:, i]
        w_full = np.vstack([self.w_hat, np.full((1, self.w_hat.shape[1]), np.nan)])
        for i, name in enumerate(w_names):
            columns[f"{name}_hat"] = w_full[:, i]
        columns.update(
            status=self.status,
            success=self.success,
            iterations=self.iterations,
            solve_time=self.solve_time,
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
    """:meth:`Trajectory.from_pandas` of a CSV or Parquet file (a ``k`` column, from ``to_pandas``, is the index)."""
    from pathlib import Path

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
    if "k" in frame.columns:
        frame = frame.set_index("k").sort_index()
        if not np.array_equal(frame.index.to_numpy(), np.arange(len(frame))):
            raise DataError(f"data: the k column must be 0, 1, ..., K without gaps or repeats ({file})")
    return Trajectory.from_pandas(frame, system)
