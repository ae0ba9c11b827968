r"""The delayed UISE: an unknown input of relative degree 2, estimated with a lag.

When the next output does not see some directions of the unknown input (``rank(C B) <
rank(B)``), x[k] is not determined by y[..k], but x[k-1] can be (:mod:`uiest.delay`). The
delayed UISE runs the UISE of Theorem 3.6 of Guo et al. (the full-order UISE guarantee) on the
delayed system (state ``b = T_b x``,
unknown input ``(w, a)`` with ``a = T_a x``) and reads the original state from its window::

    x_lag[k]   = M_a a*_{k-lag|k} + M_b b*_{k-lag|k}     (the estimate of x[k-lag], lag >= 1)
    x_hat[k]   = M_a a*_{k-1|k}   + M_b b*_{k|k}         (a[k] is not determined by y[..k]: held from k-1)
    w_hat[k-lag-1] = least-squares fit of f(x_lag[k-lag-1], u, w) = x_lag[k-lag]   (same window)

Its weights and certificate are those of the delayed system: ``certify_strong_detectability(
delayed_system(system).system)``.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from uiest.box import Box, FloatArray, as_vector
from uiest.checks import check_int
from uiest.delay import delayed_system
from uiest.errors import OptionError
from uiest.estimators.base import WindowOptions
from uiest.estimators.bounds import strong_bound
from uiest.estimators.design_search import estimator_options, search_uise
from uiest.estimators.input_fit import InputFit
from uiest.estimators.uise import UISE, check_system
from uiest.guarantee import Guarantee
from uiest.scales import data_scales
from uiest.system import System
from uiest.theory import FULL_ORDER_GUARANTEE, FULL_ORDER_HORIZON
from uiest.window import WindowTrajectory
from uiest.window.size import check_horizon

__all__ = ["DelayedUISE"]


class DelayedUISE(UISE):
    r"""UISE of the delayed system (module docstring): estimates ``x[k-lag]``, ``lag >= 1``.

    Parameters
    ----------
    system : System
        A system whose unknown input has relative degree 2 (:func:`~uiest.delay.delayed_system`
        raises ModelError otherwise, naming the ranks).
    lag : int
        The delay d >= 1 of the estimate ``x_lag`` (``EstimationResult.x_lag``), at most N - 1
        (the window must hold the transition before ``x[k-lag]`` for ``w_hat``).
    certificate, weights, N, x0_prior, v_prior, **options
        As for :class:`~uiest.estimators.UISE`, but the certificate and weights are those of the
        delayed system (:attr:`delayed` ``.system``); N defaults to
        ``max(certificate.min_horizon(), lag + 1)``.

    """

    estimator_name = "DelayedUISE"
    theorem = f"{FULL_ORDER_GUARANTEE} for the delayed system"
    free_input = False  # its nodes are the delayed system's; its newest input is found from later outputs

    def __init__(self, system: System, *, lag: int = 1, **keywords: Any) -> None:
        system = data_scales(check_system(system), keywords.get("x0_prior"))
        self.delayed = delayed_system(system)
        _check_lag(lag, self.delayed.system)
        certificate = keywords.get("certificate")
        if (
            keywords.get("N") is None
            and certificate is not None
            and getattr(certificate, "certified", False)
            and isinstance(lag, int | np.integer)
        ):
            keywords["N"] = max(certificate.min_horizon(), int(lag) + 1)
        self._fit = InputFit(system)
        self._a_last: FloatArray | None = None
        window = keywords.get("window")
        if isinstance(window, WindowOptions):  # the delayed estimate is the window's fixed-lag one
            if window.lag not in (0, lag):
                raise OptionError(f"window: its lag {window.lag} differs from lag = {lag}; the delayed UISE sets it")
            keywords["window"] = dataclasses.replace(window, lag=lag)
            super().__init__(system, **keywords)
            return
        super().__init__(system, lag=lag, **keywords)

    @classmethod
    def design(cls, system: System, *, x0_prior: ArrayLike, lag: int = 1, **design_options: Any) -> DelayedUISE:
        """:meth:`UISE.design <uiest.estimators.UISE.design>` on the delayed system (prior ``T_b x0_prior``)."""
        given = design_options.get("design")
        if "records" in design_options or getattr(given, "records", None) is not None:
            # records would score a UISE of the delayed system, not this estimator
            raise OptionError("records: DelayedUISE.design scores its candidates on noise trials only")
        system = data_scales(check_system(system), x0_prior)
        delayed = delayed_system(system)
        _check_lag(lag, delayed.system)
        prior = delayed.T_b @ as_vector(x0_prior, system.nx, "x0_prior")
        design = search_uise(UISE, delayed.system, prior, **design_options)
        est = cls(system, lag=lag, certificate=design.certificate, N=max(design.ranked_horizon, int(lag) + 1),
                  x0_prior=x0_prior, **estimator_options(design_options))  # fmt: skip
        est.design_report = design
        return est

    def _window_system(self, system: System, force: bool) -> System:
        if force:
            raise OptionError("force: the delayed UISE needs no force (its delayed system satisfies matching)")
        self.matching = True
        return self.delayed.system

    def _window_inputs(self) -> dict[str, Any]:
        a_box = self.delayed.a_bounds  # a = T_a x stays in T_a X (with b in T_b X: x in X's bounding box)
        nw = self.delayed.original.nw  # called before the template sets self.system
        lower, upper = np.full(nw, -np.inf), np.full(nw, np.inf)
        return {
            "w_box": Box(np.concatenate([lower, a_box.lower]), np.concatenate([upper, a_box.upper])),
            "w_prior": self.delayed.nominal_w,
        }

    def _checked(self, options: WindowOptions) -> WindowOptions:
        if options.lag < 1:
            raise OptionError(
                f"lag: expected >= 1, got {options.lag}: the unknown input has relative degree 2, so x[k] is not "
                "determined by y[..k]; the delayed UISE estimates x[k-lag]"
            )
        if self.N is not None and options.lag >= self.N:
            raise OptionError(
                f"lag: expected 1 <= lag <= N - 1 = {self.N - 1} (w_hat[k-lag-1] needs the transition before "
                f"x[k-lag] in the window), got {options.lag}"
            )
        return options

    def _clear(self) -> None:
        super()._clear()
        self._a_last = None

    # ------------------------------------------------------------------ hooks of the template
    def _node_of(self, x: FloatArray) -> FloatArray:
        return self.delayed.T_b @ x

    def _a_of(self, window: WindowTrajectory, j: int) -> FloatArray:
        """``a`` at window node j (``-len(window.x) <= j <= -2``): the unknown input of the transition from node j."""
        return window.w[len(window.w) + 1 + j if j < 0 else j][self.system.nw :]

    def _node_state(self, window: WindowTrajectory, j: int, data: FloatArray) -> FloatArray:
        return self.system.x.bounds.clip(self.delayed.state(window.x[j], self._a_of(window, j)))

    def _to_state(
        self, node: FloatArray, y: FloatArray, u_prev: FloatArray, k: int, window: WindowTrajectory | None
    ) -> tuple[FloatArray, FloatArray]:
        if window is not None and len(window.w):
            self._a_last = self._a_of(window, -2)
        if self._a_last is None:
            self._a_last = self.delayed.T_a @ self._require_prior()
        return self.system.x.bounds.clip(self.delayed.state(node, self._a_last)), np.zeros(0)

    def _w_guess(self) -> FloatArray:
        return self.w_prior if self._a_last is None else np.concatenate([self.w_prior[: self.system.nw], self._a_last])

    def _w_estimate(
        self, window: WindowTrajectory | None, x_hat: FloatArray, u_prev: FloatArray, k: int
    ) -> tuple[FloatArray | None, int | None]:
        """Fit of ``w[k-lag-1]`` to the window's ``x[k-lag-1]`` and ``x[k-lag]``."""
        lag = self.options.lag
        if window is None or len(window.w) < lag + 1:
            return None, None
        j = -2 - lag
        u = self._u[-lag]  # u[k-lag-1]: u[k-1] is not stored yet
        x_prev, x_next = self._node_state(window, j, np.zeros(0)), self._node_state(window, j + 1, np.zeros(0))
        guess = self._w_last if self._w_last is not None else self.system.nominal_w
        return self._fit(x_prev, u, x_next, guess), k - lag - 1

    # ------------------------------------------------------------------ guarantee
    @property
    def guarantee(self) -> Guarantee:
        """Theorem 3.6 for the delayed system, read back to ``x_hat[k] = M_a a + M_b b`` (or why it does not apply).

        The theorem bounds the estimate of ``b[k]``; ``a`` is an unknown input of the delayed system,
        which it does not bound, so only the states with ``M_a``'s row zero (to 1e-12 of the row)
        have a bound; the others are NaN. The lagged estimates are not covered.
        """
        missing = self._horizon_missing("delayed system's strong-detectability", FULL_ORDER_HORIZON)
        if missing:
            return self._no_guarantee(self.theorem, missing)
        d = self.delayed
        free = np.abs(d.M_a).max(axis=1, initial=0.0) <= 1e-12 * np.abs(np.hstack([d.M_a, d.M_b])).max(axis=1)
        bound, settling = strong_bound(self.weights.P, self.weights.R_v, self.weights.mu, self.N, self.system.v.bounds,
                                       self.v_prior, self.system.x.bounds.width, T=d.T_b, M=d.M_b)  # fmt: skip
        note = "" if free.all() else "these states depend on a = T_a x, an unknown input of the delayed system"
        return self._holds(self.theorem, np.where(free, bound, np.nan), settling, self._assumes(), note)

    def _assumes(self) -> str:
        return f"{super()._assumes()}; it bounds x_hat[k], not the lagged estimates x[k-lag]"

    def __repr__(self) -> str:
        return (
            f"DelayedUISE(system={self.system.name!r}, N={self.N}, lag={self.options.lag}, mu={self.weights.mu:.4g}, "
            f"guarantee={str(self.guarantee)!r})"
        )


def _check_lag(lag: Any, window_system: System) -> None:
    """OptionError naming ``lag`` unless it is an integer >= 1 whose window (lag + 1 transitions) fits in memory."""
    lag = check_int(lag, "lag", low=1)
    check_horizon(lag + 1, "lag + 1 (the shortest window of this lag)", window_system)
