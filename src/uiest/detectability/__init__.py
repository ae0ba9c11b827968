"""Detectability certificates: the paper's conditions turned into numbers a user can check.

Every certificate is a :class:`Certificate` (verdict and status, rate, quadratic storage P and gains,
``min_horizon()``, ``verify()``, ``to_dict()``); the estimators turn it into their weights
(``UISEWeights.from_certificate`` and its siblings in :mod:`uiest.estimators`):

- :func:`certify_strong_detectability` (Theorem 3.2 of Guo et al.; see the theory map): the unknown input and
  the current-output
  gain eliminated exactly, vertices that provably cover the Jacobian over X x U.

Each ``certify_*`` searches for a pair that violates what its LMIs claim before it returns
(``falsification``); ``certified`` is True only for a proof that search did not refute.
- :func:`linear_strong_detectability` (Lemma 3.5): matching, invariant zeros, mu_min.
- :func:`certify_reduced_ioss` (Assumption 4.7): exponential i-IOSS of a reduced-order model.
- :func:`certify_delta_ioss` (Schiller et al. 2023, Assumption 1): for the standard MHE.
- :func:`window_information`: the smallest state difference one window's data can resolve.
"""

from uiest.detectability.certificate import Certificate, Verification
from uiest.detectability.delta import DeltaIOSS, certify_delta_ioss
from uiest.detectability.information import InformationBound, window_information
from uiest.detectability.linear import LinearStrongDetectability, invariant_zeros, linear_strong_detectability
from uiest.detectability.reduced import ReducedIOSS, certify_reduced_ioss, certify_reduced_model
from uiest.detectability.strong import StrongDetectability, certify_strong_detectability

__all__ = [
    "Certificate",
    "DeltaIOSS",
    "InformationBound",
    "LinearStrongDetectability",
    "ReducedIOSS",
    "StrongDetectability",
    "Verification",
    "certify_delta_ioss",
    "certify_reduced_ioss",
    "certify_reduced_model",
    "certify_strong_detectability",
    "invariant_zeros",
    "linear_strong_detectability",
    "window_information",
]
