"""Measurement-noise models for :func:`uiest.simulate`.

A noise model draws a ``(count, n)`` array from a NumPy ``Generator``; the same generator state
gives the same numbers, bit for bit.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike

from uiest.box import Box, FloatArray
from uiest.checks import real_array
from uiest.errors import DataError, ModelError

__all__ = ["GaussianNoise", "NoiseModel", "UniformNoise"]


@runtime_checkable
class NoiseModel(Protocol):
    """Anything with ``sample(rng, count, n) -> ndarray (count, n)``."""

    def sample(self, rng: np.random.Generator, count: int, n: int) -> FloatArray:
        """Draw ``count`` samples of an ``n``-vector."""
        ...


def _broadcast(value: ArrayLike, n: int, name: str) -> FloatArray:
    arr = real_array(value, name, f"a scalar or {n} real numbers")
    try:
        return np.broadcast_to(arr, (n,)).astype(float)
    except ValueError as exc:
        raise DataError(f"{name}: expected a scalar or {n} values, got shape {arr.shape}") from exc


@dataclass(frozen=True)
class UniformNoise:
    """Independent uniform noise in the box ``lower <= v <= upper`` (scalars broadcast).

    ``UniformNoise.symmetric(3e-6)`` is ``|v_i| <= 3e-6`` for every channel.
    """

    lower: ArrayLike
    upper: ArrayLike

    @classmethod
    def symmetric(cls, bound: ArrayLike) -> UniformNoise:
        """Uniform noise in ``[-bound, bound]`` per channel."""
        b = np.abs(np.asarray(bound, dtype=float))
        return cls(-b, b)

    def box(self, n: int) -> Box:
        """The support as a Box of dimension n."""
        try:
            return Box(_broadcast(self.lower, n, "UniformNoise.lower"), _broadcast(self.upper, n, "UniformNoise.upper"))
        except ModelError as exc:
            raise DataError(f"UniformNoise: {exc}") from None

    def sample(self, rng: np.random.Generator, count: int, n: int) -> FloatArray:
        """Draw ``count`` samples, shape (count, n)."""
        support = self.box(n)
        if not support.is_bounded:
            raise DataError(f"UniformNoise: expected finite bounds, got {support}")
        return rng.uniform(support.lower, support.upper, size=(count, n))


@dataclass(frozen=True)
class GaussianNoise:
    """Independent Gaussian noise with standard deviation ``std`` and mean ``mean`` per channel."""

    std: ArrayLike
    mean: ArrayLike = 0.0

    def sample(self, rng: np.random.Generator, count: int, n: int) -> FloatArray:
        """Draw ``count`` samples, shape (count, n)."""
        std = _broadcast(self.std, n, "GaussianNoise.std")
        if not np.all(np.isfinite(std)) or np.any(std < 0):
            raise DataError(f"GaussianNoise.std: expected non-negative finite values, got {std.tolist()}")
        mean = _broadcast(self.mean, n, "GaussianNoise.mean")
        if not np.all(np.isfinite(mean)):
            raise DataError(f"GaussianNoise.mean: expected finite values, got {mean.tolist()}")
        return mean + std * rng.standard_normal((count, n))
