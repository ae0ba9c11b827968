r"""Choosing the UISE's rate mu and horizon N for accuracy under noise, from certificates.

The minimal certified rate is a poor design under noise: with ``mu ~ 1e-2`` the window forgets
its past at once and the estimate follows every noise sample. The proof of Theorem 3.6 of Guo et
al. (the full-order UISE guarantee; see the theory map) bounds the error the noise leaves
(:func:`uiest.estimators.bounds.strong_bound`, the bound of
:attr:`UISE.guarantee <uiest.estimators.UISE.guarantee>`): with ``lambda = 8^{1/N} mu`` it is
proportional to ``1 / sqrt(lambda (1 - lambda))``. That bound is worst-case (every noise sample
aligned): it is smallest near ``lambda = 1/2``, while under independent noise a slower forgetting
averages more samples and errs less. :func:`search_uise` therefore

1. certifies at the minimal rate and at a grid of rates (``rates``, those above its design rate), within a
   CPU budget; each certified rate gets the horizon ``N <= max_horizon`` that minimises its bound
   (only pairs with ``N >= min_horizon()`` are candidates; an N beyond the weights' information horizon runs
   capped there, possibly without a guarantee, and guaranteed candidates are chosen first); a rate
   whose gain-optimal certificate needs more than ``max_horizon`` (``min_horizon`` grows with
   log cond(P)) is certified again with cond(P) bounded so that it fits (``max_condition``); where no rate then
   admits a window within ``max_horizon`` and a ``fallback_horizon`` is given, the same certificates are fitted to
   that longer limit instead (only the bounded ones are certified again);
2. runs each candidate on ``trials`` noise records (uniform in V, the true state starting at
   ``x0``, known input at U's centre, unknown input zero: the UISE's error does not depend on it
   for systems affine in w), or on the user's ``records`` (where that run would leave X, say);
3. for the UISE, runs the best one's certificate again with its output weights times
   :data:`OUTPUT_WEIGHTS` (a weaker certificate: the same guarantee, a bound ``sqrt(factor)``
   wider);
4. scores every candidate on every state and unknown input (:func:`regret`): the geometric mean
   over them of its error RMS over the smallest any candidate reached (1: best on every one); the
   candidates within :data:`ERROR_TOLERANCE` of the best score are equally accurate, and of those
   the one with the smallest guaranteed bound (relative to the state scales) is chosen.

Each candidate carries its estimator's :class:`~uiest.guarantee.Guarantee` (its ``bound`` is the
guarantee's per-state bound) and the simulated RMS; the design warns when the chosen one's
guarantee is not informative (its bound not below X's width in every state).
"""

from __future__ import annotations

import inspect
import time
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from uiest.box import FloatArray, as_vector
from uiest.checks import check_int, check_keywords, check_real, check_seed, shown, user_stacklevel
from uiest.detectability import certify_reduced_model, certify_strong_detectability
from uiest.detectability.certificate import horizon_condition
from uiest.detectability.lmi import finite_box
from uiest.errors import CertificationError, DataError, HorizonError, ModelError, OptionError
from uiest.estimators.bounds import noise_quadratic, strong_bound, two_stage_z_bound
from uiest.guarantee import Guarantee
from uiest.health import without_bound_warnings
from uiest.results import Trajectory
from uiest.scales import data_scales
from uiest.simulate import simulate
from uiest.system import System
from uiest.theory import REDUCED_IOSS
from uiest.window.size import check_horizon

__all__ = [
    "CONDITION_MARGIN",
    "ERROR_TOLERANCE",
    "Candidate",
    "Design",
    "DesignOptions",
    "estimator_options",
    "regret",
    "search_two_stage",
    "search_uise",
]

CONDITION_MARGIN = 0.99
"""A design for ``max_horizon`` bounds cond(P) this fraction below :func:`horizon_condition`: the LMI solver keeps
``P << c I`` only to its tolerance, and the horizon's logarithm is floored."""

OUTPUT_WEIGHTS = (1.0, 10.0, 100.0)
"""Factors on a strong certificate's output weights the UISE design tries (``with_output_weight``): the certified
weights can leave the prior dominant over directly measured states."""

ERROR_TOLERANCE = 1.02
"""Candidates whose :func:`regret` is within this factor of the best one's are equally accurate: the smallest
guaranteed bound decides among them (a larger bound for a difference within the records' scatter is no trade)."""

ERROR_FLOOR = 1e-6
"""A component's smallest error counts as at least this fraction of the largest component's (both relative to
their scales) in :func:`regret`: differences at the level of rounding are not scored."""

DEFAULT_RATES = (0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9)
"""Rates certified by default (with the minimal rate), each kept when it is at least mu_min."""


@dataclass(frozen=True, eq=False, kw_only=True)
class Candidate:
    """One (mu, N, output weight) weighed by the design.

    Attributes
    ----------
    mu : float
    N : int
        The window the candidate runs: the one its rate's bound ranks best, capped at its weights' information
        horizon (:mod:`uiest.estimators.horizon`).
    bound : ndarray (nx,)
        The guarantee's per-state bound (``guarantee.error_bound``, state units; NaN where it bounds nothing).
    rms : ndarray (nx,)
        Simulated state error RMS per state.
    output_weight : float
        The factor on the certificate's output weights.
    guarantee : Guarantee or None
        The candidate estimator's guarantee.
    w_rms : ndarray (nw,)
        Simulated unknown-input error RMS per input (NaN where no estimate was delivered).
    ranked_horizon : int or None
        The window the rate's bound ranked best when the information horizon capped it to ``N``, else None.

    """

    mu: float
    N: int
    bound: FloatArray
    rms: FloatArray
    output_weight: float = 1.0
    guarantee: Guarantee | None = None
    w_rms: FloatArray = field(default_factory=lambda: np.zeros(0))
    ranked_horizon: int | None = None


def regret(errors: FloatArray) -> FloatArray:
    """Each candidate's geometric mean, over components, of its error over the smallest any candidate reached.

    ``errors`` (candidates, components) are error RMS values relative to each component's scale. A
    component no candidate has a value for (NaN throughout: an input no window informed) is not
    scored; a candidate's NaN or inf elsewhere scores inf. The smallest error of a component is
    floored at :data:`ERROR_FLOOR` times the largest component's smallest error. Returns shape
    (candidates,); 1 means best on every component.
    """
    errors = np.asarray(errors, dtype=float)
    errors = errors[:, ~np.all(np.isnan(errors), axis=0)]
    if not errors.shape[1]:
        return np.ones(len(errors))
    errors = np.where(np.isfinite(errors), errors, np.inf)
    best = errors.min(axis=0)
    best = np.maximum(best, ERROR_FLOOR * float(np.max(best[np.isfinite(best)], initial=0.0)))
    with np.errstate(divide="ignore", invalid="ignore"):
        logs = np.where(errors > best, np.log(errors / np.where(best > 0, best, 1.0)), 0.0)
    return np.exp(logs.mean(axis=1))


@dataclass(frozen=True, eq=False, kw_only=True)
class Design:
    """The chosen certificate and horizon, the bound they imply, and all candidates.

    Attributes
    ----------
    certificate : StrongDetectability or ReducedIOSS
        Certified at the chosen rate.
    N : int
        The window the chosen estimator runs.
    ranked_horizon : int
        The window its rate's bound ranked best: ``N``, or longer when the weights' information horizon capped it
        (:mod:`uiest.estimators.horizon`); the ``design()`` classmethods build the estimator with it, so it states
        the cap.
    bound : ndarray (nx,)
        The chosen estimator's guarantee's error bound per state (Theorem 3.6 or Theorem 4.8,
        :mod:`uiest.estimators.bounds`), in the states' units.
    candidates : tuple of Candidate
    seconds : float
        CPU time of the certifications.

    """

    certificate: Any
    N: int
    ranked_horizon: int
    bound: FloatArray
    candidates: tuple[Candidate, ...]
    seconds: float

    def summary(self) -> str:
        """One line per candidate, the chosen one marked."""
        rows = []
        chosen = (self.certificate.mu, self.N, getattr(self.certificate, "output_weight", 1.0))
        for c in self.candidates:
            mark = "*" if (c.mu, c.N, c.output_weight) == chosen else " "
            weight = f" output weight x{c.output_weight:g}" if c.output_weight != 1.0 else ""
            weight += f" (ranked N={c.ranked_horizon}, capped at the information horizon)" if c.ranked_horizon else ""
            w_rms = f" w rms={np.array2string(c.w_rms, precision=3)}" if c.w_rms.size else ""
            rows.append(
                f"{mark} mu={c.mu:.4g} N={c.N:<3d}{weight} bound={np.array2string(c.bound, precision=3)} "
                f"rms={np.array2string(c.rms, precision=3)}{w_rms}"
            )
        return "\n".join(rows)


DEFAULT_STEPS = 80
"""Length of a design's noise trials unless the longest horizon admitted (``fallback_horizon`` if given, else
``max_horizon``) asks for longer ones."""


@dataclass(frozen=True, kw_only=True)
class DesignOptions:
    """How :func:`~uiest.design.design_uise` and :func:`~uiest.design.design_two_stage` search; every field checked.

    Attributes
    ----------
    max_horizon : int
        Largest N considered (window cost grows with N), >= 1.
    fallback_horizon : int, optional
        The larger limit admitted where no certified rate has a window within ``max_horizon`` (the certificates are
        reused, not computed again); None: :class:`~uiest.errors.HorizonError` then. At least ``max_horizon``.
    rates : tuple of float
        Rates in (0, 1) to certify besides the minimal one (those below mu_min are skipped); stored sorted, without
        repeats.
    budget : float
        CPU seconds >= 0 for the certifications (``inf``: no limit); the grid stops when it is spent.
    trials : int
        Noise records per candidate, >= 1.
    steps : int
        Their length. The first quarter is not scored, so at least ``ceil(4 H / 3)`` (a full window of the longest
        admitted horizon ``H``, ``fallback_horizon`` if given, else ``max_horizon``, in the rest); default
        :data:`DEFAULT_STEPS` or that least length.
    seed : int
        Seed of the noise records, >= 0.
    certify_options : mapping, optional
        Keywords of the certification (:func:`~uiest.detectability.certify_strong_detectability`, or the reduced
        :func:`~uiest.detectability.certify_reduced_model`).
    records : sequence of Trajectory, optional
        Simulated records (with their states) to score the candidates on instead of the noise trials: records of
        the operating conditions, inside X, with the unknown inputs one expects. Their first quarter is not scored.

    Examples
    --------
    >>> from uiest.design import DesignOptions
    >>> DesignOptions(max_horizon=60, rates=(0.9, 0.5)).steps, DesignOptions(rates=(0.9, 0.5)).rates
    (80, (0.5, 0.9))

    """

    max_horizon: int = 30
    fallback_horizon: int | None = None
    rates: tuple[float, ...] = DEFAULT_RATES
    budget: float = 60.0
    trials: int = 2
    steps: int | None = None
    seed: int = 0
    certify_options: Mapping[str, Any] | None = None
    records: Sequence[Any] | None = None

    def __post_init__(self) -> None:
        max_horizon = check_int(self.max_horizon, "max_horizon", low=1)
        fallback = self.fallback_horizon
        if fallback is not None:
            fallback = check_int(fallback, f"fallback_horizon (at least max_horizon = {max_horizon})", low=max_horizon)
        trials = check_int(self.trials, "trials", low=1)
        # a trial scores from steps // 4 on: its scored part holds at least one full window of the longest horizon
        longest, limit_name = (max_horizon, "max_horizon") if fallback is None else (fallback, "fallback_horizon")
        shortest = -(-4 * longest // 3)
        steps = max(DEFAULT_STEPS, shortest) if self.steps is None else self.steps
        steps = check_int(steps, f"steps (at least {shortest}: a full window of {limit_name} = {longest} in the "
                                 "scored three quarters of a trial)", low=shortest)  # fmt: skip
        budget = check_real(self.budget, "budget", "CPU seconds >= 0")
        if not budget >= 0:
            raise OptionError(f"budget: expected CPU seconds >= 0 (inf: no limit), got {self.budget!r}")
        try:
            grid = tuple(sorted({float(r) for r in self.rates}))
        except (TypeError, ValueError):
            raise OptionError(f"rates: expected numbers in (0, 1), got {self.rates!r}") from None
        if any(not 0.0 < r < 1.0 for r in grid):
            raise OptionError(f"rates: expected numbers in (0, 1), got {list(self.rates)}")
        if self.certify_options is not None and not isinstance(self.certify_options, Mapping):
            raise OptionError(f"certify_options: expected a mapping of keywords, got {shown(self.certify_options)}")
        values = {"max_horizon": max_horizon, "fallback_horizon": fallback, "trials": trials, "steps": steps,
                  "budget": budget, "rates": grid, "seed": check_seed(self.seed)}  # fmt: skip
        for name, value in values.items():
            object.__setattr__(self, name, value)

    @classmethod
    def split(cls, design: DesignOptions | None, keywords: Mapping[str, Any]) -> tuple[DesignOptions, dict[str, Any]]:
        """The design options (``design``, or keywords named as its fields; not both) and the other keywords."""
        named = {key: value for key, value in keywords.items() if key in _DESIGN_FIELDS}
        rest = {key: value for key, value in keywords.items() if key not in _DESIGN_FIELDS}
        if design is None:
            return cls(**named), rest
        if not isinstance(design, DesignOptions):
            raise OptionError(f"design: expected a DesignOptions, got {shown(design)}")
        if named:
            raise OptionError(f"design: given together with {', '.join(sorted(named))}; put them in the DesignOptions")
        return design, rest


_DESIGN_FIELDS = tuple(f.name for f in fields(DesignOptions))

DESIGN_KEYS = ("design", *_DESIGN_FIELDS)
"""Keywords of :func:`search_uise` / :func:`search_two_stage`; the others go to the estimators."""


def estimator_options(options: Mapping[str, Any]) -> dict[str, Any]:
    """The keywords of ``options`` that are not :data:`DESIGN_KEYS` (the designed estimator's own)."""
    return {k: v for k, v in options.items() if k not in DESIGN_KEYS}


def search_uise(
    estimator: Callable[..., Any],
    system: System,
    x0: ArrayLike,
    *,
    design: DesignOptions | None = None,
    **options: Any,
) -> Design:
    """:func:`uiest.design.design_uise` with the candidates built by ``estimator``.

    ``estimator(system, certificate=, N=, x0_prior=, **options)`` builds a candidate UISE: ``design_uise`` passes
    the :class:`~uiest.estimators.UISE` class, ``UISE.design`` passes its class (``DelayedUISE.design`` the UISE of the
    delayed system). The other
    parameters, the result and the errors are ``design_uise``'s.

    Examples
    --------
    >>> from uiest.estimators import UISE
    >>> from uiest.models import closed_form
    >>> system = closed_form.system(x_bounds=((-100.0, -10.0), (100.0, 10.0)))
    >>> design = search_uise(UISE, system, [0.0, 0.0], rates=(0.8,), max_horizon=10, trials=1)
    >>> design.N, design.bound.shape
    (10, (2,))

    """
    search, options = DesignOptions.split(design, options)
    certify = _certify_options(search.certify_options, certify_strong_detectability)
    system = data_scales(system, as_vector(x0, system.nx, "x0"))
    scale, V, width = system.x.scale, system.v.bounds, system.x.bounds.width
    v_bar = _v_prior(system, options)

    def rank(cert: Any, n: int) -> float:
        return float(np.max(strong_bound(cert.P, cert.R_v, cert.mu, n, V, v_bar, width)[0] / scale))

    def fit(cert: Any, limit: int) -> Any:
        """``cert``, or if its min_horizon exceeds ``limit``, the one at its rate with cond(P) bounded to fit."""
        if cert.min_horizon() > limit and "max_condition" not in certify:
            fitting = CONDITION_MARGIN * horizon_condition(cert.mu, limit)
            if fitting > 1.0:
                conditioned = certify_strong_detectability(system, mu=cert.mu, max_condition=fitting, **certify)
                if conditioned.certified:
                    return conditioned
        return cert

    return _design(
        system, x0, lambda mu: certify_strong_detectability(system, mu=mu, **certify), rank,
        lambda cert, n, prior: estimator(system, certificate=cert, N=n, x0_prior=prior, **options),
        what="strong detectability", search=search, fit=fit, least=_lag(options),
        variants=lambda cert: [cert.with_output_weight(factor) for factor in OUTPUT_WEIGHTS if factor != 1.0],
    )  # fmt: skip


def search_two_stage(
    estimator: Callable[..., Any],
    reduced: Any,
    x0: ArrayLike,
    *,
    design: DesignOptions | None = None,
    **options: Any,
) -> Design:
    """:func:`search_uise` for the two-stage UISE: reduced e-IOSS certificates and Theorem 4.8's bound.

    ``estimator(reduced, certificate=, N=, x0_prior=, **options)`` builds a candidate (the
    :class:`~uiest.estimators.TwoStageUISE` class); ``reduced`` is a :class:`~uiest.reduction.ReducedModel`
    with its data scales set (:func:`~uiest.estimators.two_stage.reduced_data_scales`); ``options`` are the
    estimator's keywords (``projection``, window options). N is ranked by Theorem 4.8's settled bound on
    ``z_sharp`` (:func:`~uiest.estimators.bounds.two_stage_z_bound`, the one the guarantee carries to the states).
    """
    search, options = DesignOptions.split(design, options)
    system = reduced.system
    certify = dict(search.certify_options or {})
    v_bar = _v_prior(system, options)

    def rank(cert: Any, n: int) -> float:
        return two_stage_z_bound(cert.mu, cert.c_x, n, noise_quadratic(cert.R_v, system.v.bounds, v_bar))

    return _design(
        system, x0, lambda mu: certify_reduced_model(reduced, mu=mu, **certify), rank,
        lambda cert, n, prior: estimator(reduced, certificate=cert, N=n, x0_prior=prior, **options),
        what=REDUCED_IOSS, search=search, least=_lag(options),
    )  # fmt: skip


@without_bound_warnings  # the trial runs' estimates at X's sides are the candidates' business, not the user's
def _design(
    system: System,
    x0: ArrayLike,
    certify: Callable[[float | None], Any],
    rank: Callable[[Any, int], float],
    build: Callable[[Any, int, FloatArray], Any],
    *,
    what: str,
    search: DesignOptions,
    fit: Callable[[Any, int], Any] = lambda cert, limit: cert,
    variants: Callable[[Any], list[Any]] = lambda cert: [],
    least: int = 1,
) -> Design:
    """The design loop of the module docstring.

    ``certify(mu)`` certifies at a rate (None: the minimal one), ``fit(certificate, limit)`` returns a certified
    certificate of the same rate whose window fits ``limit`` where it can (else the one given),
    ``rank(certificate, N)`` orders the horizons of a rate, at least ``least`` (the estimators' lag). A candidate
    whose estimator cannot be built (``OptionError``: its window capped below the lag at its information horizon,
    its weights out of the window's range) is none; where no candidate can be built, the first such error is raised.
    """
    check_horizon(search.max_horizon, "max_horizon", system)
    records = search.records
    prior = as_vector(x0, system.nx, "x0")
    start = time.thread_time()
    limit, certificates = _certificates(system, certify, fit, search, what)
    if records is None:
        assert search.steps is not None  # set by DesignOptions
        scored = _noise_records(system, prior, search.trials, search.steps, search.seed)
    else:
        scored = _given_records(system, records)
    candidates: list[tuple[Candidate, Any]] = []

    def weigh(cert: Any, N: int) -> tuple[Candidate, Any]:
        estimator = build(cert, N, prior)
        errors, w_errors = [], []
        for u, y, x, w in scored:
            result = estimator.run(u, y)
            first = (len(y) - 1) // 4
            errors.append(result.error(x)[first:])
            w_errors.append((result.w_hat - w)[first:])
        rms = np.sqrt(np.mean(np.concatenate(errors) ** 2, axis=0))
        w_err = np.concatenate(w_errors)
        informed = np.isfinite(w_err)
        w_rms = np.sqrt(np.sum(np.where(informed, w_err, 0.0) ** 2, axis=0) / np.maximum(informed.sum(axis=0), 1))
        w_rms = np.where(informed.any(axis=0), w_rms, np.nan)
        guarantee = estimator.guarantee
        bound = np.full(system.nx, np.nan) if guarantee.error_bound is None else guarantee.error_bound
        output_weight = float(getattr(cert, "output_weight", 1.0))
        return Candidate(
            mu=cert.mu,
            N=estimator.N,
            bound=bound,
            rms=rms,
            output_weight=output_weight,
            guarantee=guarantee,
            w_rms=w_rms,
            ranked_horizon=N if estimator.N != N else None,
        ), cert

    refused: list[OptionError] = []  # candidates that cannot be built (a window capped below the lag, ...)
    for cert in certificates:
        horizons = range(max(cert.min_horizon(), least), limit + 1)
        N = min(horizons, key=lambda n: rank(cert, n), default=None)
        if N is not None:
            try:
                candidates.append(weigh(cert, N))
            except OptionError as exc:
                refused.append(exc)
    if not candidates and refused:
        raise refused[0]
    if not candidates:
        shortest = min(cert.min_horizon() for cert in certificates)
        name = "max_horizon" if limit == search.max_horizon else "fallback_horizon"
        raise HorizonError(
            f"{name}: no certified rate has an admissible horizon <= {limit} (the shortest window of the "
            f"certificates found at the rates tried: {shortest}; {name}={shortest} admits it, and the estimator "
            "built from a certificate with a shorter N runs without a guarantee)",
            limit,
            shortest,
        )
    chosen, cert = _choose(candidates, system)
    for variant in variants(cert):  # the best rate's variants, at its ranked window
        try:
            candidates.append(weigh(variant, chosen.ranked_horizon or chosen.N))
        except OptionError:  # output weights too large for the window's weight range: not a candidate
            continue
    chosen, cert = _choose(candidates, system)
    _warn_if_vacuous(chosen)
    return Design(
        certificate=cert,
        N=chosen.N,
        ranked_horizon=chosen.ranked_horizon or chosen.N,
        bound=chosen.bound,
        candidates=tuple(c for c, _ in candidates),
        seconds=time.thread_time() - start,
    )


def _certificates(
    system: System,
    certify: Callable[[float | None], Any],
    fit: Callable[[Any, int], Any],
    search: DesignOptions,
    what: str,
) -> tuple[int, list[Any]]:
    """The window limit and the certified rates' certificates fitted to it (:func:`_design`'s arguments).

    The limit is ``max_horizon``, or ``fallback_horizon`` (when given) where no certificate fits ``max_horizon``; the
    grid of rates stops when the budget is spent.
    """
    max_horizon, fallback = search.max_horizon, search.fallback_horizon
    start = time.thread_time()
    first = certify(None)
    if not first.certified:
        raise CertificationError(f"system: {what} is not certified ({first.reason}); nothing to design")
    found = [first]  # as certified, each to be fitted to a limit
    certificates = [fit(first, max_horizon)]
    for mu in search.rates:
        if mu > first.mu and time.thread_time() - start <= search.budget:
            cert = certify(mu)
            if cert.certified:
                found.append(cert)
                certificates.append(fit(cert, max_horizon))
    if fallback is None or fallback <= max_horizon or any(cert.min_horizon() <= max_horizon for cert in certificates):
        return max_horizon, certificates
    fallback = check_horizon(fallback, "fallback_horizon", system)  # checked where it is used
    return fallback, [fit(cert, fallback) for cert in found]


def _choose(pool: list[tuple[Candidate, Any]], system: System) -> tuple[Candidate, Any]:
    """The smallest bound among the candidates whose regret is within ERROR_TOLERANCE of the best.

    Only the candidates whose guarantee applies compete, where there are any (an information horizon can cap a
    candidate's window below its min_horizon()).
    """
    pool = [pair for pair in pool if pair[0].guarantee is not None and pair[0].guarantee.applies] or pool
    errors = np.array([np.concatenate([c.rms / system.x.scale, c.w_rms / system.w.scale]) for c, _ in pool])
    score = regret(errors)
    tied = [pair for pair, value in zip(pool, score, strict=True) if value <= ERROR_TOLERANCE * score.min()]
    return min(tied, key=lambda pair: _largest_bound(pair[0].bound, system.x.scale))


def _warn_if_vacuous(chosen: Candidate) -> None:
    """Warn when the chosen guarantee is not informative: certified, but its bound says nothing X does not."""
    guarantee = chosen.guarantee
    if guarantee is not None and not guarantee.informative:
        wide = np.flatnonzero(~guarantee.informative_states)
        names = [guarantee.names[i] for i in wide]
        warnings.warn(
            f"design: the chosen guarantee is not informative for {names} under V's noise: {guarantee.text} "
            f"(RMS on the design's records {np.array2string(chosen.rms[wide], precision=3)})",
            UserWarning,
            stacklevel=user_stacklevel(),
        )


def _largest_bound(bound: FloatArray, scale: FloatArray) -> float:
    """The largest per-state bound relative to the state scales; a state without a bound (NaN) counts as inf."""
    relative = np.asarray(bound, dtype=float) / scale
    return float(np.max(np.where(np.isnan(relative), np.inf, relative), initial=0.0))


def _lag(options: Mapping[str, Any]) -> int:
    """The candidates' lag (``lag=`` or ``window=WindowOptions(lag=...)`` among the estimator options), at least 1."""
    lag = options.get("lag", getattr(options.get("window"), "lag", 0))
    return max(1, int(lag)) if isinstance(lag, int | np.integer) else 1


def _v_prior(system: System, options: Mapping[str, Any]) -> FloatArray:
    """The candidates' noise prior (``v_prior`` among the estimator options, else 0) for ranking N."""
    given = options.get("v_prior")
    return np.zeros(system.nv) if given is None else as_vector(given, system.nv, "v_prior")


def _given_records(
    system: System, records: Sequence[Any]
) -> list[tuple[FloatArray | None, FloatArray, FloatArray, FloatArray]]:
    """``(u, y, x, w)`` of the user's records; DataError for anything that is not a record of ``system`` with states."""
    records = [] if isinstance(records, Trajectory) else list(records)
    if not records:
        raise DataError("records: expected a non-empty sequence of Trajectory records")
    scored = []
    for i, record in enumerate(records):
        if not isinstance(record, Trajectory) or record.y.shape[1] != system.ny or record.x.shape[1] != system.nx:
            raise DataError(f"records[{i}]: expected a Trajectory of {system.name!r} (nx = {system.nx}, "
                            f"ny = {system.ny})")  # fmt: skip
        if not np.all(np.isfinite(record.x)):
            raise DataError(f"records[{i}]: expected a record with its states (a simulation), to score the errors")
        scored.append((record.u if system.nu else None, record.y, record.x, record.w))
    return scored


def _noise_records(
    system: System, x0: FloatArray, trials: int, steps: int, seed: int
) -> list[tuple[FloatArray | None, FloatArray, FloatArray, FloatArray]]:
    """``(u, y, x, w)`` of noise-only runs: u at U's centre, w = nominal, v uniform in V (its scale where unbounded)."""
    if not system.x.bounds.contains(x0):  # as simulate() requires of its start
        raise DataError(f"x0_prior: expected a point in X = {system.x.bounds}, got {np.asarray(x0).tolist()}")
    rng = np.random.default_rng(seed)
    V = finite_box(system.v.bounds, system.v.bounds.center, system.v.scale)
    u = np.tile(system.u.bounds.center, (steps, 1)) if system.nu else None
    records = []
    for _ in range(trials):
        try:
            traj = simulate(system, x0, steps, u=u, w=system.nominal_w, v=V.sample(rng, steps + 1))
        except ModelError as exc:  # the design's own trial: say so, and how to give it others
            raise type(exc)(
                f"x0_prior: the design's noise trial, simulated from it with w = nominal and u at U's centre, "
                f"failed ({exc}); pass records= (simulations of the operating conditions) to score the designs on"
            ) from None
        records.append((u, traj.y, traj.x, traj.w))
    return records


def _certify_options(options: Any, certify: Callable[..., Any]) -> dict[str, Any]:
    """``certify_options`` as a dict of keywords ``certify`` takes (besides the system and mu), else OptionError."""
    if options is None:
        return {}
    known = [name for name in inspect.signature(certify).parameters if name not in ("system", "mu")]
    check_keywords(options, known, "certify_options")
    return dict(options)
