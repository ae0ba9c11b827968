r"""The range of weights for which a window problem stays well posed in double precision.

The window problems are solved in scaled coordinates (:mod:`uiest.window.problem`): a weight
``W`` of a signal with scales ``s`` enters as ``W~ = S W S`` (``S = diag(s)``), and a node one
step older than another carries the discount ``rate`` once more. A window's cost and its
Gauss-Newton matrix ``J^T J`` are sums of these terms, so a term smaller than ``eps`` (the double
precision rounding unit, 2.2e-16) times the largest is lost in rounding: the information it
carries (the prior that fixes the window's first state, the older outputs) no longer counts,
and the solver reports convergence on a different problem. The weights are accepted when, over
the blocks that must count (the prior ``P``, the output and noise weights, and the standard
MHE's disturbance weight),

    rate * smallest eigenvalue of any W~  >=  eps * largest eigenvalue of any W~,

that is when a one-step window keeps every term, and every eigenvalue lies in
``[sqrt(tiny), sqrt(huge)]`` (about 1.5e-154 .. 1.3e154), where products of two weights stay
finite and normal. The prior weight must be positive definite (a zero eigenvalue leaves a
direction of the first state fixed by nothing but the outputs, which the window need not
determine). A longer window discounts its oldest terms further: that is the estimator's design
(the prior is forgotten at the rate the certificate allows), not a loss of precision.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from uiest.errors import OptionError

__all__ = ["check_weight_range"]

EPS = float(np.finfo(float).eps)
"""Double-precision rounding unit: a term below ``EPS`` times the largest vanishes from a sum."""

SMALLEST_WEIGHT = float(np.sqrt(np.finfo(float).tiny))
"""Smallest scaled eigenvalue accepted: the product of two weights stays a normal double."""

LARGEST_WEIGHT = float(np.sqrt(np.finfo(float).max))
"""Largest scaled eigenvalue accepted: the product of two weights stays finite."""


def check_weight_range(
    rate: float, rate_name: str, blocks: Sequence[tuple[str, NDArray[np.float64], NDArray[np.float64], bool]]
) -> None:
    """OptionError naming the weight and the range when the window problem would lose terms in rounding.

    Parameters
    ----------
    rate : float
        The discount per step (``mu``, ``eta``), in (0, 1).
    rate_name : str
        Its name in messages (``"weights.mu"``).
    blocks : sequence of (name, W, s, positive)
        Each weight matrix ``W (n, n)`` in original units, its signal's scales ``s (n,)``, and
        whether it must be positive definite (else positive semidefinite: zero eigenvalues are
        terms the cost leaves out on purpose and are not compared).

    """
    found: list[tuple[float, float, str]] = []
    for name, matrix, scale, positive in blocks:
        if matrix.size == 0:
            continue
        eig = np.linalg.eigvalsh(np.outer(scale, scale) * matrix)
        if positive and not eig.min() > 0.0:
            raise OptionError(
                f"{name}: expected a positive definite weight, got smallest eigenvalue {eig.min():.3g} (in scaled "
                "units S W S): the window's first state is then fixed by nothing in the cost where the outputs "
                "do not determine it"
            )
        kept = eig[eig > 0.0]
        if kept.size:
            found.append((float(kept.min()), float(kept.max()), name))
    for low, high, name in found:
        if low < SMALLEST_WEIGHT or high > LARGEST_WEIGHT:
            value = low if low < SMALLEST_WEIGHT else high
            raise OptionError(
                f"{name}: expected eigenvalues (in scaled units S W S) in [{SMALLEST_WEIGHT:.3g}, "
                f"{LARGEST_WEIGHT:.3g}], where products of two weights stay finite and normal doubles; got {value:.3g}"
            )
    if not found:
        return
    low, low_name = min((item[0], item[2]) for item in found)
    high, high_name = max((item[1], item[2]) for item in found)
    if rate * low < EPS * high:
        raise OptionError(
            f"{rate_name}, {low_name}, {high_name}: the window problem's weights would span {high / (rate * low):.3g} "
            f"(largest scaled eigenvalue {high:.3g} of {high_name}; smallest {low:.3g} of {low_name}, times "
            f"{rate_name} = {rate:.3g} one step older); expected at most 1/eps = {1 / EPS:.3g}, beyond which the "
            "smaller terms vanish in double-precision rounding: bring the discount and the weights into this range, "
            "or give the signals scales of their magnitudes (System.with_scales; a scale taken from a domain far "
            "wider than the signal makes the weights of precise measurements large)"
        )
