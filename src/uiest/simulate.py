"""Simulation of a :class:`~uiest.system.System`: :func:`simulate` returns a :class:`Trajectory`."""

from __future__ import annotations

import warnings
from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike

from uiest.box import FloatArray, as_vector
from uiest.checks import DOMAIN_TOL, MAX_SAMPLES, MEMORY_BUDGET, check_callable, check_int, check_seed, real_array
from uiest.errors import DataError, DomainWarning, ModelError
from uiest.noise import NoiseModel
from uiest.results import Trajectory
from uiest.system import System

__all__ = ["check_steps", "simulate"]

InputLike = ArrayLike | Callable[[int, FloatArray], ArrayLike] | None
InputSource = FloatArray | Callable[[int, FloatArray], ArrayLike]


def _sequence(value: ArrayLike, rows: int, n: int, name: str) -> FloatArray:
    """A (rows, n) array from a (rows, n) array or a constant (n,) vector."""
    arr = real_array(value, name, f"an array of shape ({rows}, {n})")
    if arr.ndim <= 1 and arr.size == n:
        arr = np.broadcast_to(arr.reshape(n), (rows, n))
    if arr.shape != (rows, n):
        raise DataError(f"{name}: expected shape ({rows}, {n}) or a constant of shape ({n},), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise DataError(f"{name}: expected finite values")
    return np.array(arr, dtype=float)


RECORD_COPIES = 5
"""Float copies per sample and per signal component while a record is simulated and stored (arrays, outputs,
the Trajectory), rounded up from a measurement (design notes: input checks)."""


def check_steps(steps: object, system: System, name: str = "steps", *, error: type[Exception] = DataError) -> int:
    """``steps`` as an int in ``[0, max_steps(system)]``, else ``error`` naming ``name``, the limit and why."""
    steps = check_int(steps, name, error=error)
    limit = max_steps(system)
    if steps > limit:
        raise error(
            f"{name}: expected at most {limit:_} steps for this system, got {steps:_}: a record is stepped one sample "
            f"at a time in Python (at most {MAX_SAMPLES:_} samples), and its arrays take about {RECORD_COPIES} x 8 "
            f"bytes per component and step (at most {MEMORY_BUDGET / 1024**3:.3g} GiB)"
        )
    return steps


def max_steps(system: System) -> int:
    """The longest record :func:`simulate` makes: :data:`~uiest.checks.MAX_SAMPLES` samples within the budget."""
    components = sum(signal.size for signal in system.signals) + 1  # and the time
    return min(MAX_SAMPLES, MEMORY_BUDGET // (RECORD_COPIES * 8 * components) - 1)


def _known_input(system: System, u: InputLike, steps: int) -> FloatArray | Callable[[int, FloatArray], ArrayLike]:
    if callable(u):
        return u
    if u is None:
        if system.nu == 0:
            return np.zeros((steps, 0))
        bounds = system.u.bounds
        if np.array_equal(bounds.lower, bounds.upper):
            return np.broadcast_to(bounds.lower, (steps, system.nu)).copy()
        raise DataError(f"u: required, the system has nu={system.nu} known inputs and U={bounds} is not a point")
    return _sequence(u, steps, system.nu, "u")


def simulate(
    system: System,
    x0: ArrayLike,
    steps: int,
    *,
    u: InputLike = None,
    w: InputLike = None,
    v: ArrayLike | NoiseModel | None = None,
    seed: int | None = None,
    progress: Callable[[int], None] | None = None,
) -> Trajectory:
    """Simulate ``x[k+1] = f(x[k], u[k], w[k])``, ``y[k] = h(x[k], v[k])`` for k = 0..steps-1.

    Parameters
    ----------
    system : System
    x0 : array_like, shape (nx,)
        Initial state; must lie in the state domain X.
    steps : int
        Number of transitions K >= 0.
    u : array_like (K, nu) or (nu,), callable ``(k, x[k]) -> (nu,)``, or None
        Known input. None: no input (nu = 0) or the single point of U when U is a point.
        Every value must lie in U.
    w : array_like (K, nw) or (nw,), callable ``(k, x[k]) -> (nw,)``, or None
        Unknown input; None means zero. A callable lets w depend on the state.
    v : array_like (K+1, nv), a noise model (:class:`~uiest.noise.UniformNoise`,
        :class:`~uiest.noise.GaussianNoise`) or None
        Measurement noise; None means zero. A noise model draws all K+1 samples at once
        from ``numpy.random.default_rng(seed)``, so the same seed gives the same numbers.
    seed : int, optional
        Seed of the noise draw.
    progress : callable, optional
        Called with the number of completed steps (for progress bars).

    Returns
    -------
    Trajectory
        Time-first arrays ``t (K+1,)``, ``x (K+1, nx)``, ``u (K, nu)``, ``w (K, nw)``,
        ``v (K+1, nv)``, ``y (K+1, ny)``; samples where x left X or v left V are recorded in
        ``x_outside`` and ``v_outside`` and announced by a :class:`~uiest.errors.DomainWarning`.

    Raises
    ------
    DataError
        ``system`` not a System, ``x0`` outside X, inputs of the wrong shape or outside U, or a bad ``steps``.

    Examples
    --------
    The closed-form model driven by an unknown input that grows without bound, with uniform noise:

    >>> import numpy as np
    >>> from uiest import UniformNoise, simulate
    >>> from uiest.models import closed_form
    >>> system = closed_form.system(x_bounds=((-100.0, -10.0), (100.0, 10.0)))
    >>> truth = simulate(system, x0=[0.5, 1.0], steps=30, u=np.zeros(1), w=lambda k, x: [-0.5 * x[0] + 0.002 * k**2],
    ...                  v=UniformNoise.symmetric(1e-3), seed=0)
    >>> truth.x.shape, truth.u.shape, truth.w.shape, truth.y.shape
    ((31, 2), (30, 1), (30, 1), (31, 1))

    """
    if not isinstance(system, System):
        raise DataError(f"system: expected a uiest.System, got {type(system).__name__}")
    steps = check_steps(steps, system)
    if seed is not None:
        check_seed(seed, error=DataError)
    check_callable(progress, "progress")
    x_start = as_vector(x0, system.nx, "x0")
    if not system.x.bounds.contains(x_start):
        raise DataError(f"x0: expected a point in X = {system.x.bounds}, got {x_start.tolist()}")
    u_source, w_source, v_arr = _inputs(system, u, w, v, steps, seed)
    try:
        x_arr = np.empty((steps + 1, system.nx))
        u_arr = np.empty((steps, system.nu))
        w_arr = np.empty((steps, system.nw))
    except MemoryError:
        raise DataError(f"steps: {steps} steps of this system do not fit in memory") from None
    x_arr[0] = x_start
    _propagate(system, u_source, w_source, x_arr, u_arr, w_arr, progress)
    if not np.all(system.u.bounds.contains(u_arr, tol=DOMAIN_TOL)):
        raise DataError(f"u: expected values in U = {system.u.bounds}")
    y_arr = system.output(x_arr, v_arr)
    x_outside = ~np.asarray(system.x.bounds.contains(x_arr, tol=1e-12))
    v_outside = ~np.asarray(system.v.bounds.contains(v_arr, tol=1e-12))
    _warn_outside(system, x_arr, v_arr, x_outside, v_outside)
    return Trajectory(
        t=np.arange(steps + 1, dtype=float) * system.dt,
        x=x_arr,
        u=u_arr,
        w=w_arr,
        v=v_arr,
        y=y_arr.reshape(steps + 1, system.ny),
        names={s.kind: s.names for s in system.signals},
        system_name=system.name,
        seed=seed,
        time_unit=system.time_unit,
        x_outside=x_outside,
        v_outside=v_outside,
    )


def _inputs(
    system: System, u: InputLike, w: InputLike, v: ArrayLike | NoiseModel | None, steps: int, seed: int | None
) -> tuple[InputSource, InputSource, FloatArray]:
    """The known and unknown inputs' sources and the noise ``(steps + 1, nv)`` (see :func:`simulate`)."""
    try:
        u_source = _known_input(system, u, steps)
        w_source = (
            np.zeros((steps, system.nw)) if w is None else (w if callable(w) else _sequence(w, steps, system.nw, "w"))
        )
        return u_source, w_source, _noise(system, v, steps, seed)
    except MemoryError:
        raise DataError(f"steps: {steps} steps of this system do not fit in memory") from None


def _noise(system: System, v: ArrayLike | NoiseModel | None, steps: int, seed: int | None) -> FloatArray:
    """The measurement noise ``(steps + 1, nv)``: zero, drawn from a noise model with ``seed``, or given."""
    if v is None:
        return np.zeros((steps + 1, system.nv))
    if isinstance(v, NoiseModel):
        return np.asarray(v.sample(np.random.default_rng(seed), steps + 1, system.nv), dtype=float)
    return _sequence(v, steps + 1, system.nv, "v")


def _propagate(
    system: System,
    u_source: InputSource,
    w_source: InputSource,
    x_arr: FloatArray,
    u_arr: FloatArray,
    w_arr: FloatArray,
    progress: Callable[[int], None] | None,
) -> None:
    """Fill ``x_arr[1:]`` (K+1, nx), ``u_arr`` and ``w_arr`` (K, .) from ``x_arr[0]`` by the model ``f``."""
    f = system.f
    for k in range(u_arr.shape[0]):
        u_arr[k] = _value_at(u_source, k, x_arr[k], system.nu, "u")
        w_arr[k] = _value_at(w_source, k, x_arr[k], system.nw, "w")
        x_next = np.asarray(f(x_arr[k], u_arr[k], w_arr[k]), dtype=float).reshape(-1)
        if not np.all(np.isfinite(x_next)):
            raise ModelError(f"f: non-finite state at step k={k + 1} (x[{k}]={x_arr[k].tolist()})")
        x_arr[k + 1] = x_next
        if progress is not None:
            progress(k + 1)


def _warn_outside(
    system: System, x_arr: FloatArray, v_arr: FloatArray, x_outside: np.ndarray, v_outside: np.ndarray
) -> None:
    """A DomainWarning (pointing at simulate's caller) for x outside X and for v outside V."""
    samples = x_arr.shape[0]
    for label, flags, domain in (("x", x_outside, "X"), ("v", v_outside, "V")):
        if flags.any():
            first = int(np.argmax(flags))
            warnings.warn(
                f"{label} left {domain} at {int(flags.sum())} of {samples} samples (first at k={first}: "
                f"{np.round(x_arr[first] if label == 'x' else v_arr[first], 6).tolist()}, {domain} = "
                f"{system.x.bounds if label == 'x' else system.v.bounds}); recorded in Trajectory.{label}_outside",
                DomainWarning,
                stacklevel=3,
            )


def _value_at(source: InputSource, k: int, x: FloatArray, n: int, name: str) -> FloatArray:
    if callable(source):
        try:
            value = source(k, x.copy())
        except Exception as exc:  # the user's function: its error, named and placed, with the original as cause
            raise DataError(f"{name}: the callable raised {type(exc).__name__} at step k={k}: {exc}") from exc
        return as_vector(value, n, f"{name}(k={k}, x)")
    return source[k]
