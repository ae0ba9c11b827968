"""Typed exceptions of uiest.

Every error raised for bad user input is one of these, and its message names the argument,
what was expected and what came. The CLI turns them into a one-line message and exit code 2.
"""

from __future__ import annotations

__all__ = [
    "BoundWarning",
    "CertificationError",
    "DataError",
    "DomainWarning",
    "FailureWarning",
    "HorizonError",
    "ModelError",
    "OptionError",
    "SolverError",
    "StorageError",
    "UiestError",
]


class UiestError(Exception):
    """Base class of every error raised by uiest on purpose."""


class ModelError(UiestError, ValueError):
    """A system description is inconsistent (sizes, domains, non-finite model values)."""


class DataError(UiestError, ValueError):
    """Data handed to a function has the wrong shape, non-finite values or leaves its domain."""


class OptionError(UiestError, ValueError):
    """An unknown name or an invalid option value (model name, keyword, setting)."""


class CertificationError(UiestError, RuntimeError):
    """A certificate was required but could not be established."""


class HorizonError(CertificationError):
    """Certificates hold, but each needs a longer window than the largest horizon allowed.

    Attributes
    ----------
    limit : int
        The largest horizon allowed (``max_horizon``, or ``fallback_horizon`` where a design has one).
    shortest : int
        The shortest window any certificate found admits (its ``min_horizon()``), > ``limit``.

    """

    def __init__(self, message: str, limit: int, shortest: int) -> None:
        super().__init__(message)
        self.limit, self.shortest = int(limit), int(shortest)

    def __reduce__(self) -> tuple[type, tuple[str, int, int]]:
        return (type(self), (str(self), self.limit, self.shortest))


class SolverError(UiestError, RuntimeError):
    """A numerical solver failed and the caller asked for failures to be raised."""


class StorageError(UiestError, OSError):
    """A file or folder could not be written or locked (disk full, permission, file-size limit, in use).

    Attributes
    ----------
    path : str
        The file or folder concerned.

    """

    def __init__(self, message: str, path: str) -> None:
        super().__init__(message)
        self.path = str(path)

    def __str__(self) -> str:
        return str(self.args[0])

    def __reduce__(self) -> tuple[type, tuple[str, str]]:
        return (type(self), (str(self), self.path))


class DomainWarning(UserWarning):
    """Data left its declared domain (the true state outside X, noise outside V); it is recorded."""


class BoundWarning(UserWarning):
    """A run's estimates lie at a side of the state domain X in many steps: X may be too narrow."""


class FailureWarning(UserWarning):
    """A run's estimator failed in many of its steps (their estimates are propagated or kept)."""
