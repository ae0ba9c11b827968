"""``analyse(system)``: which estimator a model admits, and why (:class:`~uiest.analysis.ModelAnalysis`)."""

from __future__ import annotations

import time

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike

from uiest.analysis.designs import delayed_design, strong_design
from uiest.analysis.near_zeros import find_near_zeros
from uiest.analysis.points import POINTS, input_degrees, linearise, relative_degrees
from uiest.analysis.random_walk import random_walk_detectability
from uiest.analysis.recommend import decide
from uiest.analysis.report import ModelAnalysis
from uiest.analysis.zeros import find_zeros
from uiest.box import as_vector
from uiest.checks import shown
from uiest.delay import matching_ranks
from uiest.errors import ModelError, OptionError
from uiest.system import System
from uiest.window.size import check_horizon

__all__ = ["DEFAULT_MAX_HORIZON", "analyse"]

DEFAULT_MAX_HORIZON = 60
"""The longest estimator window :func:`analyse` considers by default."""


def analyse(
    system: System, *, x0: ArrayLike | None = None, max_horizon: int = DEFAULT_MAX_HORIZON, points: int = POINTS,
    seed: int = 0,
) -> ModelAnalysis:  # fmt: skip
    """Analyse ``system``: its structure, zeros and near-zeros, certificates, and the estimator that suits it.

    Parameters
    ----------
    system : System
        Needs at least one output.
    x0 : array_like (nx,), optional
        The reference point (an operating point in X): the first linearisation point, where the
        zeros and channels are reported, and the estimators' prior. Default: X's centre (the
        centre of X's finite sides; the state scale's box where a side is infinite).
    max_horizon : int
        The longest estimator window N considered (the UISE is recommended only with a window up to it).
    points : int
        Points of X x U at which the model is linearised (the reference point included).
    seed : int
        Seed of those points.

    Returns
    -------
    ModelAnalysis
        Matching ranks and the samples each unknown input needs to reach an output (and, for a
        model sampled by ``from_ode``, its continuous-time relative degree); the invariant zeros of
        the linearised model at the points (the ones sampling created named as such) and per
        channel; the near-zeros and the error floor they imply (:mod:`uiest.analysis.near_zeros`);
        the strong-detectability certificate and the guarantee of the UISE it designs; the delayed
        UISE where matching fails; the recommended estimator with its cause and reason
        (:mod:`uiest.analysis.recommend`).

    Raises
    ------
    OptionError
        ``system`` not a System, or a bad ``max_horizon``, ``points`` or ``seed``.
    ModelError
        No output, or Jacobians that are not finite at the reference point.
    DataError
        ``x0`` of the wrong shape or not finite.

    Examples
    --------
    >>> from uiest import analyse
    >>> from uiest.models import closed_form
    >>> analysis = analyse(closed_form.system(x_bounds=((-100.0, -10.0), (100.0, 10.0))))
    >>> analysis.rank_CB, analysis.rank_B, analysis.strong.certified
    (1, 1, True)
    >>> analysis.recommendation.value, analysis.cause.value
    ('UISE', "the UISE's guarantee is informative")

    """
    start = time.thread_time()
    if not isinstance(system, System):
        raise OptionError(f"system: expected a uiest.System, got {shown(system)}")
    max_horizon = check_horizon(max_horizon, "max_horizon", system)
    if system.ny == 0:
        raise ModelError("h: the analysis needs at least one output")
    reference = None if x0 is None else as_vector(x0, system.nx, "x0")
    lin = linearise(system, reference, points=points, seed=seed)
    prior = lin.x[0]
    rank_CB, rank_B = matching_ranks(system, seed=seed)
    steps = input_degrees(relative_degrees(lin.A, lin.B, lin.C))
    continuous = None
    if lin.A_c is not None and lin.G is not None:
        continuous = input_degrees(relative_degrees(lin.A_c, lin.G, lin.C))
    zeros = find_zeros(system, lin)
    strong = strong_design(system, prior, max_horizon)
    rate = strong.certificate.rate if strong.certified else None
    near = find_near_zeros(system, lin, rate)
    walk = random_walk_detectability(lin)
    matching = rank_CB == rank_B
    delayed = None if matching else delayed_design(system, prior, max_horizon)
    recommendation, cause = decide(matching, zeros, strong, delayed, walk)
    width = system.x.bounds.width
    return ModelAnalysis(
        system_name=system.name, state_names=tuple(system.x.names), state_units=tuple(system.x.units),
        input_names=tuple(system.w.names), output_names=tuple(system.y.names), output_units=tuple(system.y.units),
        dt=system.dt, time_unit=system.time_unit,
        continuous_method=None if system.sampled_from is None else system.sampled_from.method,
        x_width=np.where(np.isfinite(width), width, system.x.scale), reference=prior,
        x_bounded=bool(system.x.bounds.is_bounded), linear=jacobians_constant(system),
        rank_CB=rank_CB, rank_B=rank_B, steps=steps,
        continuous_degree=continuous, zeros=zeros, near_zeros=near, random_walk=walk, strong=strong, delayed=delayed,
        recommendation=recommendation, cause=cause, max_horizon=max_horizon, cpu_time=time.thread_time() - start,
    )  # fmt: skip


def jacobians_constant(system: System) -> bool:
    """Whether the Jacobians A, B (of w) and C depend on none of x, u, w, v (a linear or affine model).

    Decided from the model's expressions: a nonlinear model's Jacobians sampled at one point would look constant.
    """
    jacobian = system.jacobian_function
    symbols = [ca.SX.sym(f"a{i}", jacobian.size_in(i)) for i in range(jacobian.n_in())]
    A, _, B, C, _ = jacobian(*symbols)
    return not any(ca.depends_on(matrix, symbol) for matrix in (A, B, C) for symbol in symbols)
