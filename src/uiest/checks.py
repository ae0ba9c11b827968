"""Checks of user input shared across uiest: typed errors naming the argument, the expected and the received value."""

from __future__ import annotations

import numbers
from typing import Any

import numpy as np
from numpy.typing import NDArray

from uiest.errors import DataError, OptionError

MAX_SAMPLES = 1_000_000
"""Most random points one call may draw (cover samples, verification pairs, assumption-check points).

Ten times the default verification; a larger count is refused before anything is allocated
(10**6 verification pairs take about 7 s and 0.3 GB on the closed-form model)."""

DOMAIN_TOL = 1e-12
"""Known inputs may leave U by this fraction of its width (rounding) before they are refused."""


def shown(value: Any) -> str:
    """A short description of a received value for an error message."""
    if isinstance(value, np.ndarray):
        return f"an array of shape {value.shape} and dtype {value.dtype}"
    text = repr(value)
    return text if len(text) <= 80 else f"an object of type {type(value).__name__} ({text[:60]}...)"


def check_int(
    value: Any, name: str, *, low: int = 0, high: int | None = None, error: type[Exception] = OptionError
) -> int:
    """``value`` as an int in ``[low, high]`` (bools refused), else ``error`` naming ``name``."""
    if (
        isinstance(value, bool)
        or not isinstance(value, numbers.Integral)
        or value < low
        or (high is not None and value > high)
    ):
        wanted = f">= {low}" if high is None else f"in [{low}, {high:_}]"
        raise error(f"{name}: expected an integer {wanted}, got {shown(value)}")
    return int(value)


def check_seed(seed: Any, name: str = "seed", *, error: type[Exception] = OptionError) -> int:
    """A random seed: an integer >= 0."""
    return check_int(seed, name, low=0, error=error)


def check_samples(value: Any, name: str, *, low: int = 1, error: type[Exception] = OptionError) -> int:
    """A count of random points: an integer in ``[low, MAX_SAMPLES]``."""
    return check_int(value, name, low=low, high=MAX_SAMPLES, error=error)


def check_real(value: Any, name: str, expected: str, *, error: type[Exception] = OptionError) -> float:
    """``value`` as a float when it is a real number (bools and strings refused); range checks are the caller's."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise error(f"{name}: expected {expected}, got {shown(value)}")
    return float(value)


def check_callable(value: Any, name: str, *, error: type[Exception] = OptionError) -> Any:
    """``value`` if it is None or callable."""
    if value is not None and not callable(value):
        raise error(f"{name}: expected a callable or None, got {shown(value)}")
    return value


def real_array(value: Any, name: str, expected: str, *, error: type[Exception] = DataError) -> NDArray[np.float64]:
    """``value`` as a float array; complex numbers, strings and objects that are not real numbers are refused."""
    try:
        arr = np.asarray(value)
        if arr.dtype.kind not in "biufO":
            raise TypeError(arr.dtype)
        return np.array(arr, dtype=float)
    except (TypeError, ValueError) as exc:
        raise error(f"{name}: expected {expected}, got {shown(value)}") from exc
