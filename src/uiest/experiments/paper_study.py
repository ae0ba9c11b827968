"""The built-in studies: the paper's study of the crop-growth model, and a model's study by its entry.

The models do not know the experiments: a model file's ``study()`` is registered with its entry
(:class:`uiest.models.ModelEntry`), and the crop-growth model's study lives here.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

from uiest.experiments.scenario import EstimatorSpec, Scenario
from uiest.models import ModelEntry, crop_growth

__all__ = ["BUILT_IN_STUDIES", "crop_growth_study", "study_of"]


def crop_growth_study() -> Scenario:
    """The paper's study (Section "Numerical example") with every open choice named.

    N = 30 and mu = 0.48 for all three schemes (the paper's values); ``x_hat^c_0 = y^c_0``;
    crop-weight priors at the centre of X; x0 drawn from ``CropScenario.x0_box``; 300 steps of
    60 s; 20 runs; uniform noise ``|v| <= 3e-6`` in the noisy case. Output weights 1e6 per scaled
    unit against prior and noise weights 1 (the paper does not give its weights). Beside them,
    the UISE with the weights and the horizon of its certificate (strong detectability holds at
    mu = 0.48 with N >= 3) and the two-stage UISE with the weights of the reduced model's
    e-IOSS certificate (which holds only near mu = 1, so its N = 30 is below the theorem's).
    """
    crop = crop_growth.DEFAULT_SCENARIO
    return Scenario(
        name="crop-growth",
        model=crop_growth.NAME,
        steps=crop.steps,
        runs=20,
        x0=crop.x0,
        x0_lower=crop.x0_box[0],
        x0_upper=crop.x0_box[1],
        prior=(math.nan, *crop.prior_d),
        prior_from_output=((0, 0),),
        settle=30,
        focus_state=1,
        estimators=(
            EstimatorSpec("UISE", "uise"),
            EstimatorSpec("two-stage UISE", "two-stage"),
            EstimatorSpec("standard MHE", "standard-mhe"),
            EstimatorSpec("UISE (certified)", "uise", N=0, weights="certificate"),
            EstimatorSpec("two-stage UISE (certified)", "two-stage", weights="certificate"),
            EstimatorSpec("EKF (tuned)", "ekf"),
            EstimatorSpec("UKF (tuned)", "ukf"),
        ),
    )


BUILT_IN_STUDIES: dict[str, Callable[[], Scenario]] = {crop_growth.NAME: crop_growth_study}
"""The studies of the built-in models, by model name."""


def study_of(entry: ModelEntry) -> Callable[[], Any] | None:
    """The model's study: the built-in one of its name, else the ``study()`` of its file; None when it has none."""
    return BUILT_IN_STUDIES.get(entry.name, entry.study)
