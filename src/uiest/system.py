"""The system ``x[k+1] = f(x[k], u[k], w[k]),  y[k] = h(x[k], v[k])``.

``x`` is the state, ``u`` the known input, ``w`` the unknown input (unbounded unless the user
states a known range, which only baseline estimators may use), ``v`` the measurement noise and
``y`` the measured output. ``f`` and ``h`` are CasADi Functions; the :class:`System` adds
sizes, names, units, box domains X, U, V, Y, nominal scales and the sampling time.
"""

from __future__ import annotations

import contextlib
import dataclasses
import inspect
import warnings
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from functools import cached_property
from typing import TYPE_CHECKING, Any

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike

from uiest import ode
from uiest.box import Box, FloatArray, as_vector
from uiest.checks import (
    MAX_STAGE_SIZE,
    MEMORY_BUDGET,
    STAGE_BYTES_PER_SIZE2,
    check_int,
    check_keywords,
    check_name,
    check_real,
    real_array,
)
from uiest.errors import DataError, ModelError, OptionError
from uiest.signal import ScaleSource, Signal, SignalSpec, flat_signal_keywords, signal_specs

if TYPE_CHECKING:
    from uiest.ode import ContinuousModel

__all__ = ["Linearization", "System", "as_function", "output_spread"]

BoxLike = Box | tuple[ArrayLike, ArrayLike] | None


@dataclass(frozen=True, kw_only=True)
class Linearization:
    """Jacobians of f and h at one point (x, u, w, v).

    Attributes
    ----------
    A : ndarray, shape (nx, nx)
        df/dx.
    B_u : ndarray, shape (nx, nu)
        df/du.
    B_w : ndarray, shape (nx, nw)
        df/dw.
    C : ndarray, shape (ny, nx)
        dh/dx.
    D_v : ndarray, shape (ny, nv)
        dh/dv.

    """

    A: FloatArray
    B_u: FloatArray
    B_w: FloatArray
    C: FloatArray
    D_v: FloatArray


@contextlib.contextmanager
def _casadi_legacy_numpy() -> Iterator[None]:
    """Silence CasADi's numpy-interop notice while user callables are traced.

    Tracing passes 1-D numpy object arrays of scalar SX symbols: numpy semantics (``@``,
    broadcasting, ufuncs) then hold elementwise, and CasADi functions accept them too.
    """
    options = ca.GlobalOptions
    if not hasattr(options, "setNumpyMode"):
        yield
        return
    previous = options.getNumpyMode()
    options.setNumpyMode(-1)
    try:
        yield
    finally:
        options.setNumpyMode(previous)


def _symbol_array(name: str, n: int) -> tuple[ca.SX, np.ndarray]:
    """A CasADi column symbol and the same symbols as a 1-D numpy object array."""
    column = ca.SX.sym(name, n)
    items = np.empty(n, dtype=object)
    for i in range(n):
        items[i] = column[i]
    return column, items


def _as_column(value: Any, name: str) -> ca.SX:
    """Turn what a traced callable returned (SX, DM, number, sequence or object array) into a column."""
    if isinstance(value, np.ndarray) and value.dtype == object:
        value = list(value.ravel())
    if isinstance(value, list | tuple):
        parts = [_as_column(item, name) for item in value]
        return ca.vertcat(*parts) if parts else ca.SX(0, 1)
    if isinstance(value, np.ndarray | int | float | np.floating | np.integer):
        value = ca.DM(np.asarray(value, dtype=float).reshape(-1, 1))
    if not isinstance(value, ca.SX | ca.DM):
        raise ModelError(f"{name}: expected a CasADi expression or a sequence of them, got {type(value).__name__}")
    expr = ca.SX(value)
    if expr.size2() != 1:
        if expr.size1() != 1:
            raise ModelError(f"{name}: expected a vector, got a {expr.size1()}x{expr.size2()} matrix")
        expr = expr.T
    return expr


def _check_no_nan(expr: ca.SX, name: str) -> ca.SX:
    """Refuse a traced expression holding NaN: a ``math`` function turned a CasADi symbol into NaN."""
    function = ca.Function("probe", ca.symvar(expr), [expr])
    constants = [function.instruction_constant(k) for k in range(function.n_instructions())
                 if function.instruction_id(k) == ca.OP_CONST]  # fmt: skip
    if any(np.isnan(c) for c in constants):
        raise ModelError(
            f"{name}: the traced expression holds NaN. A function of Python's math module (math.sin, math.exp, ...) "
            "turns a CasADi symbol into NaN; use numpy (np.sin) or casadi (ca.sin), which take symbols"
        )
    return expr


def as_function(fun: Any, name: str, inputs: list[tuple[str, int]], n_out: int | None = None) -> ca.Function:
    """A CasADi Function from ``fun``: a ``casadi.Function`` (sizes checked) or a Python callable.

    Callables are traced once with 1-D numpy object arrays of scalar SX symbols, one per entry
    of ``inputs`` (name, size), as in :meth:`System.from_callables`. ``n_out`` checks the size of
    the (single) output.
    """
    if isinstance(fun, ca.Function):
        sizes = [fun.numel_in(i) for i in range(fun.n_in())]
        if sizes != [n for _, n in inputs] or fun.n_out() != 1:
            raise ModelError(
                f"{name}: expected a casadi.Function with inputs of sizes {[n for _, n in inputs]} and one output, "
                f"got inputs {sizes} and {fun.n_out()} outputs"
            )
        function = fun
    elif callable(fun):
        symbols = [_symbol_array(label, n) for label, n in inputs]
        with _casadi_legacy_numpy():
            try:
                out = _check_no_nan(_as_column(fun(*[arr for _, arr in symbols]), name), name)
            except ModelError:
                raise
            except Exception as exc:
                raise ModelError(f"{name}: tracing with CasADi symbols failed: {exc}") from exc
        function = ca.Function(name, [col for col, _ in symbols], [out], [label for label, _ in inputs], ["out"])
    else:
        raise ModelError(f"{name}: expected a callable or a casadi.Function, got {type(fun).__name__}")
    if n_out is not None and function.numel_out(0) != n_out:
        raise ModelError(f"{name}: expected an output of size {n_out}, got {function.numel_out(0)}")
    return function


@dataclass(frozen=True, eq=False)
class System:
    """A discrete-time system ``x+ = f(x, u, w)``, ``y = h(x, v)`` with domains and scales.

    Build it with :meth:`from_callables`, :meth:`from_expressions` or :meth:`from_functions`;
    the constructor takes already built parts and validates them.

    Attributes
    ----------
    f : casadi.Function
        ``(x (nx,), u (nu,), w (nw,)) -> x_next (nx,)``.
    h : casadi.Function
        ``(x (nx,), v (nv,)) -> y (ny,)``.
    x, u, w, v, y : Signal
        Names, units, box domains X, U, W (always the whole space), V, Y and nominal scales.
    w_range : Box or None
        A known range of w. Only baseline estimators (the standard MHE) may use it: the unknown
        input estimators treat w as unbounded.
    dt : float
        Sampling time, in ``time_unit``.
    name : str
        Short name of the system.
    sampled_from : ContinuousModel or None
        The continuous-time model :meth:`from_ode` sampled (its right-hand side, integrator and
        input channel); None for a model given in discrete time.

    """

    f: ca.Function
    h: ca.Function
    x: Signal
    u: Signal
    w: Signal
    v: Signal
    y: Signal
    w_range: Box | None = None
    dt: float = 1.0
    time_unit: str = "s"
    name: str = "system"
    sampled_from: ContinuousModel | None = None

    def __post_init__(self) -> None:
        self._check_functions()
        if self.w_range is not None and self.w_range.size != self.nw:
            raise ModelError(f"w_range: expected dimension {self.nw}, got {self.w_range.size}")
        object.__setattr__(self, "dt", _check_dt(self.dt))
        check_name(self.name, "name", error=ModelError)
        if self.ny == 0:
            raise ModelError("h: returns no output (ny = 0); expected at least one measured output to estimate from")
        if not self.w.bounds == Box.unbounded(self.nw):
            raise ModelError("w: the unknown input's domain is the whole space; give a known range as w_range")
        names = [n for s in self.signals for n in s.names]
        duplicates = sorted({n for n in names if names.count(n) > 1})
        if duplicates:
            raise ModelError(f"signal names must be unique across x, u, w, v, y; repeated: {duplicates}")
        x_next = self.f(self.x.bounds.center, self.u.bounds.center, self.nominal_w)
        y = self.h(self.x.bounds.center, self.v.bounds.center)
        for label, value in (("f", x_next), ("h", y)):
            if not np.all(np.isfinite(np.asarray(value, dtype=float))):
                raise ModelError(f"{label}: not finite at the domain centre (x={self.x.bounds.center.tolist()})")

    def _check_functions(self) -> None:
        expected = {
            "f": (self.f, [self.nx, self.nu, self.nw], self.nx),
            "h": (self.h, [self.nx, self.nv], self.ny),
        }
        for label, (fun, sizes_in, size_out) in expected.items():
            if not isinstance(fun, ca.Function):
                raise ModelError(f"{label}: expected a casadi.Function, got {type(fun).__name__}")
            if fun.n_in() != len(sizes_in) or fun.n_out() != 1:
                raise ModelError(
                    f"{label}: expected {len(sizes_in)} inputs and 1 output, got {fun.n_in()} and {fun.n_out()}"
                )
            got_in = [fun.numel_in(i) for i in range(fun.n_in())]
            if got_in != sizes_in or fun.numel_out(0) != size_out:
                raise ModelError(
                    f"{label}: expected input sizes {sizes_in} and output size {size_out}, "
                    f"got {got_in} and {fun.numel_out(0)}"
                )

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_functions(
        cls,
        f: ca.Function,
        h: ca.Function,
        *,
        signals: Mapping[str, SignalSpec] | None = None,
        w_range: BoxLike = None,
        dt: float = 1.0,
        time_unit: str = "s",
        name: str = "system",
        **flat: Any,
    ) -> System:
        """Build a system from CasADi Functions ``f(x, u, w)`` and ``h(x, v)``.

        Sizes are read from the Functions. Bounds are a :class:`~uiest.box.Box` or a
        ``(lower, upper)`` pair of vectors (scalars broadcast, ``±inf`` allowed, None = unbounded);
        for two states, a pair that reads as per-state pairs too is refused (:meth:`Box.coerce`).
        Scales default to the finite domain widths; for y, where Y is unbounded, to the output
        change caused by moving x and v by their scales (first order, at the domain centre);
        for w to the width of ``w_range`` when given; else 1.

        Parameters
        ----------
        f : casadi.Function
            ``x[k+1] = f(x[k], u[k], w[k])``: three inputs of sizes (nx, nu, nw), one output (nx). ``u[k]`` and
            ``w[k]`` act from time k to k+1.
        h : casadi.Function
            ``y[k] = h(x[k], v[k])``: two inputs of sizes (nx, nv), one output (ny >= 1).
        signals : mapping of str to SignalSpec, optional
            Per signal (keys among ``"x", "u", "w", "v", "y"``): the domain (X, U, V, Y, in the signals' units;
            w has none), component names and units (defaults ``x[0], x[1], ...`` and no unit), and nominal
            magnitudes (positive, in the signals' units) that solvers and certificates divide by.
        w_range : Box or (lower, upper), optional
            A range the unknown input is known to keep to (only its scale and centre are used; the
            estimators do not bound w).
        dt : float
            Sampling interval in ``time_unit``.
        time_unit : str
            Unit of ``dt`` and of the time column of records.
        name : str
            The model's name in reports.
        **flat
            The signals' data as flat keywords, instead of ``signals``: ``x_bounds``, ``x_names``, ``x_units``,
            ``x_scale`` and the same for u, v, y; ``w_names``, ``w_units``, ``w_scale``.

        Returns
        -------
        System

        Raises
        ------
        ModelError
            ``f`` or ``h`` not a Function with 3 and 2 inputs, no output, repeated names, or ``f``, ``h`` not
            finite at the domain centre.
        OptionError
            An unknown keyword, or a signal's SignalSpec and its flat keywords given together.

        Examples
        --------
        A scalar system ``x+ = 0.5 x + u + w``, ``y = x + v``:

        >>> import casadi as ca
        >>> from uiest import System
        >>> x, u, w, v = (ca.SX.sym(name) for name in "xuwv")
        >>> f = ca.Function("f", [x, u, w], [0.5 * x + u + w])
        >>> h = ca.Function("h", [x, v], [x + v])
        >>> system = System.from_functions(f, h, x_bounds=(-10, 10), u_bounds=(-1, 1), v_bounds=(-0.1, 0.1))
        >>> system.nx, system.nu, system.nw, system.nv, system.ny
        (1, 1, 1, 1, 1)
        >>> print(system.step([2.0], [0.5], [1.0]), system.output([2.0], [0.05]))
        [2.5] [2.05]

        """
        for label, fun, n_in in (("f", f, 3), ("h", h, 2)):
            if not isinstance(fun, ca.Function) or fun.n_in() != n_in:
                raise ModelError(f"{label}: expected a casadi.Function with {n_in} inputs, got {fun!r}")
        specs = signal_specs(signals, dict(flat), "System.from_functions")
        nx, nu, nw = (f.numel_in(i) for i in range(3))
        nv, ny = h.numel_in(1), h.numel_out(0)
        x_signal = Signal.from_spec("x", nx, specs["x"])
        u_signal = Signal.from_spec("u", nu, specs["u"])
        v_signal = Signal.from_spec("v", nv, specs["v"])
        known_w = None if w_range is None else Box.coerce(w_range, nw, "w_range")
        w_fallback = None if known_w is None else _usable_width(known_w)
        w_signal = Signal.from_spec("w", nw, specs["w"], fallback_scale=w_fallback)
        y_signal = Signal.from_spec("y", ny, specs["y"], fallback_scale=output_spread(h, x_signal, v_signal),
                                    fallback_source=ScaleSource.OUTPUT)  # fmt: skip
        return cls(f=f, h=h, x=x_signal, u=u_signal, w=w_signal, v=v_signal, y=y_signal, w_range=known_w, dt=dt,
                   time_unit=time_unit, name=name)  # fmt: skip

    @classmethod
    def from_expressions(
        cls,
        x: ca.SX,
        u: ca.SX,
        w: ca.SX,
        v: ca.SX,
        x_next: ca.SX,
        y: ca.SX,
        **spec: Any,
    ) -> System:
        """Build a system from CasADi symbols ``x, u, w, v`` and expressions ``x_next``, ``y``.

        ``u`` may be an empty symbol (``ca.SX.sym("u", 0)``). Further keywords as in
        :meth:`from_functions`.
        """
        _check_spec(spec, "System.from_expressions")
        f = _expression_function("f", [x, u, w], x_next, ["x", "u", "w"], "x_next")
        h = _expression_function("h", [x, v], y, ["x", "v"], "y")
        return cls.from_functions(f, h, **spec)

    @classmethod
    def from_callables(
        cls,
        f: Callable[[Any, Any, Any], Any],
        h: Callable[[Any, Any], Any],
        *,
        nx: int,
        nw: int,
        nv: int,
        nu: int = 0,
        **spec: Any,
    ) -> System:
        """Build a system from Python callables ``f(x, u, w)`` and ``h(x, v)``.

        The callables are traced once, each argument being a 1-D numpy object array of scalar
        CasADi symbols (shape (nx,), (nu,), ...). They may index (``x[0]``), use numpy
        operations (``A @ x``, ``np.exp(x)``, broadcasting) and ``casadi`` functions, and may
        return a 1-D array, a sequence of scalar expressions or a CasADi vector. Further
        keywords as in :meth:`from_functions`.
        """
        nx, nu, nw, nv = _check_sizes(nx, nu, nw, nv)
        _check_spec(spec, "System.from_callables")
        (xs, xa), (us, ua), (ws, wa), (vs, va) = (
            _symbol_array(s, n) for s, n in (("x", nx), ("u", nu), ("w", nw), ("v", nv))
        )
        with _casadi_legacy_numpy():
            try:
                x_next = _check_no_nan(_as_column(f(xa, ua, wa), "f"), "f")
                y = _check_no_nan(_as_column(h(xa, va), "h"), "h")
            except ModelError:
                raise
            except Exception as exc:
                raise ModelError(f"f/h: tracing with CasADi symbols failed: {exc}") from exc
        if x_next.size1() != nx:
            raise ModelError(f"f: expected {nx} outputs (nx), got {x_next.size1()}")
        return cls.from_expressions(xs, us, ws, vs, x_next, y, **spec)

    @classmethod
    def from_ode(
        cls,
        rhs: Callable[[Any, Any, Any], Any] | ca.Function,
        h: Callable[[Any, Any], Any] | ca.Function,
        *,
        nx: int,
        nw: int,
        nv: int,
        nu: int = 0,
        dt: float,
        substeps: int = 1,
        input_channel: str | None = None,
        method: str = "rk4",
        **spec: Any,
    ) -> System:
        """Sample the continuous-time model ``dx/dt = rhs(x, u, w)``, ``y = h(x, v)`` every ``dt``.

        ``rhs`` and ``h`` are callables (traced as in :meth:`from_callables`) or CasADi Functions.
        u and w are held over each sample. The drift is integrated by RK4 (``method="rk4"``) or, for stiff models, by
        Radau IIA collocation (``method="collocation"``), ``substeps`` steps per sample; where rhs is affine in w with
        a constant matrix G, the unknown input enters through its per-sample integral ``Gamma (w - w0)`` (constant
        direction, linearised at the centre of X and U; ``input_channel="rk4"`` keeps w inside RK4 instead). Warns
        where that integral differs over X by more than :data:`~uiest.ode.INPUT_SPREAD` of its size; where by more
        than :data:`~uiest.ode.INPUT_SPREAD_LIMIT` (a constant direction would misstate even the size or sign of w's
        effect), w enters inside the integrator unless ``input_channel="integral"`` is given. See :mod:`uiest.ode`
        for the discretisation error. Warns where RK4 grows a mode the ODE damps somewhere in X. Further keywords as
        in :meth:`from_functions`. The system keeps the continuous model in ``sampled_from`` (the analysis names the
        zeros sampling created from it).

        Parameters
        ----------
        rhs : callable or casadi.Function
            ``dx/dt = rhs(x, u, w)`` (nx,), in state units per ``time_unit``.
        h : callable or casadi.Function
            ``y = h(x, v)`` (ny,).
        nx, nw, nv, nu : int
            Sizes of the state, unknown input, noise and known input (``nu`` may be 0).
        dt : float
            Sampling interval (> 0) in ``time_unit``; u and w are held over it.
        substeps : int
            Integrator steps per sample.
        input_channel : {None, "integral", "rk4"}
            ``"rk4"`` keeps w inside the integrator even where rhs is affine in w; ``"integral"`` its per-sample
            integral at X's centre even where it varies over X; None chooses (above).
        method : {"rk4", "collocation"}
            The integrator.
        **spec
            As for :meth:`from_functions` (bounds, names, units, scales, ``name``).

        Returns
        -------
        System
            The sampled model ``x[k+1] = f(x[k], u[k], w[k])``, with ``sampled_from`` set.

        Raises
        ------
        ModelError
            Callables that cannot be traced, wrong output sizes, or a sampled model that is not finite.

        Examples
        --------
        A pendulum whose angle is measured and whose torque is unknown, sampled every 0.05 s:

        >>> import numpy as np
        >>> from uiest import System
        >>> pendulum = System.from_ode(
        ...     lambda x, u, w: [x[1], -9.81 * np.sin(x[0]) + w[0]], lambda x, v: [x[0] + v[0]],
        ...     nx=2, nw=1, nv=1, dt=0.05, substeps=2, x_bounds=(-5, 5), v_bounds=(-0.01, 0.01), name="pendulum")
        >>> print(pendulum.dt, pendulum.step([0.1, 0.0], None, [0.0]).round(4))
        0.05 [ 0.0988 -0.0488]

        """
        nx, nu, nw, nv = _check_sizes(nx, nu, nw, nv)
        _check_spec(spec, "System.from_ode")
        rhs_f = as_function(rhs, "rhs", [("x", nx), ("u", nu), ("w", nw)], nx)
        h_f = as_function(h, "h", [("x", nx), ("v", nv)])
        w_range = spec.get("w_range")
        dt = _check_dt(dt)
        signals = signal_specs(spec.get("signals"),
                               {key: value for key, value in spec.items() if key in flat_signal_keywords()},
                               "System.from_ode")  # fmt: skip
        X = Box.coerce(signals["x"].bounds, nx, "x_bounds")
        u_ref = Box.coerce(signals["u"].bounds, nu, "u_bounds").center
        w_ref = np.zeros(nw) if w_range is None else Box.coerce(w_range, nw, "w_range").center
        f, channel = ode.discretise(rhs_f, dt=dt, substeps=substeps, input_channel=input_channel, method=method,
                                    x_ref=X.center, u_ref=u_ref, w_ref=w_ref)  # fmt: skip
        check = ode.rk4_instability if method == "rk4" else ode.collocation_unconverged
        unstable = check(rhs_f, X, u_ref, w_ref, dt / substeps)
        if unstable:
            warnings.warn(f"from_ode: {unstable}", UserWarning, stacklevel=2)
        if channel == "integral":  # "rk4" where a constant direction misstates w's effect by more than its size
            f, channel = _checked_channel(rhs_f, f, input_channel, X, u_ref, w_ref, (dt, substeps, method))
        try:
            system = cls.from_functions(f, h_f, dt=dt, **spec)
        except ModelError as exc:
            if unstable and "not finite" in str(exc):
                raise ModelError(f"{exc}; {unstable}") from exc
            raise
        origin = ode.ContinuousModel(rhs=rhs_f, method=method, substeps=int(substeps), input_channel=channel)
        return dataclasses.replace(system, sampled_from=origin)

    # ------------------------------------------------------------------ sizes
    @cached_property
    def nx(self) -> int:
        """State dimension."""
        return self.x.size

    @cached_property
    def nu(self) -> int:
        """Known input dimension (may be 0)."""
        return self.u.size

    @cached_property
    def nw(self) -> int:
        """Unknown input dimension."""
        return self.w.size

    @cached_property
    def nv(self) -> int:
        """Measurement noise dimension."""
        return self.v.size

    @cached_property
    def ny(self) -> int:
        """Output dimension."""
        return self.y.size

    @property
    def signals(self) -> tuple[Signal, Signal, Signal, Signal, Signal]:
        """``(x, u, w, v, y)``."""
        return (self.x, self.u, self.w, self.v, self.y)

    @property
    def nominal_w(self) -> FloatArray:
        """Centre of ``w_range`` if known, else zeros; shape (nw,)."""
        return np.zeros(self.nw) if self.w_range is None else self.w_range.center

    def with_scales(self, trajectory: Any = None, **scales: ArrayLike) -> System:
        """The same system with other nominal scales (what solvers and certificates divide by).

        Parameters
        ----------
        trajectory : Trajectory, optional
            A simulated or measured record: each signal's scale becomes the largest magnitude of
            each component over the record (``max_k |x_i[k]|``; NaN entries ignored), where that
            is positive and finite (source ``ScaleSource.DATA``); components that are zero
            throughout keep their scale.
        **scales : array_like
            ``x=``, ``u=``, ``w=``, ``v=``, ``y=``: explicit scales (positive; a scalar broadcasts),
            applied after the trajectory's (source ``ScaleSource.GIVEN``).

        Notes
        -----
        Use it when X is a wide safety box (say ``±1e9`` for "unbounded"): scales from X's width
        would make a solve resolve only about 1e-8 of that width. The estimators and designs do
        this themselves where the user gave no scales (:func:`uiest.scales.data_scales`).

        """
        unknown = sorted(set(scales) - {"x", "u", "w", "v", "y"})
        if unknown:
            raise OptionError(f"scales: unknown signals {unknown}; expected some of ['x', 'u', 'w', 'v', 'y']")
        new = {s.kind: s.scale for s in self.signals}
        sources = {s.kind: s.scale_source for s in self.signals}
        if trajectory is not None:
            for kind in new:
                peak = _peak_magnitude(trajectory, kind, len(new[kind]))
                found = np.isfinite(peak) & (peak > 0)
                new[kind] = np.where(found, peak, new[kind])
                sources[kind] = tuple(ScaleSource.DATA if data else source
                                      for data, source in zip(found, sources[kind], strict=True))  # fmt: skip
        for kind, value in scales.items():
            given = real_array(value, f"{kind}", "positive scales", error=OptionError)
            if given.size not in (1, len(new[kind])) or not np.all(np.isfinite(given) & (given > 0)):
                raise OptionError(f"{kind}: expected {len(new[kind])} positive finite scales, got {given.tolist()}")
            new[kind] = np.broadcast_to(given.reshape(-1), new[kind].shape)
            sources[kind] = (ScaleSource.GIVEN,) * len(new[kind])
        signals = {s.kind: dataclasses.replace(s, scale=np.array(new[s.kind], dtype=float),
                                               scale_source=sources[s.kind]) for s in self.signals}  # fmt: skip
        return dataclasses.replace(self, x=signals["x"], u=signals["u"], w=signals["w"], v=signals["v"], y=signals["y"])

    # ------------------------------------------------------------------ numerics
    def step(self, x: ArrayLike, u: ArrayLike | None, w: ArrayLike) -> FloatArray:
        """Evaluate ``f``: shapes (nx,), (nu,), (nw,) -> (nx,), or a batch (m, .) -> (m, nx).

        ``u`` may be None when ``nu == 0``.
        """
        if u is None and self.nu:
            raise DataError(f"u: expected the known input of shape ({self.nu},) or (m, {self.nu}), got None")
        return self._evaluate(self.f, [("x", x, self.nx), ("u", u, self.nu), ("w", w, self.nw)])

    def output(self, x: ArrayLike, v: ArrayLike | None = None) -> FloatArray:
        """Evaluate ``h``: shapes (nx,), (nv,) -> (ny,), or a batch (m, .) -> (m, ny).

        ``v`` None means no noise.
        """
        return self._evaluate(self.h, [("x", x, self.nx), ("v", v, self.nv)])

    def linearize(
        self, x: ArrayLike, u: ArrayLike | None = None, w: ArrayLike | None = None, v: ArrayLike | None = None
    ) -> Linearization:
        """Jacobians of f and h at one point; None stands for the centre of U, ``nominal_w`` or v = 0."""
        args = [
            as_vector(x, self.nx, "x"),
            self.u.bounds.center if u is None else as_vector(u, self.nu, "u"),
            self.nominal_w if w is None else as_vector(w, self.nw, "w"),
            np.zeros(self.nv) if v is None else as_vector(v, self.nv, "v"),
        ]
        A, B_u, B_w, C, D_v = (np.asarray(m, dtype=float) for m in self.jacobian_function(*args))
        return Linearization(A=A, B_u=B_u, B_w=B_w, C=C, D_v=D_v)

    @cached_property
    def jacobian_function(self) -> ca.Function:
        """CasADi Function ``(x, u, w, v) -> (A, B_u, B_w, C, D_v)``; ``.map(m)`` batches it."""
        x, u, w, v = (ca.SX.sym(s, n) for s, n in (("x", self.nx), ("u", self.nu), ("w", self.nw), ("v", self.nv)))
        fx, hx = self.f(x, u, w), self.h(x, v)
        return ca.Function(
            "jacobians",
            [x, u, w, v],
            [ca.jacobian(fx, x), ca.jacobian(fx, u), ca.jacobian(fx, w), ca.jacobian(hx, x), ca.jacobian(hx, v)],
            ["x", "u", "w", "v"],
            ["A", "B_u", "B_w", "C", "D_v"],
        )

    def _evaluate(self, fun: ca.Function, args: list[tuple[str, ArrayLike | None, int]]) -> FloatArray:
        arrays = []
        for label, value, n in args:
            arr = (
                np.zeros(n) if value is None else real_array(value, label, f"real numbers of shape ({n},) or (m, {n})")
            )
            if arr.ndim == 0 and n == 1:
                arr = arr.reshape(1)
            if arr.ndim not in (1, 2) or arr.shape[-1] != n:
                raise DataError(f"{label}: expected shape ({n},) or (m, {n}), got {arr.shape}")
            if not np.all(np.isfinite(arr)):
                raise DataError(f"{label}: expected finite values")
            arrays.append(arr)
        rows = {label: a.shape[0] for (label, _, _), a in zip(args, arrays, strict=True) if a.ndim == 2}
        batch = set(rows.values())
        if len(batch) > 1:
            raise DataError(f"{', '.join(rows)}: batched arguments disagree in length, got {rows}")
        if not batch:
            return np.asarray(fun(*arrays), dtype=float).reshape(-1)
        m = batch.pop()
        columns = [np.broadcast_to(a, (m, a.shape[-1])).T for a in arrays]
        return np.asarray(fun.map(m)(*columns), dtype=float).reshape(-1, m).T

    def __repr__(self) -> str:
        return (
            f"System(name={self.name!r}, nx={self.nx}, nu={self.nu}, nw={self.nw}, nv={self.nv}, "
            f"ny={self.ny}, dt={self.dt} {self.time_unit})"
        )


def _peak_magnitude(trajectory: Any, kind: str, n: int) -> FloatArray:
    """Largest magnitude per component of ``trajectory.<kind>`` (NaN ignored; NaN for an all-NaN column), shape (n,)."""
    if not hasattr(trajectory, kind):
        raise DataError(f"trajectory: expected a Trajectory with x, u, w, v, y, got {type(trajectory).__name__}")
    values = real_array(getattr(trajectory, kind), f"trajectory.{kind}", "a real array")
    if not n:
        return np.zeros(0)
    if values.size % n:
        raise DataError(f"trajectory.{kind}: expected {n} columns, got shape {values.shape}")
    values = values.reshape(-1, n)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN columns
        return np.nanmax(np.abs(values), axis=0) if len(values) else np.zeros(n)


def _check_sizes(nx: Any, nu: Any, nw: Any, nv: Any) -> tuple[int, int, int, int]:
    """The dimensions given to from_callables / from_ode: integers, nx >= 1, the others >= 0.

    ``nx + nw + nv`` (with at least one output, the stage size) is at most :data:`~uiest.checks.MAX_STAGE_SIZE`,
    checked before any symbol is made.
    """
    sizes = [check_int(n, label, low=int(label == "nx"), error=ModelError)
             for label, n in (("nx", nx), ("nu", nu), ("nw", nw), ("nv", nv))]  # fmt: skip
    nx, nu, nw, nv = sizes
    if nx + nw + nv + 1 > MAX_STAGE_SIZE or nu > MAX_STAGE_SIZE:
        raise ModelError(
            f"nx, nu, nw, nv: expected nx + nw + nv + ny <= {MAX_STAGE_SIZE} and nu <= {MAX_STAGE_SIZE}, got nx={nx}, "
            f"nu={nu}, nw={nw}, nv={nv}: a window of one transition would need more than "
            f"{MEMORY_BUDGET / 1024**3:.3g} GiB (about {STAGE_BYTES_PER_SIZE2 // 1024} KiB x (nx + nw + nv + ny)^2 "
            "per stage)"
        )
    return nx, nu, nw, nv


def _check_spec(spec: dict[str, Any], caller: str) -> None:
    """OptionError naming the keywords of ``spec`` that :meth:`System.from_functions` does not take."""
    parameters = inspect.signature(System.from_functions).parameters
    known = [p for p in parameters if p not in ("f", "h", "flat")] + list(flat_signal_keywords())
    check_keywords(spec, known, caller)


def _check_dt(dt: Any) -> float:
    expected = "a positive finite sampling time"
    value = check_real(dt, "dt", expected, error=ModelError)
    if not (np.isfinite(value) and value > 0):
        raise ModelError(f"dt: expected {expected}, got {dt!r}")
    return value


def _expression_function(name: str, inputs: list[Any], output: Any, names: list[str], out_name: str) -> ca.Function:
    """``ca.Function`` of expressions, or ModelError naming the symbols the output uses besides the inputs."""
    try:
        return ca.Function(name, inputs, [output], names, [out_name])
    except (RuntimeError, NotImplementedError, TypeError) as exc:
        try:
            given = {str(s) for arg in inputs for s in ca.symvar(arg)}
            free = sorted({str(s) for s in ca.symvar(output)} - given)
        except Exception:  # not CasADi expressions at all
            free = []
        if free:
            raise ModelError(
                f"{out_name}: uses the symbols {free}, which are not among the inputs {names}; expected an "
                f"expression of {', '.join(names)} only (substitute parameters by numbers)"
            ) from None
        first = (str(exc).strip().splitlines() or [type(exc).__name__])[-1]
        raise ModelError(f"{name}: cannot build a casadi.Function of {names} -> {out_name}: {first}") from None


def _usable_width(box: Box) -> FloatArray:
    """The box's widths where finite and positive, NaN elsewhere (no scale from the width)."""
    width = box.width
    return np.where(np.isfinite(width) & (width > 0), width, np.nan)


def output_spread(h: ca.Function, x: Signal, v: Signal, at: FloatArray | None = None) -> FloatArray:
    """First-order output magnitude ``sqrt(sum_j (dh_i/dz_j s_j)^2)`` over z = (x, v), shape (ny,).

    At ``x = at`` (default X's centre) and V's centre; NaN where it is not positive and finite.
    """
    xs, vs = ca.SX.sym("x", x.size), ca.SX.sym("v", v.size)
    jac = ca.Function("jac_h", [xs, vs], [ca.jacobian(h(xs, vs), ca.vertcat(xs, vs))])
    try:
        sens = np.asarray(jac(x.bounds.center if at is None else at, v.bounds.center), dtype=float)
    except RuntimeError as exc:
        raise ModelError(f"h: evaluation failed at the domain centre: {exc}") from exc
    spread = np.sqrt(((sens * np.concatenate([x.scale, v.scale])) ** 2).sum(axis=1))
    return np.where(np.isfinite(spread) & (spread > 0), spread, np.nan)


def _checked_channel(
    rhs: ca.Function, f: ca.Function, asked: str | None, X: Box, u_ref: np.ndarray, w_ref: np.ndarray,
    sampling: tuple[float, int, str]
) -> tuple[ca.Function, str]:  # fmt: skip
    """The sampled model ``f`` of the integral channel, or of "rk4" where that misstates w's effect.

    "rk4" only where ``asked`` is None; a warning wherever the per-sample integral varies over X
    (:func:`uiest.ode.input_spread`). ``sampling``: ``(dt, substeps, method)``.
    """
    dt, substeps, method = sampling
    spread = ode.input_spread(rhs, X, u_ref, w_ref, dt)
    if spread is None:
        return f, "integral"
    if spread.spread > ode.INPUT_SPREAD_LIMIT and asked is None:  # another model than the ODE over X
        f, channel = ode.discretise(rhs, dt=dt, substeps=substeps, input_channel="rk4", method=method,
                                    x_ref=X.center, u_ref=u_ref, w_ref=w_ref)  # fmt: skip
        warnings.warn(f"from_ode: {spread.text}; so w enters inside the integrator (input_channel='rk4'), its "
                      "direction varying with the state as the ODE's does (input_channel='integral' keeps the "
                      "constant direction the certificates of x+ = f1 + B w need: narrow X first)", UserWarning,
                      stacklevel=3)  # fmt: skip
        return f, channel
    warnings.warn(f"from_ode: {spread.text}; input_channel='rk4' keeps w inside the integrator", UserWarning,
                  stacklevel=3)  # fmt: skip
    return f, "integral"
