"""JSON text that any reader parses: NaN and infinities, which JSON (RFC 8259) has no numbers for, become null.

Python's ``json`` writes them as ``NaN`` and ``Infinity`` by default, which JavaScript's ``JSON.parse`` and other
strict readers refuse. A field that is null where a number is expected is not a number or unbounded (an error floor
no bound limits, a rate no solve found); the record's text fields say which.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

__all__ = ["json_text"]


def json_text(data: Any, *, indent: int | None = 2, default: Callable[[Any], Any] | None = None) -> str:
    """``data`` as JSON with every non-finite number null; ``default`` converts what json cannot (as in json.dumps)."""
    return json.dumps(_finite(data, default), indent=indent, allow_nan=False)


def _finite(value: Any, default: Callable[[Any], Any] | None) -> Any:
    """``value`` with its non-finite floats None, numpy values as Python ones, ``default`` applied to the rest."""
    if isinstance(value, bool | int | str) or value is None:
        return value
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, np.ndarray | np.generic):
        return _finite(value.tolist(), default)
    if isinstance(value, Mapping):
        return {key: _finite(item, default) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [_finite(item, default) for item in value]
    if default is None:
        raise TypeError(f"Object of type {type(value).__name__} is not JSON serializable")
    return _finite(default(value), default)
