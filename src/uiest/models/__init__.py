"""Registered models: the paper's crop-growth process and small systems with known answers.

``get(name)`` returns a :class:`ModelEntry`; ``names()`` lists what exists.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from uiest.box import FloatArray
from uiest.errors import OptionError
from uiest.models import closed_form, crop_growth, linear
from uiest.noise import NoiseModel, UniformNoise
from uiest.reduction import ReducedModel
from uiest.simulate import InputLike
from uiest.system import System


@dataclass(frozen=True)
class SimulationSetup:
    """A model's default simulation: initial state, length, inputs and noise."""

    x0: FloatArray
    steps: int
    u: InputLike
    w: InputLike
    noise: NoiseModel | None


@dataclass(frozen=True)
class ModelEntry:
    """A registered model: how to build it and how to simulate it by default."""

    name: str
    summary: str
    build: Callable[[], System]
    setup: Callable[[], SimulationSetup]
    reduction: Callable[[], ReducedModel] | None = None
    jacobian_parameters: Callable[[], Callable[..., Any]] | None = None
    """Returns ``theta(x, u)``, the functions the state Jacobian is affine in (an exact certificate cover)."""


def _crop_setup() -> SimulationSetup:
    scenario = crop_growth.DEFAULT_SCENARIO
    return SimulationSetup(
        x0=np.array(scenario.x0),
        steps=scenario.steps,
        u=None,
        w=crop_growth.UnknownInputLaw(),
        noise=scenario.noise(),
    )


def closed_form_unknown_input(k: int, x: FloatArray) -> FloatArray:
    """Default unknown input of ``closed-form``: ``-x1/2 + 2 sin(0.2 k)`` (state dependent, keeps x1 bounded)."""
    return np.array([-0.5 * x[0] + 2.0 * np.sin(0.2 * k)])


def _closed_form_setup() -> SimulationSetup:
    return SimulationSetup(
        x0=np.array([0.5, 1.0]),
        steps=200,
        u=np.zeros(1),
        w=closed_form_unknown_input,
        noise=UniformNoise.symmetric(1e-2),
    )


def linear_unknown_input(k: int, x: FloatArray) -> FloatArray:
    """Default unknown input of ``linear-example``: a growing oscillation ``(1 + k/50) sin(0.1 k)``."""
    return np.array([(1.0 + k / 50.0) * np.sin(0.1 * k)])


def _linear_setup() -> SimulationSetup:
    return SimulationSetup(
        x0=np.array([0.5, -0.5, 0.25]), steps=200, u=None, w=linear_unknown_input, noise=UniformNoise.symmetric(1e-3)
    )


_REGISTRY: dict[str, ModelEntry] = {
    entry.name: entry
    for entry in (
        ModelEntry(
            crop_growth.NAME,
            "The paper's simplified crop-growth process (CO2, two crop weights; w = 1 - exp(-45 x_d2))",
            crop_growth.system,
            _crop_setup,
            crop_growth.reduction,
            crop_growth.jacobian_parameters,
        ),
        ModelEntry(
            closed_form.NAME,
            "Nonlinear 2-state system whose unknown-input estimation error has a closed form",
            closed_form.system,
            _closed_form_setup,
            closed_form.reduction,
            closed_form.jacobian_parameters,
        ),
        ModelEntry(
            "linear-example",
            "LTI system with 3 states, 1 unknown input, invariant zeros {0.5, 0.2}",
            linear.example,
            _linear_setup,
        ),
    )
}


def names() -> list[str]:
    """Names of the registered models."""
    return sorted(_REGISTRY)


def get(name: str) -> ModelEntry:
    """The registered model called ``name``; raises :class:`OptionError` for unknown names."""
    try:
        return _REGISTRY[name]
    except KeyError:
        raise OptionError(f"model: unknown name {name!r}; expected one of {names()}") from None
