"""Result containers: frozen dataclasses of time-first arrays."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from uiest.box import FloatArray
from uiest.checks import real_array
from uiest.errors import DataError


def _freeze(array: FloatArray, name: str) -> FloatArray:
    out = real_array(array, name, "an array of real numbers")
    out.setflags(write=False)
    return out


@dataclass(frozen=True, eq=False)
class Trajectory:
    """A simulated trajectory of ``x[k+1] = f(x[k], u[k], w[k]), y[k] = h(x[k], v[k])``.

    Index convention: ``u[k]`` and ``w[k]`` act between ``k`` and ``k+1``; ``x[k]``, ``v[k]``,
    ``y[k]`` belong to time ``t[k] = k dt``.

    Attributes
    ----------
    t : ndarray, shape (K+1,)
    x : ndarray, shape (K+1, nx)
    u : ndarray, shape (K, nu)
    w : ndarray, shape (K, nw)
    v : ndarray, shape (K+1, nv)
    y : ndarray, shape (K+1, ny)
    names : mapping from "x", "u", "w", "v", "y" to the component names
    system_name : str
    seed : int or None
        The seed the noise was drawn with.
    x_outside : ndarray, shape (K+1,) of bool
        Where the state left the domain X (estimators constrain their estimates to X).
    v_outside : ndarray, shape (K+1,) of bool
        Where the noise left its domain V.

    """

    t: FloatArray
    x: FloatArray
    u: FloatArray
    w: FloatArray
    v: FloatArray
    y: FloatArray
    names: Mapping[str, tuple[str, ...]] = field(default_factory=dict)
    system_name: str = "system"
    seed: int | None = None
    time_unit: str = "s"
    x_outside: NDArray[np.bool_] | None = None
    v_outside: NDArray[np.bool_] | None = None

    def __post_init__(self) -> None:
        for name in ("t", "x", "u", "w", "v", "y"):
            object.__setattr__(self, name, _freeze(getattr(self, name), name))
        if self.t.ndim != 1 or self.t.size < 1:
            raise DataError(f"t: expected shape (K+1,) with K+1 >= 1, got {self.t.shape}")
        samples = self.t.size
        for name in ("x", "u", "w", "v", "y"):
            arr, rows = getattr(self, name), samples - 1 if name in ("u", "w") else samples
            if arr.ndim != 2 or arr.shape[0] != rows:
                wanted = f"({'K' if rows < samples else 'K+1'}, n{name})"
                raise DataError(f"{name}: expected shape {wanted} with K+1 = len(t) = {samples}, got {arr.shape}")
        for name in ("x_outside", "v_outside"):
            value = getattr(self, name)
            flags = np.zeros(self.t.shape[0], dtype=bool) if value is None else np.array(value, dtype=bool)
            if flags.shape != self.t.shape:
                raise DataError(f"{name}: expected shape {self.t.shape} (one flag per time index), got {flags.shape}")
            flags.setflags(write=False)
            object.__setattr__(self, name, flags)
        object.__setattr__(self, "names", MappingProxyType({k: tuple(v) for k, v in self.names.items()}))

    @property
    def steps(self) -> int:
        """Number of transitions K."""
        return int(self.u.shape[0])

    def to_pandas(self) -> pd.DataFrame:
        """One row per time index k = 0..K (u and w are NaN in the last row: no transition), then the flags."""
        columns: dict[str, FloatArray] = {"t": self.t}
        for kind in ("x", "u", "w", "v", "y"):
            data = getattr(self, kind)
            if kind in ("u", "w"):
                data = np.vstack([data, np.full((1, data.shape[1]), np.nan)])
            names = self.names.get(kind) or tuple(f"{kind}[{i}]" for i in range(data.shape[1]))
            for i, name in enumerate(names):
                columns[name] = data[:, i]
        frame = pd.DataFrame(columns)
        frame["x_outside"] = self.x_outside
        frame["v_outside"] = self.v_outside
        frame.index.name = "k"
        return frame
