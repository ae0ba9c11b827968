"""Choosing a certified UISE's rate mu and horizon N for accuracy under noise.

:func:`design_uise` and :func:`design_two_stage` certify at several rates, run each guaranteed (mu, N) on noise
trials and keep the most accurate (the search and its scoring: :mod:`uiest.estimators.design_search`). The
estimators' ``design()`` classmethods (:meth:`UISE.design <uiest.estimators.UISE.design>`, ...) run the same search
and return the estimator, with this :class:`Design` as its ``design_report``.
"""

from __future__ import annotations

from typing import Any

from numpy.typing import ArrayLike

from uiest.box import as_vector
from uiest.errors import OptionError
from uiest.estimators.design_search import (
    CONDITION_MARGIN,
    ERROR_TOLERANCE,
    Candidate,
    Design,
    DesignOptions,
    regret,
    search_two_stage,
    search_uise,
)
from uiest.estimators.two_stage import TwoStageUISE, reduced_data_scales
from uiest.estimators.uise import UISE
from uiest.reduction import ReducedModel
from uiest.system import System

__all__ = [
    "CONDITION_MARGIN",
    "ERROR_TOLERANCE",
    "Candidate",
    "Design",
    "DesignOptions",
    "design_two_stage",
    "design_uise",
    "regret",
]


def design_uise(system: System, x0: ArrayLike, *, design: DesignOptions | None = None, **options: Any) -> Design:
    """Certify at several rates and keep the guaranteed (mu, N) whose UISE errs least under noise.

    Parameters
    ----------
    system : System
    x0 : array_like (nx,)
        A typical state (the estimator's prior): where the noise trials start.
    design : DesignOptions, optional
        How to search (largest N, rates, budget, noise trials, records, certification keywords).
    **options
        :class:`DesignOptions`' fields as keywords (``max_horizon=``, ``rates=``, ..., instead of ``design``), and
        window options of the candidate UISEs (``solver``, ...).

    Returns
    -------
    Design
        The chosen certificate and horizon, the guarantee's bound per state (states' units) and every candidate.

    Raises
    ------
    CertificationError
        When no rate certifies; :class:`~uiest.errors.HorizonError` (with the shortest window of the certificates
        found) when no certified rate has an admissible N within ``max_horizon`` (or ``fallback_horizon``, if given).

    Examples
    --------
    >>> from uiest.design import design_uise
    >>> from uiest.models import closed_form
    >>> system = closed_form.system(x_bounds=((-100.0, -10.0), (100.0, 10.0)))
    >>> design = design_uise(system, [0.0, 0.0], rates=(0.8,), max_horizon=10, trials=1)
    >>> round(design.certificate.mu, 2), design.N, design.certificate.certified
    (0.8, 10, True)

    """
    return search_uise(UISE, system, x0, design=design, **options)


def design_two_stage(
    reduced: ReducedModel, x0: ArrayLike, *, design: DesignOptions | None = None, **options: Any
) -> Design:
    """:func:`design_uise` for the two-stage UISE: reduced e-IOSS certificates and Theorem 4.8's bound.

    ``reduced`` is a :class:`~uiest.reduction.ReducedModel`; ``options`` are the
    :class:`~uiest.estimators.TwoStageUISE` keywords (``projection``, window options) and :class:`DesignOptions`'
    fields. N is ranked by Theorem 4.8's settled bound on ``z_sharp``
    (:func:`~uiest.estimators.bounds.two_stage_z_bound`, the one the guarantee carries to the states).
    """
    if not isinstance(reduced, ReducedModel):
        raise OptionError(f"reduced: expected a uiest.reduction.ReducedModel, got {type(reduced).__name__}")
    reduced = reduced_data_scales(reduced, as_vector(x0, reduced.system.nx, "x0"))
    return search_two_stage(TwoStageUISE, reduced, x0, design=design, **options)
