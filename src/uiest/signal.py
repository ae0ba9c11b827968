"""Description of one signal of a system (x, u, w, v or y): names, units, domain, scale."""

from __future__ import annotations

import enum
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from uiest.box import Box, FloatArray
from uiest.checks import check_name, shown
from uiest.errors import ModelError

__all__ = ["ScaleSource", "Signal"]

SIGNAL_KINDS = ("x", "u", "w", "v", "y")
"""The five signals of ``x+ = f(x, u, w), y = h(x, v)``, in this order everywhere."""


class ScaleSource(enum.Enum):
    """Where a component's nominal scale came from."""

    GIVEN = "given"
    """By the user (``x_scale=`` and the like, ``System.with_scales(x=...)``, or a Signal built with its scale)."""
    WIDTH = "domain width"
    """The finite width of the signal's domain (of ``w_range`` for w)."""
    OUTPUT = "output spread"
    """For y: the first-order output change caused by moving x and v by their scales."""
    DATA = "data"
    """Magnitudes of a record or a short model simulation (:mod:`uiest.scales`, ``System.with_scales(trajectory)``)."""
    UNIT = "unit"
    """1: nothing gave a magnitude (an unbounded domain)."""


@dataclass(frozen=True, eq=False)
class Signal:
    """Names, units, domain and nominal scale of one vector signal.

    Parameters
    ----------
    kind : {"x", "u", "w", "v", "y"}
        Which signal of the system this is.
    names, units : tuple of str, length n
        One per component.
    bounds : Box
        The domain (X, U, V, Y; for w always the whole space, see ``System.w_range``).
    scale : ndarray, shape (n,)
        Positive nominal magnitudes; solvers and certificates work in ``z / scale``.
    scale_source : tuple of ScaleSource, length n, optional
        Where each scale came from; default: all ``GIVEN`` (a signal built with its scales).

    """

    kind: str
    names: tuple[str, ...]
    units: tuple[str, ...]
    bounds: Box
    scale: FloatArray
    scale_source: tuple[ScaleSource, ...] = ()

    def __post_init__(self) -> None:
        n = self.bounds.size
        if self.kind not in SIGNAL_KINDS:
            raise ModelError(f"Signal.kind: expected one of {SIGNAL_KINDS}, got {self.kind!r}")
        if len(self.names) != n or len(self.units) != n:
            raise ModelError(
                f"{self.kind}: expected {n} names and units, got {len(self.names)} names and {len(self.units)} units"
            )
        scale = np.array(self.scale, dtype=float, ndmin=1)
        if scale.shape != (n,) or not np.all(np.isfinite(scale)) or not np.all(scale > 0):
            raise ModelError(f"{self.kind}_scale: expected {n} positive finite numbers, got {scale.tolist()}")
        scale.setflags(write=False)
        object.__setattr__(self, "scale", scale)
        sources = tuple(self.scale_source) if self.scale_source else (ScaleSource.GIVEN,) * n  # None too
        if len(sources) != n or not all(isinstance(source, ScaleSource) for source in sources):
            raise ModelError(f"{self.kind}: expected {n} ScaleSource values as scale_source, got {sources!r}")
        object.__setattr__(self, "scale_source", sources)

    @property
    def size(self) -> int:
        """Number of components n."""
        return self.bounds.size

    @classmethod
    def build(
        cls,
        kind: str,
        n: int,
        *,
        bounds: Box | tuple[ArrayLike, ArrayLike] | None = None,
        names: Sequence[str] | None = None,
        units: Sequence[str] | None = None,
        scale: ArrayLike | None = None,
        fallback_scale: ArrayLike | None = None,
        fallback_source: ScaleSource = ScaleSource.WIDTH,
    ) -> Signal:
        """Build a signal from optional user data.

        Default names are ``kind[i]``, default units ``""``. The scale, per component, is the
        given one, else the finite non-zero width of ``bounds``, else ``fallback_scale`` where it is
        positive and finite (its source ``fallback_source``), else 1; :attr:`scale_source` says which.
        """
        box = Box.coerce(bounds, n, f"{kind}_bounds")
        names_t = (
            tuple(f"{kind}[{i}]" for i in range(n))
            if names is None
            else tuple(
                check_name(entry, f"{kind}_names[{i}]", error=ModelError)
                for i, entry in enumerate(_entries(names, kind))
            )
        )
        units_t = ("",) * n if units is None else tuple(str(s) for s in units)
        if scale is not None:
            try:
                scale_arr = np.broadcast_to(np.asarray(scale, dtype=float), (n,)).copy()
            except ValueError as exc:
                raise ModelError(f"{kind}_scale: expected {n} positive numbers, got {scale!r}") from exc
            sources = (ScaleSource.GIVEN,) * n
        else:
            fallback = np.full(n, np.nan) if fallback_scale is None else np.broadcast_to(fallback_scale, (n,))
            has_fallback = np.isfinite(fallback) & (fallback > 0)
            width = box.width
            usable = np.isfinite(width) & (width > 0)
            scale_arr = np.where(usable, np.where(usable, width, 1.0), np.where(has_fallback, fallback, 1.0))
            sources = tuple(
                ScaleSource.WIDTH if wide else fallback_source if known else ScaleSource.UNIT
                for wide, known in zip(usable, has_fallback, strict=True)
            )
        return cls(kind=kind, names=names_t, units=units_t, bounds=box, scale=scale_arr, scale_source=sources)


def _entries(names: object, kind: str) -> list[object]:
    """The entries of a names argument: a sequence that is not a string itself."""
    if isinstance(names, str) or not isinstance(names, Sequence):
        raise ModelError(f"{kind}_names: expected a sequence of strings, got {shown(names)}")
    return list(names)
