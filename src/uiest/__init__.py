"""uiest: state estimation for nonlinear systems with unbounded unknown inputs.

The public entry points are :class:`System`, :func:`simulate` and the result containers;
models live in :mod:`uiest.models`.
"""

from uiest.box import Box
from uiest.errors import (
    BoundWarning,
    CertificationError,
    DataError,
    DomainWarning,
    HorizonError,
    ModelError,
    OptionError,
    SolverError,
    UiestError,
)
from uiest.noise import GaussianNoise, UniformNoise
from uiest.results import Trajectory
from uiest.signal import ScaleSource, Signal
from uiest.simulate import simulate
from uiest.system import Linearization, System

__version__ = "0.1.0"

__all__ = [
    "BoundWarning",
    "Box",
    "CertificationError",
    "DataError",
    "DomainWarning",
    "GaussianNoise",
    "HorizonError",
    "Linearization",
    "ModelError",
    "OptionError",
    "ScaleSource",
    "Signal",
    "SolverError",
    "System",
    "Trajectory",
    "UiestError",
    "UniformNoise",
    "__version__",
    "simulate",
]
