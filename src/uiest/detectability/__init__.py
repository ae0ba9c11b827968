"""Detectability certificates: the paper's conditions turned into numbers a user can check.

- :func:`linear_strong_detectability` (lem:UIO_LTI): matching, invariant zeros, mu_min.
- :func:`certify_strong_detectability` (theo:Lyapunov): quadratic storage by LMIs.
"""

from uiest.detectability.linear import LinearStrongDetectability, invariant_zeros, linear_strong_detectability
from uiest.detectability.report import Verification
from uiest.detectability.strong import StrongDetectability, certify_strong_detectability

__all__ = [
    "LinearStrongDetectability",
    "StrongDetectability",
    "Verification",
    "certify_strong_detectability",
    "invariant_zeros",
    "linear_strong_detectability",
]
