r"""The Kalman filters' prior on the unknown input: a random walk or an integrated random walk.

The filters (:mod:`uiest.estimators.kalman`) carry the unknown input in their state as a linear Gauss-Markov model with
``nw * order`` components ``c`` (time-first, ``d[k]`` the input that acts between k and k+1)::

    RANDOM_WALK             (order 1)  c = d:       d[k+1] = d[k] + e[k]
    INTEGRATED_RANDOM_WALK  (order 2)  c = (d, r):  d[k+1] = d[k] + r[k],   r[k+1] = r[k] + e[k]

    Cov(e[k]) = Q_w (``w_variance``),   c[k+1] = A c[k] + G e[k]

A random walk's increments are independent: it suits an input that jumps or wanders. An integrated random walk's
increments ``r`` (its rate, per sample) are themselves a random walk: it suits an input that drifts smoothly,
whose next increment is close to the last. Both have one variance per component, so a likelihood compares them
without a penalty (:meth:`KalmanFilter.fit <uiest.estimators.kalman.KalmanFilter.fit>`).
"""

from __future__ import annotations

from enum import StrEnum

import numpy as np

from uiest.box import FloatArray


class InputModel(StrEnum):
    """The unknown input's prior in the Kalman filters (module docstring)."""

    RANDOM_WALK = "random walk"
    INTEGRATED_RANDOM_WALK = "integrated random walk"

    @property
    def order(self) -> int:
        """Components of the input's state per unknown input: 1 (d) or 2 (d and its rate r)."""
        return 1 if self is InputModel.RANDOM_WALK else 2

    def transition(self, nw: int) -> FloatArray:
        """``A`` (order nw, order nw): the input state's mean moves as ``c[k+1] = A c[k]``."""
        if self is InputModel.RANDOM_WALK:
            return np.eye(nw)
        eye, zero = np.eye(nw), np.zeros((nw, nw))
        return np.block([[eye, eye], [zero, eye]])

    def noise(self, w_variance: FloatArray) -> FloatArray:
        """``G Q_w G^T`` (order nw, order nw) from ``Q_w`` (nw, nw): the step variance on the last block."""
        nw = len(w_variance)
        out = np.zeros((self.order * nw, self.order * nw))
        out[-nw:, -nw:] = w_variance
        return out


__all__ = ["InputModel"]
