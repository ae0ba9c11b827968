"""How long a window may be: the memory its problem needs, estimated before anything is built.

A window of ``N`` transitions is a multiple-shooting problem (:mod:`uiest.window.problem`) with
one stage per node: the stage's variables ``x, v, w`` and residuals ``y, v, w``, and CasADi's
expression graph of ``f`` and ``h`` at that node. Its memory grows linearly in ``N`` with a
per-stage cost that grows with the square of the stage's size ``n = nx + nw + nv + ny`` (the
Jacobian and Hessian blocks of a stage). The estimate :func:`window_bytes` takes
:data:`STAGE_BYTES_PER_SIZE2` bytes per stage and per ``n^2`` (the IPOPT problem's build as
measured on two models, doubled for the solver's factorisation; design notes: input checks), and a
horizon whose window would need more than :data:`MEMORY_BUDGET` is refused before anything is
built.
"""

from __future__ import annotations

from typing import Any

from uiest.checks import MEMORY_BUDGET, STAGE_BYTES_PER_SIZE2, check_int
from uiest.errors import OptionError

__all__ = ["MEMORY_BUDGET", "STAGE_BYTES_PER_SIZE2", "check_horizon", "max_horizon", "window_bytes"]


def window_bytes(N: int, model: Any) -> int:
    """Estimated memory (bytes) of the window problem of ``N`` transitions of ``model`` (module docstring)."""
    size = model.nx + model.nw + model.nv + model.ny
    return (N + 1) * STAGE_BYTES_PER_SIZE2 * size * size


def max_horizon(model: Any) -> int:
    """The longest window whose estimated memory stays within :data:`MEMORY_BUDGET`."""
    size = model.nx + model.nw + model.nv + model.ny
    return MEMORY_BUDGET // (STAGE_BYTES_PER_SIZE2 * size * size) - 1


def check_horizon(N: Any, name: str, model: Any, *, error: type[Exception] = OptionError) -> int:
    """``N`` as an int in ``[1, max_horizon(model)]``, else ``error`` naming ``name``, the limit and why."""
    N = check_int(N, name, low=1, error=error)
    limit = max_horizon(model)
    if limit < N:
        raise error(
            f"{name}: expected a horizon <= {limit:_} for this model, got {N:_}: a window of N transitions needs "
            f"an estimated {window_bytes(N, model) / 1024**3:.3g} GiB (about {STAGE_BYTES_PER_SIZE2 // 1024} KiB x "
            f"(nx + nw + nv + ny)^2 per transition), more than the {MEMORY_BUDGET / 1024**3:.3g} GiB allowed"
        )
    return N
