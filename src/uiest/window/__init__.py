"""The moving-window least-squares problem shared by every optimisation-based estimator.

- :class:`WindowModel`: what a problem needs from a model (a System, or the two-stage UISE's
  reduced model with node data and node constraints).
- :class:`WindowProblem`: decision variables (scaled), residuals, dynamics constraints,
  simple bounds; the window data are parameters, so it is built once per window length.
- :func:`make_solver`: backends ``"ipopt"`` (the reference), ``"gn"`` (Gauss-Newton SQP, the
  estimators' default :data:`DEFAULT_BACKEND`), ``"rti"`` (real-time iteration) and ``"gn-riccati"``
  (Gauss-Newton with the stage-wise Riccati QP of :mod:`uiest.window.riccati_qp`), returning
  :class:`WindowSolution`.
- :func:`shifted_guess`, :func:`predicted_guess`: warm starts (previous solution shifted in time).
"""

from uiest.window.backends import BACKENDS, DEFAULT_BACKEND, make_solver
from uiest.window.model import WindowModel
from uiest.window.problem import WindowProblem, WindowTrajectory, WindowWeights, sqrt_psd
from uiest.window.solvers import (
    IPOPT_DEFAULTS,
    IPOPT_WARM_START,
    IpoptSolver,
    WindowSolution,
    WindowSolver,
)
from uiest.window.warmstart import predicted_guess, shifted_guess

__all__ = [
    "BACKENDS",
    "DEFAULT_BACKEND",
    "IPOPT_DEFAULTS",
    "IPOPT_WARM_START",
    "IpoptSolver",
    "WindowModel",
    "WindowProblem",
    "WindowSolution",
    "WindowSolver",
    "WindowTrajectory",
    "WindowWeights",
    "make_solver",
    "predicted_guess",
    "shifted_guess",
    "sqrt_psd",
]
