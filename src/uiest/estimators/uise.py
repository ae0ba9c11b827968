r"""The MHE-based unknown input state estimator with the full-order model (Theorem 3.6).

Theorem and equation numbers are those of Guo et al. (see the theory map).

Index convention (every array time-first)::

    x[k+1] = f(x[k], u[k], w[k]),   y[k] = h(x[k], v[k])
    x_hat[k] = x^*_{k|k}  from  u[k-N_k .. k-1], y[k-N_k .. k]   (current measurement included)
    w_hat[k-1] = w^*_{k-1|k}                                        (from the window ending at k)
    N_k = min(N, k)

Cost (Eq. (11) with quadratic functions; node time ``k-j``, ``j = 0 .. N_k``)::

    J = mu^{N_k} 4 |x_{k-N_k|k} - x_hat_{k-N_k}|_P^2
        + sum_{j=0}^{N_k} mu^{j-1} ( 8 |v_{k-j|k} - v_bar|_{R_v}^2 + 2 |y_{k-j} - h(x_{k-j|k}, v_{k-j|k})|_{R_y}^2 )

subject to ``x_{j+1|k} = f(x_{j|k}, u_j, w_{j|k})``, ``x_{j|k}`` in X at every node, ``v_{j|k}`` in V,
``w_{j|k}`` free (unbounded), and the prior rule Eq. (12): ``x_hat_{k-N_k}`` is the
estimate delivered at time ``k-N_k`` (``x_bar_0`` when ``k-N_k = 0``).

Where the numbers come from: the paper's ``alpha_2(2 r)`` term. The certificate's storage is
``V(x, x~) = |x - x~|_P^2 <= alpha_2(|x - x~|)`` with ``alpha_2(r) = lambda_max(P) r^2``. We use
the quadratic form of P itself, ``4 |.|_P^2 = V(2 .)``, instead of ``4 lambda_max(P) |.|^2``: the
proof of Theorem 3.6 only needs ``V(x_{k-N}, x^*) <= |2 (x - prior)|_P^2 + |2 (x^* - prior)|_P^2``,
which holds for the P-norm (``|a + b|_P <= 2 max(|a|_P, |b|_P)``), and its last step then needs
``8 mu^N < 1``, weaker than ``8 mu^N lambda_max / lambda_min < 1`` which ``min_horizon()`` checks.
So the certificate's horizon still suffices, and the prior is not over-weighted in the directions
where P is small. ``sigma_v(2 r) = 4 |r|_{R_v}^2`` gives the factor 8 of the noise term.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from uiest.checks import check_flag
from uiest.delay import matching_ranks
from uiest.errors import ModelError, OptionError
from uiest.estimators.base import WindowEstimator
from uiest.estimators.bounds import strong_bound
from uiest.estimators.design_search import estimator_options, search_uise
from uiest.estimators.weights import StrongCertificate, UISEWeights, resolve_weights
from uiest.guarantee import Guarantee
from uiest.scales import data_scales
from uiest.system import System
from uiest.theory import FULL_ORDER_GUARANTEE, FULL_ORDER_HORIZON
from uiest.window import WindowModel

__all__ = ["UISE", "check_system"]


def check_system(system: Any) -> System:
    """``system`` if it is a :class:`~uiest.system.System`, else OptionError."""
    if not isinstance(system, System):
        raise OptionError(f"system: expected a uiest.System, got {type(system).__name__}")
    return system


class UISE(WindowEstimator):
    r"""MHE-based UISE (Theorem 3.6 of Guo et al.) with the cost Eq. (11) and the prior rule Eq. (12).

    The module docstring gives the index convention, the cost and the choice of P for ``alpha_2``.

    Parameters
    ----------
    system : System
        Where the user gave no state scales and X's width is no scale (unbounded, or far wider than the
        states' magnitudes), the estimator uses :func:`~uiest.scales.data_scales` from ``x0_prior``
        (:attr:`system` is then that copy).
    certificate : StrongDetectability, optional
        Gives ``mu, P, R_y, R_v`` and the default horizon ``min_horizon()``.
    weights : UISEWeights, optional
        Explicit weights instead of a certificate (e.g. :meth:`UISEWeights.from_scales`); then
        N is required and :attr:`guarantee` says that Theorem 3.6 does not apply.
        :attr:`guarantee` bounds ``x_hat[k]`` (not the lagged estimates).
    N : int, optional
        Horizon >= 1; default ``certificate.min_horizon()``.
    x0_prior : array_like (nx,), optional
        Prior ``x_bar_0`` in X (or give it to :meth:`reset` / :meth:`run`).
    v_prior : array_like (nv,), optional
        Noise prior ``v_bar`` in V (default 0).
    force : bool
        Build the estimator although matching fails (``rank(C B) < rank(B)`` at a sampled point,
        :func:`~uiest.delay.matching_ranks`): x[k] is then not determined by y[..k] and
        :attr:`guarantee` says "none: matching fails". Without it such a system raises ModelError
        (for relative degree 2, :class:`~uiest.estimators.DelayedUISE` estimates x[k-1]).
    **options
        :class:`~uiest.estimators.base.WindowOptions`: ``solver`` (``"gn"`` default, ``"ipopt"``,
        ``"rti"``, ``"gn-riccati"``), ``solver_options``, ``warm_start``, ``strict``, ``polish``, ``lag``; or all
        of them as one ``window=WindowOptions(...)``.

    Raises
    ------
    ModelError
        Matching fails and ``force`` is False.
    OptionError
        Neither or both of ``certificate`` and ``weights``, ``weights`` without ``N``, or a bad ``N`` or option.

    Examples
    --------
    Estimate the closed-form model's states under an unknown input that grows without bound:

    >>> import numpy as np
    >>> from uiest import UniformNoise, simulate
    >>> from uiest.detectability import certify_strong_detectability
    >>> from uiest.estimators import UISE
    >>> from uiest.models import closed_form
    >>> system = closed_form.system(x_bounds=((-100.0, -10.0), (100.0, 10.0)))
    >>> truth = simulate(system, x0=[0.5, 1.0], steps=30, u=np.zeros(1), w=lambda k, x: [-0.5 * x[0] + 0.002 * k**2],
    ...                  v=UniformNoise.symmetric(1e-3), seed=0)
    >>> uise = UISE(system, certificate=certify_strong_detectability(system), x0_prior=[0.0, 0.0])
    >>> uise.N, uise.guaranteed
    (30, True)
    >>> print(uise.guarantee)  # doctest: +ELLIPSIS
    holds, bound x1 ..., x2 ... after ... steps (informative)
    >>> result = uise.run(truth.u, truth.y)  # u[k] and w[k] act from k to k+1; y[k] measures x[k]
    >>> result.x_hat.shape, result.w_hat.shape
    ((31, 2), (30, 1))
    >>> bool(np.abs(result.error(truth.x))[10:].max() < 0.05), result.counts()["failures"]
    (True, 0)

    """

    estimator_name = "UISE"
    theorem = FULL_ORDER_GUARANTEE
    free_input = True

    def __init__(
        self,
        system: System,
        *,
        certificate: StrongCertificate | None = None,
        weights: UISEWeights | None = None,
        N: int | None = None,
        x0_prior: ArrayLike | None = None,
        v_prior: ArrayLike | None = None,
        force: bool = False,
        **options: Any,
    ) -> None:
        force = check_flag(force, "force")
        system = data_scales(check_system(system), x0_prior)
        window_system = self._window_system(system, force)
        self.design_report: Any = None
        """The :class:`~uiest.estimators.design_search.Design` when built by :meth:`design`, else None."""
        self.weights, self.certificate, N = resolve_weights(
            UISEWeights, certificate, weights, N, lambda w: w.check(window_system)
        )
        super().__init__(system, WindowModel.from_system(window_system), schedule=self.weights.schedule(), N=N,
                         x0_prior=x0_prior, v_prior=v_prior, options=options, **self._window_inputs())  # fmt: skip

    def _window_system(self, system: System, force: bool) -> System:
        """The system the window estimates: ``system`` itself, after the matching test (``force``: see above)."""
        rank_CB, rank_B = matching_ranks(system)
        self.matching = rank_CB == rank_B
        """Whether matching holds at every sampled point (False only when built with ``force=True``)."""
        detail = f"rank(C B) = {rank_CB} < rank(B) = {rank_B}"
        if not self.matching:
            if not force:
                raise ModelError(
                    f"matching fails ({detail} at a point of X): the unknown input moves the state without changing "
                    "the next output, so x[k] is not determined by y[..k]. For relative degree 2, DelayedUISE(system, "
                    "lag=1) estimates x[k-1]; force=True builds this estimator without guarantee"
                )
            self.status_note = f" [no guarantee: {detail}]"
        return system

    def _window_inputs(self) -> dict[str, Any]:
        """Extra keywords of the window template (the delayed UISE's box and prior of its unknown input)."""
        return {}

    @classmethod
    def design(cls, system: System, *, x0_prior: ArrayLike, **design_options: Any) -> UISE:
        """A certified UISE whose mu and N are chosen for accuracy under noise (:func:`uiest.design.design_uise`).

        ``x0_prior`` is the prior and where the design's noise trials start; ``design_options``
        go to :func:`~uiest.design.design_uise` (``max_horizon``, ``fallback_horizon``, ``rates``, ``budget``,
        ``trials``, ``certify_options``, and window options such as ``solver``). The design (the chosen pair,
        the guaranteed bound and the simulated error of every candidate) is :attr:`design_report`.
        """
        system = data_scales(check_system(system), x0_prior)
        design = search_uise(cls, system, x0_prior, **design_options)
        est = cls(system, certificate=design.certificate, N=design.ranked_horizon, x0_prior=x0_prior,
                  **estimator_options(design_options))  # fmt: skip
        est.design_report = design
        return est

    @property
    def guarantee(self) -> Guarantee:
        """Theorem 3.6's bound per state (:func:`~uiest.estimators.bounds.strong_bound`), or why it does not apply."""
        if not self.matching:
            return self._no_guarantee(self.theorem, f"matching fails ({self.status_note.strip(' []')}), x[k] is not "
                                      "determined by y[..k]")  # fmt: skip
        missing = self._horizon_missing("strong-detectability", FULL_ORDER_HORIZON)
        if missing:
            return self._no_guarantee(self.theorem, missing)
        bound, settling = strong_bound(self.weights.P, self.weights.R_v, self.weights.mu, self.N, self.system.v.bounds,
                                       self.v_prior, self.system.x.bounds.width)  # fmt: skip
        return self._holds(self.theorem, bound, settling, self._assumes())

    def _assumes(self) -> str:
        return (
            f"mu={self.weights.mu:.4g}, N={self.N}; noise in V around v_prior {np.round(self.v_prior, 12).tolist()}, "
            "the true state in X, every output measured and every window problem solved to optimality; any unknown "
            "input"
        )

    def __repr__(self) -> str:
        return (
            f"UISE(system={self.system.name!r}, N={self.N}, mu={self.weights.mu:.4g}, "
            f"guarantee={str(self.guarantee)!r})"
        )
