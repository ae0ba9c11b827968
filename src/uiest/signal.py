"""Description of one signal of a system (x, u, w, v or y): names, units, domain, scale."""

from __future__ import annotations

import enum
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, fields
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from uiest.box import Box, FloatArray
from uiest.checks import check_name, shown
from uiest.errors import ModelError, OptionError

__all__ = ["ScaleSource", "Signal", "SignalSpec", "signal_specs"]

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


@dataclass(frozen=True, kw_only=True)
class SignalSpec:
    """What a model states about one signal before its size is known: domain, names, units, scale.

    Every field is optional; :meth:`Signal.build` fills the rest (names ``x[0], ...``, no unit, scales from the
    domain's width) and checks the sizes. Construction checks the types.

    Parameters
    ----------
    bounds : Box or (lower, upper), optional
        The domain in the signal's units (scalars broadcast, ``±inf`` allowed; None: unbounded). Not for w,
        whose known range is :meth:`System.from_functions`' ``w_range``.
    names, units : sequence of str, optional
        One per component.
    scale : array_like, optional
        Positive finite nominal magnitudes (a scalar broadcasts).

    Examples
    --------
    >>> from uiest.signal import SignalSpec
    >>> SignalSpec(bounds=(0.0, 10.0), names=["level"], units=["m"]).names
    ('level',)

    """

    bounds: Box | tuple[ArrayLike, ArrayLike] | None = None
    names: Sequence[str] | None = None
    units: Sequence[str] | None = None
    scale: ArrayLike | None = None

    def __post_init__(self) -> None:
        if self.names is not None:
            if isinstance(self.names, str) or not isinstance(self.names, Sequence):
                raise ModelError(f"names: expected a sequence of strings, got {shown(self.names)}")
            object.__setattr__(self, "names", tuple(self.names))
        if self.units is not None:
            if isinstance(self.units, str) or not isinstance(self.units, Sequence):
                raise ModelError(f"units: expected a sequence of strings, got {shown(self.units)}")
            object.__setattr__(self, "units", tuple(str(unit) for unit in self.units))
        if self.scale is not None:
            try:
                scale = np.array(self.scale, dtype=float, ndmin=1)
            except (TypeError, ValueError):
                raise ModelError(f"scale: expected positive finite numbers, got {shown(self.scale)}") from None
            if scale.ndim != 1 or not np.all(np.isfinite(scale)) or not np.all(scale > 0):
                raise ModelError(f"scale: expected positive finite numbers, got {scale.tolist()}")


_FLAT_FIELDS = ("bounds", "names", "units", "scale")


def signal_specs(given: Mapping[str, Any] | None, flat: dict[str, Any], caller: str) -> dict[str, SignalSpec]:
    """One :class:`SignalSpec` per signal kind from ``given`` (kind -> spec) and flat keywords (``x_bounds``, ...).

    A kind's spec and its flat keywords may not both be given; w takes no ``w_bounds``. OptionError names a
    keyword or key that is neither.
    """
    given = {} if given is None else given
    if not isinstance(given, Mapping) or not set(given) <= set(SIGNAL_KINDS):
        raise OptionError(f"signals: expected a mapping from some of {SIGNAL_KINDS} to SignalSpec, got {shown(given)}")
    specs: dict[str, SignalSpec] = {}
    for kind in SIGNAL_KINDS:
        spec = given.get(kind)
        if spec is not None and not isinstance(spec, SignalSpec):
            raise OptionError(f"signals[{kind!r}]: expected a SignalSpec, got {shown(spec)}")
        allowed = ("names", "units", "scale") if kind == "w" else _FLAT_FIELDS
        values = {name: flat.pop(f"{kind}_{name}") for name in allowed if f"{kind}_{name}" in flat}
        if spec is not None and values:
            raise OptionError(f"signals[{kind!r}] and {', '.join(f'{kind}_{n}' for n in values)} given together")
        try:
            specs[kind] = spec if spec is not None else SignalSpec(**values)
        except ModelError as exc:
            raise ModelError(f"{kind}_{exc}") from None
        if kind == "w" and specs[kind].bounds is not None:
            raise ModelError("w: the unknown input has no domain; give its known range as w_range")
    if flat:
        raise OptionError(f"{caller}: unexpected keyword(s) {', '.join(sorted(flat))}")
    return specs


def flat_signal_keywords() -> tuple[str, ...]:
    """The flat per-signal keywords :func:`signal_specs` takes (``x_bounds``, ``x_names``, ...)."""
    return tuple(
        f"{kind}_{name}" for kind in SIGNAL_KINDS for name in _FLAT_FIELDS if not (kind == "w" and name == "bounds")
    )


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

    @classmethod
    def from_spec(
        cls,
        kind: str,
        n: int,
        spec: SignalSpec,
        *,
        fallback_scale: ArrayLike | None = None,
        fallback_source: ScaleSource = ScaleSource.WIDTH,
    ) -> Signal:
        """:meth:`build` from a :class:`SignalSpec`."""
        data = {field.name: getattr(spec, field.name) for field in fields(SignalSpec)}
        return cls.build(kind, n, **data, fallback_scale=fallback_scale, fallback_source=fallback_source)


def _entries(names: object, kind: str) -> list[object]:
    """The entries of a names argument: a sequence that is not a string itself."""
    if isinstance(names, str) or not isinstance(names, Sequence):
        raise ModelError(f"{kind}_names: expected a sequence of strings, got {shown(names)}")
    return list(names)
