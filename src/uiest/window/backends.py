"""The window solver backends by name: :data:`BACKENDS`, :data:`DEFAULT_BACKEND` and :func:`make_solver`.

:data:`MULTIPLIER_BACKENDS` says which of them take multipliers for a warm start.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from uiest.errors import OptionError
from uiest.window.gauss_newton import GaussNewtonSolver
from uiest.window.problem import WindowProblem
from uiest.window.solvers import IpoptSolver, WindowSolver

__all__ = ["BACKENDS", "DEFAULT_BACKEND", "MULTIPLIER_BACKENDS", "make_solver"]

BACKENDS = ("ipopt", "gn", "rti", "gn-riccati")
"""Names accepted as ``solver=``."""

MULTIPLIER_BACKENDS = ("ipopt",)
"""The backends whose ``solve`` takes multipliers (``lam_x0``, ``lam_g0``) for a warm start; the Gauss-Newton
ones refuse them (design notes: Gauss-Newton solver)."""

DEFAULT_BACKEND = "gn"
"""The estimators' default backend: Gauss-Newton SQP, with IPOPT as its fallback for any sample it does not
solve (its cost against IPOPT's: the performance page and the design notes, window solvers)."""


_SET_BY_NAME: dict[str, dict[str, Any]] = {"rti": {"max_iter": 1}, "gn-riccati": {"qp": "riccati"}}
"""The Gauss-Newton settings a backend's name fixes (a contradicting ``solver_options`` entry is refused)."""


def make_solver(
    name: str,
    problem: WindowProblem,
    *,
    warm_start: bool = False,
    options: Mapping[str, Any] | None = None,
    polish: bool = False,
) -> WindowSolver:
    """Build the backend ``name`` for ``problem``; unknown names raise :class:`OptionError`."""
    if name == "ipopt":
        return IpoptSolver(problem, warm_start=warm_start, options=options, polish=polish)
    if name in ("gn", "rti", "gn-riccati"):
        settings = {"polish": polish, **(options or {})}
        for key, value in _SET_BY_NAME.get(name, {}).items():
            if settings.setdefault(key, value) != value:
                raise OptionError(f"solver_options: {key}={settings[key]!r} contradicts solver={name!r}, which "
                                  f"sets {key}={value!r}")  # fmt: skip
        try:
            return GaussNewtonSolver(problem, **settings)
        except TypeError as exc:
            raise OptionError(f"solver_options: {exc}") from exc
    raise OptionError(f"solver: unknown backend {name!r}; expected one of {list(BACKENDS)}")
