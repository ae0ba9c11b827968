"""uiest: state estimation for nonlinear systems with unbounded unknown inputs.

The public entry points are :class:`System`, :func:`simulate`, :func:`analyse` (which estimator
a model admits, and why) and the result containers; models live in :mod:`uiest.models`.
"""

from importlib import metadata as _metadata

from uiest.analysis import ModelAnalysis, analyse
from uiest.box import Box
from uiest.errors import (
    BoundWarning,
    CertificationError,
    DataError,
    DomainWarning,
    FailureWarning,
    HorizonError,
    ModelError,
    OptionError,
    SolverError,
    UiestError,
)
from uiest.noise import GaussianNoise, UniformNoise
from uiest.results import Trajectory
from uiest.signal import ScaleSource, Signal, SignalSpec
from uiest.simulate import simulate
from uiest.system import Linearization, System


def _installed_version() -> str:
    """The installed distribution's version (package metadata); ``0+unknown`` for a source tree never installed."""
    try:
        return _metadata.version("uiest")
    except _metadata.PackageNotFoundError:
        return "0+unknown"


__version__ = _installed_version()
"""uiest's version (``uiest --version`` prints it)."""


__all__ = [
    "BoundWarning",
    "Box",
    "CertificationError",
    "DataError",
    "DomainWarning",
    "FailureWarning",
    "GaussianNoise",
    "HorizonError",
    "Linearization",
    "ModelAnalysis",
    "ModelError",
    "OptionError",
    "ScaleSource",
    "Signal",
    "SignalSpec",
    "SolverError",
    "System",
    "Trajectory",
    "UiestError",
    "UniformNoise",
    "__version__",
    "analyse",
    "simulate",
]
