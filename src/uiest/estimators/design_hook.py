"""How the estimators' ``design()`` classmethods reach :mod:`uiest.design`, which sits above them.

The design layer builds and scores estimators, so the estimators do not import it: :mod:`uiest.design`
registers its functions here when it is imported, and :mod:`uiest.estimators` imports it, so the functions
are registered whenever an estimator class can be reached.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

__all__ = ["design_function", "register"]

_REGISTERED: dict[str, Callable[..., Any]] = {}


def register(**functions: Callable[..., Any]) -> None:
    """Register the design layer's functions under their names (``design_uise=design_uise, ...``)."""
    _REGISTERED.update(functions)


def design_function(name: str) -> Callable[..., Any]:
    """The registered design function ``name``; LookupError when :mod:`uiest.design` registered none of that name."""
    try:
        return _REGISTERED[name]
    except KeyError:
        raise LookupError(f"uiest.design registered no function {name!r} (it registers when imported)") from None
