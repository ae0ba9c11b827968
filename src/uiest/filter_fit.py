r"""The Kalman filters' fit to a record: the unknown input's model, its variance and the prior's factor.

:meth:`KalmanFilter.fit <uiest.estimators.kalman.KalmanFilter.fit>` maximises the innovations' log-likelihood
(:mod:`uiest.likelihood`) over three things, all from the record alone:

- the input model (:class:`~uiest.input_model.InputModel`: a random walk or an integrated random walk);
- its variance ``q`` (``w_variance = q * w.scale^2``);
- a factor ``c`` on the prior's covariances (``P0``, ``W0``, ``W0_rate`` times c): how far the record trusts the
  prior ``x0_prior``. The filter's early steps, before the data have separated the states from the unknown input,
  follow from it, and the likelihood of those steps' innovations measures it.

For each model, :func:`fit_filter` searches ``q`` at ``c = 1`` (the prior as given), then ``c`` at that ``q``, then
``q`` again at the chosen ``c`` (coordinate ascent, one round; each search is :func:`~uiest.likelihood.
maximise_likelihood`'s grid and golden-section refinement). The models have the same number of fitted parameters
(``q`` and ``c``), so their maximised log-likelihoods are compared as they are: the larger is chosen, and
:class:`FilterFit` keeps every model's profiles and the margin between the two best.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, replace

import numpy as np

from uiest.box import FloatArray
from uiest.errors import OptionError
from uiest.input_model import InputModel
from uiest.likelihood import LIKELIHOOD_INTERVAL, LikelihoodProfile, Score, check_grid, maximise_likelihood

PRIOR_GRID = np.logspace(-8, 2, 11)
"""Factors of the prior's covariances tried by default: from a prior trusted to 1e-4 of its standard deviations to
one ten times wider than given."""


@dataclass(frozen=True, kw_only=True)
class ModelFit:
    """One input model's maximum: its variance profile at the chosen prior factor and the prior factor's profile.

    Attributes
    ----------
    input_model : InputModel
    variance : LikelihoodProfile
        ``L`` against ``q`` (``w_variance = q * w.scale^2``) at the chosen prior factor.
    prior : LikelihoodProfile or None
        ``L`` against the prior factor ``c`` at the first search's ``q``; None when the prior was held (factor 1).

    """

    input_model: InputModel
    variance: LikelihoodProfile
    prior: LikelihoodProfile | None

    @property
    def maximum(self) -> float:
        """The largest log-likelihood found for this model."""
        return self.variance.maximum

    @property
    def prior_factor(self) -> float:
        """The chosen factor on the prior's covariances (1 when held)."""
        return 1.0 if self.prior is None else self.prior.chosen

    def summary(self) -> str:
        """One line: the model, the variance and the prior factor chosen."""
        text = f"{self.input_model.value}: {self.variance.summary()}"
        return text if self.prior is None else f"{text}; {self.prior.summary()}"

    def to_dict(self) -> dict[str, object]:
        """Plain data: the model, its maximum and both profiles (:meth:`LikelihoodProfile.to_dict`)."""
        return {
            "input_model": self.input_model.value,
            "maximum": self.maximum,
            "variance": self.variance.to_dict(),
            "prior": None if self.prior is None else self.prior.to_dict(),
        }


@dataclass(frozen=True, kw_only=True)
class FilterFit:
    """What :func:`fit_filter` found: every input model's :class:`ModelFit`, in the order tried.

    ``failed`` holds the models none of whose filters ran through the record (each with the reason).
    """

    fits: tuple[ModelFit, ...]
    failed: tuple[tuple[InputModel, str], ...] = ()

    @property
    def best(self) -> ModelFit:
        """The model with the largest maximised log-likelihood."""
        return max(self.fits, key=lambda fit: fit.maximum)

    @property
    def margin(self) -> float:
        """The best model's maximum minus the next one's (inf with one model tried)."""
        others = [fit.maximum for fit in self.fits if fit is not self.best]
        return float(self.best.maximum - max(others)) if others else float("inf")

    def summary(self) -> str:
        """One line: the chosen model and its choices, its log-likelihood and the other models'."""
        best = self.best
        text = f"{best.summary()}; log-likelihood {best.maximum:.1f}"
        if self.failed:
            text += "; " + ", ".join(f"{model.value}: every filter diverged or failed" for model, _ in self.failed)
        if len(self.fits) == 1:
            return text
        others = ", ".join(f"{fit.maximum:.1f} ({fit.input_model.value})" for fit in self.fits if fit is not best)
        if self.margin < LIKELIHOOD_INTERVAL:
            return f"{text} against {others}: within {LIKELIHOOD_INTERVAL}, the record hardly tells them apart"
        return f"{text} against {others}"

    def to_dict(self) -> dict[str, object]:
        """Plain data: the chosen model, the margin and every model's fit."""
        return {
            "chosen": self.best.input_model.value,
            "margin": self.margin,
            "fits": [fit.to_dict() for fit in self.fits],
            "failed": {model.value: reason for model, reason in self.failed},
        }


def check_models(models: object | None) -> tuple[InputModel, ...]:
    """The input models to try: every :class:`InputModel` for None, else the given ones (unique, in order)."""
    if models is None:
        return tuple(InputModel)
    items = [models] if isinstance(models, str | InputModel) else models
    try:
        if not isinstance(items, Iterable):
            raise TypeError
        chosen = tuple(dict.fromkeys(InputModel(m) for m in items))
    except (TypeError, ValueError):
        chosen = ()
    if not chosen:
        raise OptionError(f"input_models: expected some of {[m.value for m in InputModel]}, got {models!r}")
    return chosen


def fit_filter(
    score: Callable[[InputModel, float, float], Score],
    *,
    models: Sequence[InputModel],
    variances: FloatArray,
    prior_factors: FloatArray | None,
    scale: FloatArray,
    extend: int = 0,
) -> FilterFit:
    """Maximise ``score(model, q, c)`` for each model (module docstring); ``prior_factors`` None holds c = 1.

    ``variances`` and ``prior_factors`` are grids (:func:`~uiest.likelihood.check_grid`); ``scale`` is w's (nw,);
    ``extend``: points the variances' grid may grow by beyond an end (:func:`~uiest.likelihood.maximise_likelihood`).
    A model every run of whose search diverged or failed is kept in :attr:`FilterFit.failed`; OptionError when
    every model's did (:func:`~uiest.likelihood.maximise_likelihood`).
    """
    fits, failed = [], []
    for model in models:
        try:
            fits.append(_fit_model(score, model, variances, prior_factors, scale, extend))
        except OptionError as exc:
            failed.append((model, str(exc)))
    if not fits:
        raise OptionError("; ".join(f"{model.value}: {reason}" for model, reason in failed))
    return FilterFit(fits=tuple(fits), failed=tuple(failed))


def _fit_model(
    score: Callable[[InputModel, float, float], Score],
    model: InputModel,
    variances: FloatArray,
    prior_factors: FloatArray | None,
    scale: FloatArray,
    extend: int,
) -> ModelFit:
    """One model's coordinate ascent: q at c = 1, c at that q, q at that c (module docstring)."""

    def of_q(c: float) -> Callable[[float], Score]:
        return lambda q: score(model, q, c)

    variance = maximise_likelihood(of_q(1.0), variances, name="w_variance", unit="w.scale^2", scale=scale,
                                   extend=extend)  # fmt: skip
    if prior_factors is None:
        return ModelFit(input_model=model, variance=variance, prior=None)
    q = variance.chosen
    prior = maximise_likelihood(lambda c: score(model, q, c), prior_factors, name="prior_factor",
                                unit="x (P0, W0, W0_rate)", scale=np.ones(1))  # fmt: skip
    if prior.chosen != 1.0:  # q searched again at the chosen c, its grid holding the q already scored there
        again = np.union1d(variance.grid, [q])
        grown = variance.extended  # points of `again` beyond the given grid
        variance = maximise_likelihood(of_q(prior.chosen), again, name="w_variance", unit="w.scale^2", scale=scale,
                                       extend=extend - grown)  # fmt: skip
        variance = replace(variance, extended=variance.extended + grown)
    return ModelFit(input_model=model, variance=variance, prior=prior)


def check_prior_factors(prior_factors: object | None) -> FloatArray | None:
    """The prior factors' grid: :data:`PRIOR_GRID` for None, None (held at 1) for ``[1]``, else checked."""
    if prior_factors is None:
        return PRIOR_GRID.copy()
    grid = check_grid(prior_factors, "prior_factors")
    return None if np.array_equal(grid, [1.0]) else grid


__all__ = ["PRIOR_GRID", "FilterFit", "ModelFit", "check_models", "check_prior_factors", "fit_filter"]
