"""Scales from data where a domain's width is not one.

A state's scale is the user's, else X's width (:class:`~uiest.signal.Signal`). A width serves only
when it is of the signal's order: a user who writes ``X = ±1e9`` means "unbounded", and dividing
by it costs 9 digits of every solve. :func:`data_scales` replaces, for the components whose scale
the user did not give,

- a state scale from X's width wider than :data:`WIDE_DOMAIN` times the state's magnitude, and a
  unit scale (X unbounded), by that magnitude: the largest ``|x_i|`` of the prior ``x0`` and of
  two short simulations from it (:data:`SIMULATION_STEPS` steps; the unknown input at its nominal value
  and, in the second, moved by up to its scale uniformly at random; the known input the record's in
  both, or without a record U's centre and, in the second, uniform draws from U; seed
  :data:`SIMULATION_SEED`), each stopped where it leaves X or stops
  being finite (where one leaves X and the other does not, only the one that stays counts);
- then the output scales derived from the replaced state scales (``ScaleSource.OUTPUT``) by the
  measured outputs' magnitudes (``max_k |y_j[k]|`` of the record, NaN ignored) or, without a
  record, by the output spread of the new state scales at ``x0``; an output scale from Y's width
  by the record's output magnitude under the same rule.

A state that neither the prior nor the simulations move (magnitude at most :data:`ROUNDING` of the
largest) takes the largest state magnitude; where no state moves, the scales stay as they are (the
estimators warn where that leaves a scale far above the prior's magnitude). Components with a scale the user gave
(``ScaleSource.GIVEN``) or from data (``ScaleSource.DATA``) are never changed, so calling it twice
changes nothing more.
"""

from __future__ import annotations

import dataclasses
import warnings
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from uiest.box import FloatArray, as_vector
from uiest.signal import ScaleSource, Signal
from uiest.system import System, output_spread

__all__ = ["ROUNDING", "WIDE_DOMAIN", "data_scales", "state_peaks"]

WIDE_DOMAIN = 1e4
"""A domain width above this many times the signal's magnitude is not a scale."""

ROUNDING = 1e-10
"""A state magnitude below this fraction of the largest state's is rounding, not a magnitude (a state that no
simulation moves, moved by rounding errors only)."""

SIMULATION_STEPS = 50
"""Length of the simulations that estimate the states' magnitudes."""

SIMULATION_SEED = 0
"""Seed of the unknown input of the excited simulation."""


def data_scales(system: System, x0: ArrayLike | None, record: Any = None) -> System:
    """``system`` with its state and output scales from data where X's (or Y's) width is not a scale.

    Parameters
    ----------
    system : System
    x0 : array_like, shape (nx,), or None
        The prior of x[0] (where the simulations start); None: ``system`` is returned as it is.
    record : Trajectory, optional
        A measured record: its outputs ``y`` (K+1, ny) give the output magnitudes and its known
        inputs ``u`` (K, nu) drive the simulations; its states are not used.

    Returns
    -------
    System
        ``system`` itself when no scale changes (module docstring), else a copy with the new
        scales (source ``ScaleSource.DATA``) and the same f, h, domains and names.

    """
    if x0 is None:
        return system
    prior = as_vector(x0, system.nx, "x0_prior")
    x = system.x
    unit = np.array([s is ScaleSource.UNIT for s in x.scale_source], dtype=np.bool_)
    width = np.array([s is ScaleSource.WIDTH for s in x.scale_source], dtype=np.bool_)
    open_ = unit | (width & (x.scale > WIDE_DOMAIN * np.abs(prior)))  # the prior alone does not settle them
    magnitude = np.maximum(np.abs(prior), state_peaks(system, prior, record)) if open_.any() else np.abs(prior)
    largest = float(np.max(magnitude, initial=0.0))
    unmoved = magnitude <= ROUNDING * largest
    magnitude = np.where(unmoved, largest, magnitude)  # the order of the states that did move
    replace_x = (magnitude > 0) & (unit | (width & (x.scale > WIDE_DOMAIN * magnitude)))
    new_x = _replaced(x, replace_x, magnitude)
    new_y = _output_scales(system, new_x, bool(replace_x.any()), prior, record)
    if new_x is x and new_y is system.y:
        return system
    return dataclasses.replace(system, x=new_x, y=new_y)


def state_peaks(system: System, x0: FloatArray, record: Any = None) -> FloatArray:
    """Largest ``|x_i|`` of the two simulations of the module docstring, shape (nx,) (0 where they never move).

    A simulation that leaves X (or stops being finite) escaped: where the other stays in X throughout, only that one
    counts (the excited Henon map in X = +-1e6 reached 1e5 on its way out, against 1.3 on its attractor).
    """
    rng = np.random.default_rng(SIMULATION_SEED)
    steps = SIMULATION_STEPS
    w = np.stack([np.tile(system.nominal_w, (steps, 1)),
                  system.nominal_w + system.w.scale * rng.uniform(-1.0, 1.0, (steps, system.nw))])  # fmt: skip
    u = _known_input(system, record, steps, rng)
    x = np.tile(x0, (2, 1))
    live = np.ones(2, dtype=bool)
    peak = np.zeros((2, system.nx))
    for k in range(steps):
        rows = np.flatnonzero(live)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # a model evaluated outside its domain may warn (overflow, ...)
            nxt = system.step(x[rows], u[rows, k], w[rows, k])
        ok = np.all(np.isfinite(nxt), axis=1) & np.asarray(system.x.bounds.contains(nxt), dtype=bool)
        live[rows[~ok]] = False
        if not ok.any():
            break
        peak[rows[ok]] = np.maximum(peak[rows[ok]], np.abs(nxt[ok]))
        x[rows[ok]] = nxt[ok]
    result: FloatArray = peak[live].max(axis=0) if live.any() else peak.max(axis=0)
    return result


def _replaced(signal: Signal, mask: np.ndarray, values: FloatArray) -> Signal:
    """``signal`` with ``values`` as the scales where ``mask`` (source DATA); ``signal`` itself if mask is empty."""
    if not mask.any():
        return signal
    sources = tuple(ScaleSource.DATA if m else s for m, s in zip(mask, signal.scale_source, strict=True))
    return dataclasses.replace(signal, scale=np.where(mask, values, signal.scale), scale_source=sources)


def _output_scales(system: System, x: Signal, x_changed: bool, prior: FloatArray, record: Any) -> Signal:
    """The output scales of the module docstring for the new state signal ``x``."""
    y = system.y
    peaks = _output_peaks(system, record)
    derived = np.array([s is ScaleSource.OUTPUT for s in y.scale_source], dtype=np.bool_) & x_changed
    width = y.bounds.width
    too_wide = np.array([s is ScaleSource.WIDTH for s in y.scale_source], dtype=np.bool_) & (
        width > WIDE_DOMAIN * peaks
    )
    if not (derived.any() or too_wide.any()):
        return y
    spread = output_spread(system.h, x, system.v, at=prior)
    measured = np.isfinite(peaks) & (peaks > 0)
    value = np.where(measured, peaks, spread) if record is not None else spread
    value = np.where(too_wide, peaks, value)
    return _replaced(y, (derived | too_wide) & np.isfinite(value) & (value > 0), value)


def _output_peaks(system: System, record: Any) -> FloatArray:
    """``max_k |y_j[k]|`` of the record's outputs (NaN ignored), shape (ny,); NaN throughout without a record."""
    if record is None or not system.ny:
        return np.full(system.ny, np.nan)
    y = np.asarray(record.y, dtype=float).reshape(-1, system.ny)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN columns
        return np.nanmax(np.abs(y), axis=0) if len(y) else np.full(system.ny, np.nan)


def _known_input(system: System, record: Any, steps: int, rng: np.random.Generator) -> FloatArray:
    """The two simulations' known inputs (2, steps, nu).

    With a record, its u in both (U's centre where missing or beyond the record); without, U's centre in the first
    and uniform draws from U in the excited one (U's centre in a component with an infinite side).
    """
    U = system.u.bounds
    centre = np.tile(U.center, (steps, 1))
    if record is None or not system.nu:
        bounded = np.isfinite(U.lower) & np.isfinite(U.upper)
        drawn = np.where(bounded, rng.uniform(np.where(bounded, U.lower, 0.0), np.where(bounded, U.upper, 0.0),
                                              (steps, system.nu)), centre)  # fmt: skip
        return np.stack([centre, drawn])
    given = np.asarray(record.u, dtype=float).reshape(-1, system.nu)[:steps]
    centre[: len(given)] = np.where(np.isfinite(given), given, centre[: len(given)])
    return np.stack([centre, centre])
