r"""The unknown input as a state with bounded increments: the model the smooth-input MHE estimates.

For ``x[k+1] = f(x[k], u[k], w[k])``, ``y[k] = h(x[k], v[k])`` and an unknown input that changes
by a bounded step per sample, the augmented system with state ``z = (x, w)`` is ::

    x[k+1] = f(x[k], u[k], w[k]),   w[k+1] = w[k] + dw[k],   y[k] = h(x[k], v[k]),
    z in X x W,   dw[k] in [-dw_bound, dw_bound]

Its unknown input is the increment ``dw``, whose known range (``w_range`` of the augmented
:class:`~uiest.system.System`) is the bound: a bounded disturbance, as the standard MHE of
Schiller et al. 2023 and :func:`~uiest.detectability.certify_delta_ioss` treat it. A sampled
mechanical model whose unknown force hides behind a sampling zero is not strongly detectable (an
input alternating every sample hides a velocity), but the augmented model can be incrementally
IOSS: a bound on the increments excludes the alternating input.
"""

from __future__ import annotations

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike

from uiest.box import Box, FloatArray
from uiest.checks import real_array
from uiest.errors import ModelError, OptionError
from uiest.system import System

W_SPREAD = 100.0
"""Without ``w_bounds`` or ``system.w_range``, W is ``nominal_w +- W_SPREAD * w.scale`` (as
:func:`~uiest.detectability.certify_delta_ioss`'s default ``w_spread``)."""


def increment_bound(dw_bound: ArrayLike, nw: int, name: str = "dw_bound") -> FloatArray:
    """``dw_bound`` as (nw,) positive finite numbers (a scalar broadcasts); OptionError naming ``name`` otherwise."""
    arr = real_array(dw_bound, name, f"a positive finite number or {nw} of them", error=OptionError)
    if arr.ndim > 1 or arr.size not in (1, nw) or not np.all(np.isfinite(arr) & (arr > 0)):
        raise OptionError(f"{name}: expected a positive finite number or {nw} of them, got {arr.tolist()}")
    return np.broadcast_to(arr.reshape(-1), (nw,)).astype(float)


def input_box(system: System, w_bounds: Box | tuple[ArrayLike, ArrayLike] | None) -> Box:
    """W: ``w_bounds`` if given, else ``system.w_range``, else ``nominal_w +- W_SPREAD * w.scale`` (bounded)."""
    if w_bounds is not None:
        box = Box.coerce(w_bounds, system.nw, "w_bounds")
    elif system.w_range is not None:
        box = system.w_range
    else:
        spread = W_SPREAD * system.w.scale
        box = Box(system.nominal_w - spread, system.nominal_w + spread)
    if not box.is_bounded:
        raise ModelError(f"w_bounds: expected a bounded range of the unknown input, got {box}")
    return box


def augmented_system(
    system: System, dw_bound: ArrayLike, w_bounds: Box | tuple[ArrayLike, ArrayLike] | None = None
) -> System:
    """The system with state ``z = (x, w)`` and unknown input ``dw`` (module docstring).

    Parameters
    ----------
    system : System
        ``x+ = f(x, u, w)``, ``y = h(x, v)``; ``nw >= 1``.
    dw_bound : float or array_like (nw,)
        ``|dw_i[k]| <= dw_bound_i``: the augmented system's ``w_range``; its ``w`` scale is the
        range's width.
    w_bounds : Box or (lower, upper), optional
        W, the range of w the augmented state covers (:func:`input_box`).

    Returns
    -------
    System
        ``nx + nw`` states named ``x.names + w.names`` (X x W, scales ``x.scale, w.scale``),
        unknown input ``dw`` named ``delta_<w name>``; u, v, y, dt as in ``system``.

    """
    if not isinstance(system, System):
        raise OptionError(f"system: expected a uiest.System, got {type(system).__name__}")
    if system.nw == 0:
        raise ModelError("system: expected an unknown input (nw >= 1) to make a state of, got nw = 0")
    bound = increment_bound(dw_bound, system.nw)
    W = input_box(system, w_bounds)
    nx, nw = system.nx, system.nw
    z, u, dw, v = (ca.SX.sym(n, m) for n, m in (("z", nx + nw), ("u", system.nu), ("dw", nw), ("v", system.nv)))
    x, w = z[:nx], z[nx:]
    f = ca.Function("f", [z, u, dw], [ca.vertcat(system.f(x, u, w), w + dw)], ["x", "u", "w"], ["x_next"])
    h = ca.Function("h", [z, v], [system.h(x, v)], ["x", "v"], ["y"])
    sx, sw, X = system.x, system.w, system.x.bounds
    return System.from_functions(
        f,
        h,
        x_bounds=(np.concatenate([X.lower, W.lower]), np.concatenate([X.upper, W.upper])),
        u_bounds=system.u.bounds,
        v_bounds=system.v.bounds,
        y_bounds=system.y.bounds,
        w_range=(-bound, bound),
        x_names=sx.names + sw.names,
        u_names=system.u.names,
        w_names=tuple(f"delta_{n}" for n in sw.names),
        v_names=system.v.names,
        y_names=system.y.names,
        x_units=sx.units + sw.units,
        u_units=system.u.units,
        w_units=sw.units,
        v_units=system.v.units,
        y_units=system.y.units,
        x_scale=np.concatenate([sx.scale, sw.scale]),
        u_scale=system.u.scale,
        v_scale=system.v.scale,
        y_scale=system.y.scale,
        dt=system.dt,
        time_unit=system.time_unit,
        name=f"{system.name} (unknown input as a state)",
    )


__all__ = ["W_SPREAD", "augmented_system", "increment_bound", "input_box"]
