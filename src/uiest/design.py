r"""Choosing the UISE's rate mu and horizon N for accuracy under noise, from certificates.

The minimal certified rate is a poor design under noise: with ``mu ~ 1e-2`` the window forgets
its past at once and the estimate follows every noise sample. theo:MHE_full's proof bounds the
error the noise leaves: for a quadratic certificate (``V = |e|_P^2``, ``sigma_v(r) = sigma_v r^2``)
and ``N`` with ``rho = 8 mu^N < 1`` (the P-norm form of eq:MHE_full_horizon, see
:mod:`uiest.estimators.uise`), the proof's last lines give
``V(e_k) <= rho lambda^k / mu^N V(e_0) + sum_{i>=0} 8 lambda^{i-1} sigma_v(2 |dv_{k-i}|)`` with
``lambda = max(mu, rho^{1/N}) = 8^{1/N} mu``, where the term ``i = 0`` is the current sample's
(weight ``mu^{-1}`` in eq:cost_MHE_full; the paper's last line drops it, we keep it); with
``|dv| <= d`` (V's diameter) the sum is at most ``8 sigma_v(2 d) / (lambda (1 - lambda))`` and the
error settles within::

    |e_i| <= noise_gain_i * 4 / sqrt(lambda (1 - lambda))      (settled_bound)

(``noise_gain`` is the certificate's ``sqrt(2 sigma_v d^2 / alpha_1)`` in state units). That bound
is worst-case (every noise sample aligned): it is smallest near ``lambda = 1/2``, while under
independent noise a slower forgetting averages more samples and errs less (measured on random
3-state linear systems: the bound's choice, mu ~ 0.3-0.6, gave 1.0-1.4x the linear UIO's RMSE,
mu = 0.9 gave 1.04x). :func:`design_uise` therefore

1. certifies at the minimal rate and at a grid of rates (``rates``, those above its design rate), within a
   CPU budget; each certified rate gets the horizon ``N <= max_horizon`` that minimises its bound
   (only pairs with ``N >= min_horizon()`` are candidates, so every candidate is guaranteed); a rate
   whose gain-optimal certificate needs more than ``max_horizon`` (``min_horizon`` grows with
   log cond(P)) is certified again with cond(P) bounded so that it fits (``max_condition``);
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

The result carries both numbers per candidate, the guaranteed bound and the simulated RMS.
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from uiest.box import FloatArray, as_vector
from uiest.checks import check_int, user_stacklevel
from uiest.errors import CertificationError, DataError, OptionError
from uiest.health import without_bound_warnings
from uiest.system import System

CONDITION_MARGIN = 0.99
"""A design for ``max_horizon`` bounds cond(P) this fraction below :func:`horizon_condition`: the LMI solver keeps
``P << c I`` only to its tolerance, and the horizon's logarithm is floored."""

OUTPUT_WEIGHTS = (1.0, 10.0, 100.0)
"""Factors on a strong certificate's output weights the UISE design tries (``with_output_weight``): the certified
weights can leave the prior dominant over directly measured states (a Rossler map, N = 15: measured y RMSE 0.22 at x1,
0.0015 at x100)."""

ERROR_TOLERANCE = 1.02
"""Candidates whose :func:`regret` is within this factor of the best one's are equally accurate: the smallest
guaranteed bound decides among them (a larger bound for a difference within the records' scatter is no trade)."""

ERROR_FLOOR = 1e-6
"""A component's smallest error counts as at least this fraction of the largest component's (both relative to
their scales) in :func:`regret`: differences at the level of rounding are not scored."""

DEFAULT_RATES = (0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9)
"""Rates certified by default (with the minimal rate), each kept when it is at least mu_min."""


@dataclass(frozen=True)
class Candidate:
    """One (mu, N, output weight) weighed by the design.

    Attributes
    ----------
    mu : float
    N : int
    bound : ndarray
        The settled error bound (per state, or per ``z_sharp`` component for the two-stage UISE).
    rms : ndarray (nx,)
        Simulated state error RMS per state.
    output_weight : float
        The factor on the certificate's output weights.
    w_rms : ndarray (nw,)
        Simulated unknown-input error RMS per input (NaN where no estimate was delivered).

    """

    mu: float
    N: int
    bound: FloatArray
    rms: FloatArray
    output_weight: float = 1.0
    w_rms: FloatArray = field(default_factory=lambda: np.zeros(0))


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


@dataclass(frozen=True, eq=False)
class Design:
    """The chosen certificate and horizon, the bound they imply, and all candidates.

    Attributes
    ----------
    certificate : StrongDetectability or ReducedIOSS
        Certified at the chosen rate.
    N : int
    bound : ndarray
        The error the noise can leave, guaranteed by the theorem: per state for the UISE
        (:func:`settled_bound`, theo:MHE_full), per ``z_sharp`` component for the two-stage
        UISE (:func:`two_stage_bound`, theo:stab).
    candidates : tuple of Candidate
    seconds : float
        CPU time of the certifications.

    """

    certificate: Any
    N: int
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
            w_rms = f" w rms={np.array2string(c.w_rms, precision=3)}" if c.w_rms.size else ""
            rows.append(
                f"{mark} mu={c.mu:.4g} N={c.N:<3d}{weight} bound={np.array2string(c.bound, precision=3)} "
                f"rms={np.array2string(c.rms, precision=3)}{w_rms}"
            )
        return "\n".join(rows)


DESIGN_KEYS = ("max_horizon", "rates", "budget", "trials", "steps", "seed", "certify_options", "records")
"""Keywords of :func:`design_uise` / :func:`design_two_stage`; the others go to the estimators."""


def estimator_options(options: Mapping[str, Any]) -> dict[str, Any]:
    """The keywords of ``options`` that are not :data:`DESIGN_KEYS` (the designed estimator's own)."""
    return {k: v for k, v in options.items() if k not in DESIGN_KEYS}


def settled_bound(noise_gain: FloatArray, mu: float, N: int) -> FloatArray:
    """``noise_gain * 4 / sqrt(lambda (1 - lambda))`` with ``lambda = 8^{1/N} mu``; inf when lambda >= 1."""
    lam = 8.0 ** (1.0 / N) * mu
    if not 0.0 < lam < 1.0:
        return np.full(np.shape(noise_gain), np.inf)
    return np.asarray(noise_gain, dtype=float) * 4.0 / np.sqrt(lam * (1.0 - lam))


def two_stage_bound(certificate: Any, N: int, diameter: float) -> FloatArray:
    """theo:stab's settled error of ``z_sharp`` per component (its units), noise of scaled diameter ``diameter``.

    From eq:rges_proof_4 with ``|v - v_bar| <= diameter``: ``2 sqrt(c_v) diameter lambda / (1 - lambda)``
    scaled units, ``lambda = max(sqrt(mu) (2 sqrt(c_x))^{1/N}, sqrt(mu))``; inf when ``lambda >= 1``.
    """
    eta = np.sqrt(certificate.mu)
    lam = max(eta * (2.0 * np.sqrt(certificate.c_x)) ** (1.0 / N), eta)
    scale = np.asarray(certificate.scale, dtype=float)
    if not lam < 1.0:
        return np.full(scale.shape, np.inf)
    return 2.0 * np.sqrt(certificate.c_v) * diameter * lam / (1.0 - lam) * scale


def design_uise(
    system: System,
    x0: ArrayLike,
    *,
    max_horizon: int = 30,
    rates: tuple[float, ...] = DEFAULT_RATES,
    budget: float = 60.0,
    trials: int = 2,
    steps: int = 80,
    seed: int = 0,
    certify_options: Mapping[str, Any] | None = None,
    records: Sequence[Any] | None = None,
    **options: Any,
) -> Design:
    """Certify at several rates and keep the guaranteed (mu, N) with the smallest simulated noise error.

    Parameters
    ----------
    system : System
    x0 : array_like (nx,)
        A typical state (the estimator's prior): where the noise trials start.
    max_horizon : int
        Largest N considered (window cost grows with N).
    rates : tuple of float
        Rates in (0, 1) to certify besides the minimal one (those below mu_min are skipped).
    budget : float
        CPU seconds for the certifications; the grid stops when it is spent.
    trials, steps, seed : int
        Noise records per candidate, their length (the first quarter is not scored), the seed.
    certify_options : mapping, optional
        Passed to :func:`~uiest.detectability.certify_strong_detectability`.
    records : sequence of Trajectory, optional
        Simulated records (with their states) to score the candidates on instead of the noise
        trials: records of the operating conditions, inside X, with the unknown inputs one expects.
        Their first quarter is not scored.
    **options
        Window options of the candidate UISEs (``solver``, ...).

    Raises
    ------
    CertificationError
        When no rate certifies, or no certified rate has an admissible N within ``max_horizon``.

    """
    from uiest.detectability import certify_strong_detectability
    from uiest.detectability.certificate import horizon_condition
    from uiest.estimators import UISE

    certify = dict(certify_options or {})
    scale = system.x.scale

    def bound(cert: Any, n: int) -> FloatArray:
        return settled_bound(np.asarray(cert.noise_gain, dtype=float), cert.mu, n)

    def certify_with_horizon(mu: float | None) -> Any:
        """The certificate at mu; if its min_horizon exceeds max_horizon, one with cond(P) bounded to fit."""
        cert = certify_strong_detectability(system, mu=mu, **certify)
        if cert.certified and cert.min_horizon() > max_horizon and "max_condition" not in certify:
            fitting = CONDITION_MARGIN * horizon_condition(cert.mu, max_horizon)
            if fitting > 1.0:
                conditioned = certify_strong_detectability(system, mu=cert.mu, max_condition=fitting, **certify)
                if conditioned.certified:
                    return conditioned
        return cert

    return _design(
        system, x0, certify_with_horizon, bound,
        lambda cert, n, prior: UISE(system, certificate=cert, N=n, x0_prior=prior, **options),
        bound_scale=scale, what="strong detectability", max_horizon=max_horizon, rates=rates, budget=budget,
        trials=trials, steps=steps, seed=seed, records=records,
        variants=lambda cert: [cert.with_output_weight(factor) for factor in OUTPUT_WEIGHTS if factor != 1.0],
    )  # fmt: skip


def design_two_stage(
    reduced: Any,
    x0: ArrayLike,
    *,
    max_horizon: int = 30,
    rates: tuple[float, ...] = DEFAULT_RATES,
    budget: float = 60.0,
    trials: int = 2,
    steps: int = 80,
    seed: int = 0,
    certify_options: Mapping[str, Any] | None = None,
    records: Sequence[Any] | None = None,
    **options: Any,
) -> Design:
    """:func:`design_uise` for the two-stage UISE: reduced e-IOSS certificates and :func:`two_stage_bound`.

    ``reduced`` is a :class:`~uiest.reduction.ReducedModel`; ``options`` are the
    :class:`~uiest.estimators.TwoStageUISE` keywords (``projection``, window options). The
    candidates' ``bound`` is the settled error of ``z_sharp`` (theo:stab, per component).
    """
    from uiest.estimators import TwoStageUISE

    system = reduced.system
    certify = dict(certify_options or {})
    V = system.v.bounds
    diameter = float(np.linalg.norm(np.where(np.isfinite(V.width), V.width, 0.0) / system.v.scale))
    return _design(
        system, x0, lambda mu: reduced.certify(mu=mu, **certify), lambda cert, n: two_stage_bound(cert, n, diameter),
        lambda cert, n, prior: TwoStageUISE(reduced, certificate=cert, N=n, x0_prior=prior, **options),
        bound_scale=None, what="reduced e-IOSS (ass:e-ioss)", max_horizon=max_horizon, rates=rates, budget=budget,
        trials=trials, steps=steps, seed=seed, records=records,
    )  # fmt: skip


@without_bound_warnings  # the trial runs' estimates at X's sides are the candidates' business, not the user's
def _design(
    system: System,
    x0: ArrayLike,
    certify: Callable[[float | None], Any],
    bound: Callable[[Any, int], FloatArray],
    build: Callable[[Any, int, FloatArray], Any],
    *,
    bound_scale: FloatArray | None,
    what: str,
    max_horizon: int,
    rates: tuple[float, ...],
    budget: float,
    trials: int,
    steps: int,
    seed: int,
    records: Sequence[Any] | None,
    variants: Callable[[Any], list[Any]] = lambda cert: [],
) -> Design:
    """The design loop of the module docstring; ``bound_scale`` divides the bound when ranking N (None: as is)."""
    max_horizon = check_int(max_horizon, "max_horizon", low=1)
    trials, steps = check_int(trials, "trials", low=1), check_int(steps, "steps", low=1)
    prior = as_vector(x0, system.nx, "x0")
    try:
        grid = sorted({float(r) for r in rates})
    except (TypeError, ValueError):
        raise OptionError(f"rates: expected numbers in (0, 1), got {rates!r}") from None
    if any(not 0.0 < r < 1.0 for r in grid):
        raise OptionError(f"rates: expected numbers in (0, 1), got {list(rates)}")
    start = time.thread_time()
    first = certify(None)
    if not first.certified:
        raise CertificationError(f"system: {what} is not certified ({first.reason}); nothing to design")
    certificates = [first]
    for mu in grid:
        if mu > first.mu and time.thread_time() - start <= budget:
            cert = certify(mu)
            if cert.certified:
                certificates.append(cert)
    scored = _noise_records(system, prior, trials, steps, seed) if records is None else _given_records(system, records)
    divide = 1.0 if bound_scale is None else bound_scale
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
        output_weight = float(getattr(cert, "output_weight", 1.0))
        return Candidate(cert.mu, N, bound(cert, N), rms, output_weight, w_rms), cert

    def choose(pool: list[tuple[Candidate, Any]]) -> tuple[Candidate, Any]:
        """The smallest bound among the candidates whose regret is within ERROR_TOLERANCE of the best."""
        errors = np.array([np.concatenate([c.rms / system.x.scale, c.w_rms / system.w.scale]) for c, _ in pool])
        score = regret(errors)
        tied = [pair for pair, value in zip(pool, score, strict=True) if value <= ERROR_TOLERANCE * score.min()]
        return min(tied, key=lambda pair: float(np.max(pair[0].bound / divide)))

    for cert in certificates:
        horizons = range(cert.min_horizon(), max_horizon + 1)
        N = min(horizons, key=lambda n: float(np.max(bound(cert, n) / divide)), default=None)
        if N is not None:
            candidates.append(weigh(cert, N))
    if not candidates:
        raise CertificationError(
            f"max_horizon: no certified rate has an admissible horizon <= {max_horizon} "
            f"(min_horizon() of the minimal rate: {first.min_horizon()}; a larger max_horizon admits it, and "
            "the estimator built from a certificate with a shorter N runs without a guarantee)"
        )
    chosen, cert = choose(candidates)
    candidates += [weigh(variant, chosen.N) for variant in variants(cert)]  # the best rate's variants
    chosen, cert = choose(candidates)
    if bound_scale is not None:
        _warn_if_vacuous(system, chosen)
    return Design(cert, chosen.N, chosen.bound, tuple(c for c, _ in candidates), time.thread_time() - start)


def _warn_if_vacuous(system: System, chosen: Candidate) -> None:
    """Warn when the guaranteed noise bound of a state exceeds X's width: certified, but silent under this noise."""
    width = system.x.bounds.width
    wide = np.flatnonzero(np.isfinite(width) & (chosen.bound > width))
    if wide.size:
        names = [system.x.names[i] for i in wide]
        warnings.warn(
            f"design: the guaranteed noise bound of {names} ({np.array2string(chosen.bound[wide], precision=3)}) "
            f"exceeds X's width ({np.array2string(width[wide], precision=3)}): the certificate holds, but under "
            "V's noise its worst-case bound says nothing there (RMS on the design's records "
            f"{np.array2string(chosen.rms[wide], precision=3)})",
            UserWarning,
            stacklevel=user_stacklevel(),
        )


def _given_records(
    system: System, records: Sequence[Any]
) -> list[tuple[FloatArray | None, FloatArray, FloatArray, FloatArray]]:
    """``(u, y, x, w)`` of the user's records; DataError for anything that is not a record of ``system`` with states."""
    from uiest.results import Trajectory

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
    from uiest.detectability.lmi import finite_box
    from uiest.simulate import simulate

    rng = np.random.default_rng(seed)
    V = finite_box(system.v.bounds, system.v.bounds.center, system.v.scale)
    u = np.tile(system.u.bounds.center, (steps, 1)) if system.nu else None
    records = []
    for _ in range(trials):
        traj = simulate(system, x0, steps, u=u, w=system.nominal_w, v=V.sample(rng, steps + 1))
        records.append((u, traj.y, traj.x, traj.w))
    return records
