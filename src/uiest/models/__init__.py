"""Registered models: the paper's crop-growth process and small systems with known answers.

``get(name)`` returns a :class:`ModelEntry`; ``names()`` lists what exists; ``register(...)`` adds
a model of one's own; ``load(spec)`` takes a registered name or the path of a model file.

A model file is a Python file whose module has ``system`` (a :class:`~uiest.system.System`) or
``build()`` returning one, and optionally ``setup()`` returning a :class:`SimulationSetup` (its
default simulation, needed by ``uiest simulate``), ``reduction()``, ``jacobian_parameters()`` and
``study()`` returning a :class:`~uiest.experiments.Scenario` (run by ``uiest reproduce MODEL``).
Loading a model file runs it: it is Python code that runs with the user's rights, like a ``setup.py``
(a scenario or sweep naming it runs it in this process and in every worker). Load only files you trust.
"""

from __future__ import annotations

import importlib.util
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from uiest.box import FloatArray
from uiest.errors import ModelError, OptionError, UiestError
from uiest.models import closed_form, crop_growth, linear
from uiest.noise import NoiseModel, UniformNoise
from uiest.reduction import ReducedModel
from uiest.simulate import InputLike
from uiest.system import System

__all__ = ["BUILT_IN", "ModelEntry", "SimulationSetup", "get", "load", "loadable_elsewhere", "names", "register"]


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
    setup: Callable[[], SimulationSetup] | None = None
    reduction: Callable[[], ReducedModel] | None = None
    jacobian_parameters: Callable[[], Callable[..., Any]] | None = None
    """Returns ``theta(x, u)``, the functions the state Jacobian is affine in (an exact certificate cover)."""
    study: Callable[[], Any] | None = None
    """Returns the model's study, a :class:`~uiest.experiments.Scenario` (``uiest reproduce MODEL``)."""

    def simulation(self) -> SimulationSetup:
        """The default simulation; OptionError when the model has none (a model file without ``setup()``)."""
        if self.setup is None:
            raise OptionError(
                f"model: {self.name!r} has no default simulation; give its file a setup() returning "
                "uiest.models.SimulationSetup(x0, steps, u, w, noise)"
            )
        return self.setup()


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
        raise OptionError(
            f"model: unknown name {name!r}; expected one of {names()} or the path of a model file (.py)"
        ) from None


BUILT_IN = frozenset(_REGISTRY)
"""The models every process knows (a spawned worker too)."""

_FILES: dict[str, Path] = {}
"""Registered names of the models loaded from files -> the file (resolved)."""


def loadable_elsewhere(spec: str | Path) -> bool:
    """Whether another process can load ``spec``: a built-in name or a model file (not a run-time registration)."""
    return str(spec).endswith(".py") or str(spec) in BUILT_IN


def register(
    name: str,
    build: Callable[[], System],
    *,
    summary: str = "",
    setup: Callable[[], SimulationSetup] | None = None,
    reduction: Callable[[], ReducedModel] | None = None,
    jacobian_parameters: Callable[[], Callable[..., Any]] | None = None,
    study: Callable[[], Any] | None = None,
    replace: bool = False,
) -> ModelEntry:
    """Register a model under ``name`` (usable wherever a model name is, e.g. in a Scenario).

    ``build()`` returns the :class:`~uiest.system.System`; ``setup()`` its default simulation;
    ``study()`` its study (a :class:`~uiest.experiments.Scenario`).
    Raises OptionError for a name already taken (unless ``replace``) or a ``build`` that is not callable.
    """
    if not isinstance(name, str) or not name or name.endswith(".py"):
        raise OptionError(f"name: expected a non-empty model name (not a file name), got {name!r}")
    if name in _REGISTRY and not replace:
        raise OptionError(f"name: a model called {name!r} is registered already; pass replace=True to replace it")
    if not callable(build):
        raise OptionError(f"build: expected a function returning a System, got {build!r}")
    for label, fun in (("setup", setup), ("reduction", reduction), ("jacobian_parameters", jacobian_parameters),
                       ("study", study)):  # fmt: skip
        if fun is not None and not callable(fun):
            raise OptionError(f"{label}: expected a function or None, got {fun!r}")
    entry = ModelEntry(name, summary, build, setup, reduction, jacobian_parameters, study)
    _REGISTRY[name] = entry
    _FILES.pop(name, None)
    return entry


def load(spec: str | Path) -> ModelEntry:
    """A registered model by name, or the model defined in a Python file (module docstring).

    A file's model is named after the file (``reactor.py`` -> ``reactor``) and registered under
    that name, so studies and sweeps run in this process find it. Where that name belongs to
    another model (a built-in, a registration, or another file of the same name), the file's
    model is registered under its path instead: loading a file never replaces another model.
    Anything the file raises at import, ``SystemExit`` included (``KeyboardInterrupt`` is passed
    on), becomes a ModelError naming the file. The file is executed as Python code with this
    process's rights (like a ``setup.py``): load only files you trust.
    """
    text = str(spec)
    if not text.endswith(".py"):
        return get(text)
    path = Path(text)
    if not path.is_file():
        raise OptionError(f"model: no model file at {path} (expected a .py file or a registered name {names()})")
    module_name = f"uiest_user_model_{path.stem}"
    module_spec = importlib.util.spec_from_file_location(module_name, path)
    assert module_spec is not None and module_spec.loader is not None
    module = importlib.util.module_from_spec(module_spec)
    sys.modules[module_name] = module
    try:
        module_spec.loader.exec_module(module)
    except KeyboardInterrupt:
        raise
    except BaseException as exc:  # SystemExit too: a model file does not end the program
        raise ModelError(f"model: importing {path} raised {_raised(exc)}") from exc
    if isinstance(getattr(module, "system", None), System):
        system = module.system
        build: Callable[[], System] = lambda: system  # noqa: E731
    elif callable(getattr(module, "build", None)):
        build = _checked_build(module.build, path)
    else:
        raise ModelError(f"model: {path} defines neither `system` (a uiest.System) nor `build()` returning one")
    summary = (module.__doc__ or "").strip().splitlines()[0] if module.__doc__ else f"model file {path}"
    resolved = path.resolve()
    name = path.stem if path.stem not in _REGISTRY or _FILES.get(path.stem) == resolved else str(path)
    entry = ModelEntry(name, summary, build, _checked_setup(getattr(module, "setup", None), path),
                       _checked_call(getattr(module, "reduction", None), "reduction()", path),
                       _checked_call(getattr(module, "jacobian_parameters", None), "jacobian_parameters()", path),
                       _checked_call(getattr(module, "study", None), "study()", path))  # fmt: skip
    _REGISTRY[name], _FILES[name] = entry, resolved
    return entry


def _checked_build(build: Callable[[], Any], path: Path) -> Callable[[], System]:
    def checked() -> System:
        system = _user_call(build, "build()", path)
        if not isinstance(system, System):
            raise ModelError(f"model: build() in {path} returned {type(system).__name__}, expected a uiest.System")
        return system

    return checked


def _user_call(fun: Callable[[], Any], label: str, path: Path) -> Any:
    """Call a model file's function; its exception (other than uiest's typed ones) becomes a ModelError naming it."""
    try:
        return fun()
    except (UiestError, KeyboardInterrupt):
        raise
    except BaseException as exc:  # SystemExit too: a model file does not end the program
        raise ModelError(f"model: {label} in {path} raised {_raised(exc)}") from exc


def _raised(exc: BaseException) -> str:
    """``Type: message``, or ``Type`` alone for an exception without a message (``sys.exit()``)."""
    return f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__


def _checked_setup(setup: Callable[[], Any] | None, path: Path) -> Callable[[], SimulationSetup] | None:
    if setup is None:
        return None

    def checked() -> SimulationSetup:
        value = _user_call(setup, "setup()", path)
        if not isinstance(value, SimulationSetup):
            raise ModelError(
                f"model: setup() in {path} returned {type(value).__name__}, expected uiest.models.SimulationSetup"
            )
        return value

    return checked


def _checked_call(fun: Callable[[], Any] | None, label: str, path: Path) -> Callable[[], Any] | None:
    return None if fun is None else (lambda: _user_call(fun, label, path))
