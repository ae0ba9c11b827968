"""Estimation on one's own measurements: what ``uiest estimate MODEL --data FILE`` runs.

Without ``--estimator`` the CLI runs the kind :func:`recommended` names (the analysis's recommendation);
``--estimator all`` runs :func:`build_all`: every kind below the model admits.
:func:`build_estimator` makes each estimator from the model alone, with a guarantee where the
model certifies:

- ``uise``: :meth:`UISE.design <uiest.estimators.UISE.design>` (certified mu and N <= ``horizon``,
  chosen for accuracy; without ``horizon``: N <= 30, or, where no window of at most 30 certifies,
  N <= 60); when there is no certified design (the model does not certify, or its certified window is
  longer than that limit), explicit weights with mu = 0.8 and N = ``horizon`` (default 20), and the run says
  why (naming ``--horizon``) and that it has no guarantee. Those weights are per scale
  (``UISEWeights.from_scales``), or, given a record, hold the outputs to their noise instead
  (:func:`fallback_weights`) where that run predicts the record's outputs one step ahead more than 2 % better.
- ``delayed``: the same for :class:`~uiest.estimators.DelayedUISE` (relative degree 2, ``lag >= 1``).
- ``two-stage``: :meth:`TwoStageUISE.design <uiest.estimators.TwoStageUISE.design>` on the
  model's reduction (a model without ``reduction()`` is refused), same fallback.
- ``mhe``: the standard MHE with the weights of a delta-IOSS certificate
  (:func:`~uiest.detectability.certify_delta_ioss`) and N = ``horizon`` (20) or its ``min_horizon()`` if
  longer (up to ``horizon``, default 60) where its guarantee is informative; otherwise (or with ``w_variance``)
  Gaussian weights (:func:`uiest.tuning.likelihood_weights`, eta = 0.8, N = ``horizon``) whose disturbance variance
  is ``w_variance`` (times ``w.scale^2``) or maximises the likelihood of the record
  (:func:`uiest.tuning.fit_standard_mhe`).
- ``ekf``, ``ukf``: random-walk variance ``w_variance`` (times ``w.scale^2``) if given, else the input model
  (random walk or integrated random walk), its variance and the prior's factor that maximise the likelihood of
  the record's innovations (:meth:`EKF.fit <uiest.estimators.kalman.KalmanFilter.fit>`: the prediction-error
  method, no true states); the note gives the choices, the profiles' shapes and each model's log-likelihood.
- ``smooth``: :meth:`SmoothInputMHE.design <uiest.estimators.SmoothInputMHE.design>` with the
  increments' variance ``w_variance`` or the variance of the EKF's random walk (the same model: ``w[k+1] = w[k] +
  dw[k]``) fitted to the record with the EKF's default prior, and ``max_horizon`` as for the UISE; its
  certificate's weights where their guarantee is informative, otherwise (with a record) the window prior from that
  EKF's settled covariance on the record, or, where that predicts the whole record one step ahead more than 2 %
  better (a prior of x[0] the data contradict), each window's from the EKF's covariance of its first node (its prior
  covariance at k = 0, its posterior ones after; :func:`uiest.tuning.arrival_covariances`), and the discount
  eta among the design's and :data:`~uiest.tuning.SMOOTH_DISCOUNTS` above it whose run on the record predicts the
  outputs best one step ahead (:func:`uiest.tuning.prediction_error`; no true states); the note gives each eta's
  error.
- ``uio``: the linear UIO (linear models only).

:func:`write_estimates` writes ``estimates_<estimator>.csv`` (t, x_hat, w_hat, the status line and
the step health fields of :meth:`~uiest.results.EstimationResult.to_pandas`, and ``<state>_lag``
columns with a lag), ``estimates.png`` (measured outputs beside each
estimator's predicted output ``h(x_hat, 0)``, the state and unknown-input estimates, and the
truth where the record has it) and ``manifest.json`` (the record's and the model's files with their SHA-256, the
estimators, the options, versions and machine); it removes the ``estimates_*.csv`` of an earlier run it did not
write.

Examples
--------
What ``uiest estimate closed-form --data FILE --estimator uise --horizon 10`` does, from Python (here on a
simulated record, which also holds the true states):

>>> from uiest import models, simulate
>>> from uiest.estimate import build_estimator, default_prior, errors_against_truth, run_estimators
>>> entry = models.get("closed-form")
>>> system = entry.build()
>>> setup = entry.simulation()
>>> record = simulate(system, setup.x0, 30, u=setup.u, w=setup.w, v=setup.noise, seed=3)
>>> prior = default_prior(entry, system)
>>> uise, note = build_estimator("uise", entry, system, prior, horizon=10)
>>> note  # doctest: +ELLIPSIS
'designed: mu=..., N=..., certified'
>>> results = run_estimators({"uise": uise}, record, prior)
>>> results["uise"].guarantee.applies, bool(errors_against_truth(record, results)["uise"].max() < 0.05)
(True, True)

"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

import numpy as np

from uiest import estimators as est
from uiest.analysis import Recommendation, analyse
from uiest.atomic import remove_unwritten, staged_folder, write_file, write_text
from uiest.box import FloatArray
from uiest.checks import user_stacklevel
from uiest.covariance import output_noise_variance
from uiest.delay import delayed_system, matching_ranks
from uiest.detectability import certify_delta_ioss
from uiest.errors import CertificationError, HorizonError, ModelError, OptionError
from uiest.estimators import EKF, UISE, SmoothInputMHE, StandardMHE, UISEWeights, smooth_mhe
from uiest.estimators.design_search import ERROR_TOLERANCE
from uiest.health import quiet_bound_warnings
from uiest.input_model import InputModel
from uiest.json_text import json_text
from uiest.lock import holds_folder
from uiest.models import ModelEntry
from uiest.paths import plain_name
from uiest.plotting import plot_record, save_figure
from uiest.reduction import ReducedModel
from uiest.results import EstimationResult, Trajectory
from uiest.run_data import check_run_data
from uiest.system import System
from uiest.tuning import (
    SMOOTH_DISCOUNTS,
    arrival_covariances,
    fit_standard_mhe,
    likelihood_weights,
    prediction_error,
    preferred_discount,
)
from uiest.window import size as window_size

if TYPE_CHECKING:
    from uiest.estimators import UISE, TwoStageUISE
    from uiest.estimators.kalman import KalmanFilter

__all__ = [
    "ALL",
    "DEFAULT_MAX_HORIZON",
    "LONGEST_HORIZON",
    "build_all",
    "build_estimator",
    "check_lag",
    "default_prior",
    "error_text",
    "errors_against_truth",
    "internal_error",
    "recommended",
    "run_estimators",
    "write_estimates",
]

ESTIMATORS = ("uise", "delayed", "two-stage", "mhe", "smooth", "ekf", "ukf", "uio")
ALL = "all"
"""``--estimator all``: every estimator of :data:`ESTIMATORS` the model admits."""
Key = TypeVar("Key")

FALLBACK_RATE = 0.8
"""Discount of the explicit weights used when a model does not certify (a slow forgetting, as the designs pick)."""
DEFAULT_HORIZON = 20
DEFAULT_MAX_HORIZON = 30
"""The designs' ``max_horizon`` when ``horizon`` is not given, as the library's (a window's cost grows with N)."""
LONGEST_HORIZON = 60
"""Without ``horizon``: the longest certified window admitted where none of at most DEFAULT_MAX_HORIZON certifies."""


def recommended(system: System, x0: FloatArray, horizon: int | None) -> tuple[str, str]:
    """The estimator kind :func:`uiest.analysis.analyse` recommends for ``system``, and its reason (one sentence)."""
    kinds = {Recommendation.UISE: "uise", Recommendation.DELAYED_UISE: "delayed",
             Recommendation.SMOOTH_INPUT_MHE: "smooth", Recommendation.EKF_UKF: "ekf"}  # fmt: skip
    analysis = analyse(system, x0=x0, max_horizon=LONGEST_HORIZON if horizon is None else horizon)
    return kinds[analysis.recommendation], analysis.reason


def build_all(
    entry: ModelEntry, system: System, x0: FloatArray, **options: Any
) -> tuple[dict[str, Any], dict[str, str], dict[str, str]]:
    """Every estimator of :data:`ESTIMATORS` the model admits (:func:`build_estimator`'s options).

    Returns (estimators, notes, skipped): a kind the model does not admit (matching, no reduction, not
    linear, ...) or that could not be built (a fit to the record without a candidate, weights out of the window's
    range) is in ``skipped`` with the reason; the others are built.
    """
    built, notes, skipped = {}, {}, {}
    for kind in ESTIMATORS:
        try:
            built[kind], notes[kind] = build_estimator(kind, entry, system, x0, **options)
        except (ModelError, CertificationError, OptionError) as exc:  # not admitted, or not built on this record
            skipped[kind] = str(exc)
        except Exception as exc:  # a defect met by one estimator: the others are still built, and the error named
            skipped[kind] = internal_error(exc)
    return built, notes, skipped


def internal_error(exc: Exception) -> str:
    """Why an estimator was not built where an unexpected exception (a defect, not a refusal) stopped it."""
    return f"internal error, please report it: {type(exc).__name__}: {exc}"


def default_prior(entry: ModelEntry, system: System) -> FloatArray:
    """The prior of x[0]: the model's default initial state if it has one, else the centre of X (0 where unbounded)."""
    if entry.setup is not None:
        return np.asarray(entry.setup().x0, dtype=float)
    center = system.x.bounds.center
    return np.where(np.isfinite(center), center, 0.0)


def check_lag(lag: int, horizon: int | None) -> int:
    """``lag`` if it is below the horizon, else OptionError naming ``--lag`` (before anything is built).

    The horizon is ``horizon``, else :data:`LONGEST_HORIZON` (the longest window designed without it).
    A window of N transitions holds ``x[k-N] .. x[k]``, so it has no estimate of ``x[k-lag]`` for
    ``lag > N``, and the delayed UISE needs ``lag < N``. A given horizon is never lengthened by the
    lag; without one, the windows are at least ``lag + 1`` long.
    """
    limit = LONGEST_HORIZON if horizon is None else horizon
    if lag >= limit:
        source = (
            f"--horizon = {horizon}"
            if horizon is not None
            else f"the longest horizon designed without --horizon, {limit}"
        )
        raise OptionError(f"--lag: expected an integer below the horizon ({source}), got {lag}")
    return lag


def _reduction(entry: ModelEntry, built: ReducedModel | None = None) -> ReducedModel:
    """``built``, else the model's reduced model (the two-stage UISE's); ModelError when the model registers none."""
    if built is not None:
        return built
    if entry.reduction is None:
        raise ModelError(f"the two-stage UISE: the model {entry.name!r} has no reduction() (T, psi)")
    return entry.reduction()


def build_estimator(
    kind: str,
    entry: ModelEntry,
    system: System,
    x0: FloatArray,
    *,
    lag: int = 0,
    horizon: int | None = None,
    w_variance: float | None = None,
    record: Trajectory | None = None,
) -> tuple[Any, str]:
    """The estimator ``kind`` (module docstring) and a note on how its weights were chosen.

    ``record``: the measurements the variances are fitted to (``ekf``, ``ukf`` and ``mhe`` without ``w_variance``).
    """
    if kind not in ESTIMATORS:
        raise OptionError(f"--estimator: expected one of {[*ESTIMATORS, ALL]}, got {kind!r}")
    check_lag(lag, horizon)
    N = max(DEFAULT_HORIZON, lag + 1) if horizon is None else horizon  # a window that holds x[k - lag]
    options: dict[str, Any] = {"lag": lag} if lag else {}
    reduced = _reduction(entry) if kind == "two-stage" else None  # refused before any design work when missing
    if kind in ("uise", "two-stage"):
        rank_CB, rank_B = matching_ranks(system)
        if rank_CB < rank_B:  # no fallback weights help: x[k] is not determined by y[..k]
            try:
                delayed_system(system)
                hint = "the delayed UISE applies: use --estimator delayed"
            except ModelError as exc:
                hint = f"the delayed UISE does not apply either ({exc})"
            raise ModelError(f"--estimator {kind}: matching fails (rank(C B) = {rank_CB} < rank(B) = {rank_B}); {hint}")
    if kind in ("uise", "delayed", "two-stage"):
        # without a horizon: N <= 30, or up to 60 where none of at most 30 certifies (the certificates reused); the
        # longer limit within what the model's window may take in memory
        designed = delayed_system(system).system if kind == "delayed" else system
        limits: dict[str, Any] = (
            {"max_horizon": max(DEFAULT_MAX_HORIZON, lag + 1),
             "fallback_horizon": min(max(LONGEST_HORIZON, lag + 1), window_size.max_horizon(designed))}
            if horizon is None
            else {"max_horizon": horizon}
        )  # fmt: skip
        try:
            built: UISE | TwoStageUISE
            if kind == "uise":
                built = est.UISE.design(system, x0_prior=x0, **limits, **options)
            elif kind == "delayed":
                built = est.DelayedUISE.design(system, x0_prior=x0, **limits, **{**options, "lag": max(lag, 1)})
            else:
                built = est.TwoStageUISE.design(_reduction(entry, reduced), x0_prior=x0, **limits, **options)
            assert built.weights is not None  # a certified design has weights (n_sharp = 0 has no design)
            claim = "certified" if built.guarantee.applies else "certified, no guarantee (its guarantee says why)"
            return built, f"designed: mu={built.weights.mu:.3g}, N={built.N}, {claim}"
        except HorizonError as exc:  # certified, with a longer window than admitted
            reason = horizon_reason(exc.limit, exc.shortest, None if record is None else record.steps)
        except (CertificationError, ModelError) as exc:  # e.g. X unbounded, an output not affine in x
            reason = str(exc)
        note = f"no certified design ({reason}); explicit weights mu={FALLBACK_RATE}, N={N}, no guarantee"
        if kind == "uise":
            fallback, weighting = _fallback_uise(system, N, x0, options, record)
            return fallback, f"{note}; {weighting}"
        if kind == "delayed":
            delayed = est.DelayedUISE(system, weights=_delayed_weights(system), N=max(N, lag + 1),
                                      x0_prior=x0, lag=max(lag, 1))  # fmt: skip
            return delayed, note
        reduced = _reduction(entry, reduced)
        weights = est.TwoStageWeights.from_scales(reduced, FALLBACK_RATE)
        return est.TwoStageUISE(reduced, weights=weights, N=N, x0_prior=x0, **options), note
    if kind == "mhe":
        return _standard_mhe(system, x0, N, horizon, options, record, w_variance)
    if kind == "uio":
        return est.LinearUIO(system, x0_prior=x0), "Chen-Patton-Zhang observer (DARE gain)"
    if w_variance is not None:
        factor, source = w_variance, "given"
    else:
        u, y = _record_data(kind, system, record)
        if kind != "smooth":
            kalman: type[KalmanFilter] = est.EKF if kind == "ekf" else est.UKF
            fitted = kalman.fit(system, u, y, x0_prior=x0)
            assert fitted.filter_fit is not None
            return fitted, f"{fitted.filter_fit.summary()} on the data"
        # the smooth-input MHE's model is the random walk, its prior the EKF's default: the EKF's fit of that model
        fitted = est.EKF.fit(system, u, y, x0_prior=x0, input_models=InputModel.RANDOM_WALK, prior_factors=[1.0])
        assert fitted.likelihood is not None
        factor, source = fitted.likelihood.chosen, f"the EKF's random walk: {fitted.likelihood.summary()} on the data"
    if kind == "smooth":
        return _smooth_mhe(system, x0, factor, source, horizon, options, record)
    cls: type[KalmanFilter] = est.EKF if kind == "ekf" else est.UKF
    return cls(system, w_variance=factor * system.w.scale**2, x0_prior=x0), (
        f"random-walk variance {variance_text(system, factor)} ({source})"
    )


def variance_text(system: System, factor: float) -> str:
    """A step variance given as ``factor`` times ``w.scale^2``, and in each unknown input's own unit squared.

    For example ``"0.01 w.scale^2 = torque 0.04 (N m)^2 per step"``: the factor, then per input
    ``factor * scale_i^2`` with the input's unit (none for a unitless input).
    """
    parts = [
        f"{name} {factor * scale**2:.3g}{f' ({unit})^2' if unit else ''}"
        for name, unit, scale in zip(system.w.names, system.w.units, system.w.scale, strict=True)
    ]
    return f"{factor:g} w.scale^2 = {', '.join(parts)} per step"


def horizon_reason(limit: int, shortest: int, steps: int | None = None) -> str:
    """Why a certificate gave no estimator: its shortest window exceeds the limit (named as the CLI's flag).

    ``steps``: the record's length, where the shortest window is longer than it (a window never fills).
    """
    admits = (f"--horizon {shortest} admits it" if steps is None or shortest <= steps
              else f"longer than the record's {steps} samples")  # fmt: skip
    return f"certified, but with no window within --horizon {limit}: the shortest is {shortest}, {admits}"


def _smooth_mhe(system: System, x0: FloatArray, factor: float, source: str, horizon: int | None,
                options: dict[str, Any], record: Trajectory | None) -> tuple[Any, str]:  # fmt: skip
    """The smooth-input MHE with increments of variance ``factor * w.scale^2`` (:meth:`SmoothInputMHE.design`).

    Its certificate's weights are kept where their guarantee is informative; otherwise, given a record, the window's
    prior weight is the inverse of the random-walk EKF's settled covariance of ``(x, w)`` on it, with the design's N
    and no guarantee: the certificate's prior (or the EKF's ``P0``) is far weaker than what the data determine, and a
    window prior that never tightens lets the window explain the data by moving its oldest states. That weight holds
    a wrong x[0] for hundreds of samples, so where per-window weights (the window that starts at time s weighed by the
    inverse of the EKF's covariance of ``(x[s], w[s])``, its prior one at s = 0, its posterior one after y[s];
    :func:`uiest.tuning.arrival_covariances`) predict the whole record one step ahead more than 2 % better at the
    design's eta, they are used. Then eta is chosen (:func:`_smooth_discount`).
    """
    variance = factor * system.w.scale**2
    lag = options.get("lag", 0)
    longest = max(DEFAULT_MAX_HORIZON, lag + 1) if horizon is None else horizon
    window = max(min(smooth_mhe.DEFAULT_HORIZON, longest), lag + 1)  # the design's default N, holding x[k - lag]
    mhe = SmoothInputMHE.design(system, dw_variance=variance, x0_prior=x0, N=window, max_horizon=longest, **options)
    increments = f"increment variance {variance_text(system, factor)} ({source})"
    certified = f"delta-IOSS certificate of the augmented model: eta={mhe.weights.eta:.3g}, N={mhe.N}, {increments}"
    if mhe.certificate is not None and mhe.guarantee.informative:
        return mhe, certified
    why = mhe.why_uncertified or f"the certified smooth-input MHE's guarantee {mhe.guarantee.text}"
    if record is None:
        if mhe.certificate is None:
            return mhe, f"{why}; explicit weights eta={mhe.weights.eta:.3g}, N={mhe.N}, {increments}"
        return mhe, certified
    u, y = check_run_data(system, record.u if system.nu else None, record.y)
    prior, starts = arrival_covariances(EKF(system, w_variance=variance, x0_prior=x0), u, y, with_input=True)
    weights = replace(mhe.weights, P=0.5 * np.linalg.inv(prior))

    def build(eta: float, arrival: FloatArray | None = None) -> SmoothInputMHE:
        return SmoothInputMHE(system, weights=replace(weights, eta=eta), dw_variance=variance, dw_bound=mhe.dw_bound,
                              N=mhe.N, x0_prior=x0, arrival_P=arrival, **options)  # fmt: skip

    # a prior of x[0] the data contradict shows in the first predictions: then weigh each window's prior by what the
    # EKF knew of its first node (its prior covariance at k = 0, its posterior ones after), so that x[0] is let go
    arrivals: dict[str, FloatArray | None] = {
        "settled": None,
        "per window": np.asarray(0.5 * np.linalg.inv(starts), dtype=float),
    }
    trials = {key: build(weights.eta, arrival) for key, arrival in arrivals.items()}
    runs: dict[str, EstimationResult] = {}
    kept, errors = _scored_trials(system, trials, "settled", x0, u, y, first=0, runs=runs)
    source = {"settled": "the EKF's settled covariance of (x, w) on the data",
              "per window": "the EKF's covariance of (x, w) at each window's first node"}[kept]  # fmt: skip
    compared = (f"whole-record one-step prediction error {errors['per window']:#.4g} against {errors['settled']:#.4g} "
                "with the settled one, at the design's eta")  # fmt: skip
    data_prior, why_eta = _smooth_discount(system, lambda eta: build(eta, arrivals[kept]), weights.eta, x0, u, y,
                                           (trials[kept], runs[kept]))  # fmt: skip
    chosen = data_prior.weights.eta
    data_prior.why_uncertified = f"its window prior is {source}, not a certificate's ({why})"
    note = (f"no informative certified design (its guarantee says why); window prior: {source} ({compared}), "
            f"eta={chosen:.3g} ({why_eta}), N={mhe.N}, {increments}")  # fmt: skip
    return data_prior, note


def _smooth_discount(system: System, build: Callable[[float], SmoothInputMHE], design: float, x0: FloatArray,
                     u: FloatArray, y: FloatArray,
                     done: tuple[SmoothInputMHE, EstimationResult] | None = None
                     ) -> tuple[SmoothInputMHE, str]:  # fmt: skip
    """The data-tuned smooth-input MHE, ``build(eta)`` at the design's eta or one of :data:`SMOOTH_DISCOUNTS` above it.

    Each candidate runs on the record and is scored by its one-step output prediction error
    (:func:`~uiest.tuning.prediction_error`, :func:`~uiest.tuning.preferred_discount`). Returns the chosen estimator
    and why it was chosen. ``done``: the design eta's estimator and its run on the record, where already made.
    """
    candidates = (design, *(eta for eta in SMOOTH_DISCOUNTS if eta > design))
    if len(candidates) == 1:
        kept = build(design) if done is None else done[0]
        return kept, f"the design's; none of {', '.join(f'{eta:g}' for eta in SMOOTH_DISCOUNTS)} is above it"
    built = {eta: done[0] if done is not None and eta == design else build(eta) for eta in candidates}
    chosen, errors = _scored_trials(system, built, design, x0, u, y, runs=None if done is None else {design: done[1]})
    tried = ", ".join(f"eta {eta:.3g}: {error:#.4g}" for eta, error in errors.items())
    margin = f"{100 * (ERROR_TOLERANCE - 1):g} %"
    what = "one-step output prediction error over the record's second half"
    rule = (f"its {what} is more than {margin} below the design eta's" if chosen != design
            else f"the design's: no other eta's {what} is more than {margin} below it")  # fmt: skip
    return built[chosen], f"{rule}; the errors in output scales: {tried}"


def _scored_trials(system: System, trials: dict[Key, Any], default: Key, x0: FloatArray, u: FloatArray,
                   y: FloatArray, first: int | None = None,
                   runs: dict[Key, EstimationResult] | None = None) -> tuple[Key, dict[Key, float]]:  # fmt: skip
    """Each trial estimator's run on the record scored by its one-step output prediction error; the one to use.

    The ``default`` unless another predicts more than ``ERROR_TOLERANCE`` better
    (:func:`~uiest.tuning.prediction_error` from ``first``, :func:`~uiest.tuning.preferred_discount`; no true states
    needed). ``runs``: runs already made (used, not repeated), and where the new ones are kept.
    """
    runs = {} if runs is None else runs
    errors: dict[Key, float] = {}
    for key, estimator in trials.items():
        if key not in runs:
            with quiet_bound_warnings():  # trial runs: the chosen one's run reports its own steps
                runs[key] = estimator.run(u if system.nu else None, y, x0_prior=x0)
        errors[key] = prediction_error(system, runs[key].x_hat, runs[key].w_hat, u, y, first)
    return preferred_discount(errors, default), errors


def _fallback_uise(system: System, N: int, x0: FloatArray, options: dict[str, Any],
                   record: Trajectory | None) -> tuple[UISE, str]:  # fmt: skip
    """The UISE with explicit weights: per scale, or with the outputs held to their noise where that predicts better.

    Without a record the weights per scale (:meth:`UISEWeights.from_scales`); with one, also
    :func:`fallback_weights`, each run on it and chosen by :func:`_scored_trials`.
    """
    trials = {
        "per scale": UISE(system, weights=UISEWeights.from_scales(system, FALLBACK_RATE), N=N, x0_prior=x0, **options)
    }
    if record is None or not system.nv:
        return trials["per scale"], "output residuals weighted per y's scale"
    trials["per noise"] = UISE(system, weights=fallback_weights(system), N=N, x0_prior=x0, **options)
    u, y = check_run_data(system, record.u if system.nu else None, record.y)
    chosen, errors = _scored_trials(system, trials, "per scale", x0, u, y)
    tried = ", ".join(f"{key}: {error:#.4g}" for key, error in errors.items())
    margin = f"{100 * (ERROR_TOLERANCE - 1):g} %"
    why = (f"more than {margin} below per scale's" if chosen != "per scale"
           else f"no other more than {margin} below it")  # fmt: skip
    return trials[chosen], (f"output residuals weighted {chosen} ({why} in one-step output prediction error over the "
                            f"record's second half, in output scales: {tried})")  # fmt: skip


def _standard_mhe(system: System, x0: FloatArray, N: int, horizon: int | None, options: dict[str, Any],
                  record: Trajectory | None, w_variance: float | None) -> tuple[Any, str]:  # fmt: skip
    """The standard MHE: certificate weights where their guarantee is informative, else Gaussian weights.

    The Gaussian weights' disturbance variance is ``w_variance`` or fitted to the record by likelihood
    (:mod:`uiest.tuning`).
    """
    baseline = "a baseline: the unknown input is penalised as a disturbance"
    longest = LONGEST_HORIZON if horizon is None else horizon
    reason = ""
    if w_variance is None:
        try:
            cert = certify_delta_ioss(system)
            reason = cert.reason
            if cert.certified and cert.min_horizon() <= longest:
                window = max(N, cert.min_horizon())
                mhe = StandardMHE(system, certificate=cert, N=window, x0_prior=x0, **options)
                if mhe.guarantee.informative:
                    return mhe, f"delta-IOSS certificate: eta={mhe.weights.eta:.3g}, N={window} ({baseline})"
                reason = f"certified, but its guarantee is {mhe.guarantee.verdict.value}"
            elif cert.certified:
                reason = horizon_reason(longest, cert.min_horizon(), None if record is None else record.steps)
        except (CertificationError, ModelError) as exc:
            reason = str(exc)
    u, y = _record_data("mhe", system, record)
    if w_variance is not None:
        weights = likelihood_weights(system, u, y, x0_prior=x0, eta=FALLBACK_RATE,
                                     w_variance=w_variance * system.w.scale**2)  # fmt: skip
        mhe = StandardMHE(system, weights=weights, N=N, x0_prior=x0, **options)
        variance = variance_text(system, w_variance)
        return mhe, f"disturbance variance {variance} (given), eta={FALLBACK_RATE}, N={N} ({baseline})"
    mhe = fit_standard_mhe(system, u, y, x0_prior=x0, N=N, eta=FALLBACK_RATE, **options)
    assert mhe.likelihood is not None
    return mhe, (
        f"no informative delta-IOSS design ({reason}); disturbance: {mhe.likelihood.summary()} on the data, "
        f"eta={FALLBACK_RATE}, N={N} ({baseline})"
    )


def _record_data(kind: str, system: System, record: Trajectory | None) -> tuple[FloatArray | None, FloatArray]:
    """The record's u (None when nu = 0) and y, to fit a variance to; OptionError without one."""
    if record is None:
        raise OptionError(f"--w-variance: required for {kind} without measurements to fit it to (--data)")
    return (record.u if system.nu else None), record.y


def fallback_weights(system: System) -> UISEWeights:
    """The UISE's explicit weights where no certified design is had: mu = FALLBACK_RATE, outputs held to their noise.

    Per scaled unit (:meth:`UISEWeights.from_scales`), except the output residual's weight, ``1 / sigma_y^2`` with
    ``sigma_y^2 = diag(D Sigma_v D^T)`` (``D = dh/dv`` at X's centre, V's uniform variance; at least
    :data:`~uiest.estimators.smooth_mhe.NOISE_FLOOR` of y's scale): an output mismatch costs as much as the noise
    that would explain it, whatever y's scale. Weighted by y's scale instead, a record of I = 1e6 persons counted to
    +-100 on an X 1e7 wide left a residual of 5e4 costing (5e-3)^2, and the estimate ignored the outputs.
    """
    if not system.nv:
        return UISEWeights.from_scales(system, FALLBACK_RATE)
    sigma_y = output_noise_variance(system, smooth_mhe.NOISE_FLOOR)
    return UISEWeights.from_scales(system, FALLBACK_RATE, output=system.y.scale**2 / sigma_y)


def _delayed_weights(system: System) -> Any:

    return UISEWeights.from_scales(delayed_system(system).system, FALLBACK_RATE)


def run_estimators(estimators: dict[str, Any], record: Trajectory, x0: FloatArray) -> dict[str, EstimationResult]:
    """Each estimator's run on the record's u and y."""
    u = record.u if record.u.shape[1] else None
    return {label: estimator.run(u, record.y, x0_prior=x0) for label, estimator in estimators.items()}


@holds_folder("out")
def write_estimates(
    out: Path,
    system: System,
    record: Trajectory,
    results: dict[str, EstimationResult],
    *,
    manifest: dict[str, Any] | None = None,
) -> list[Path]:
    """``estimates_<label>.csv`` per estimator, ``estimates.png`` and ``manifest.json``; returns the paths.

    The files (module docstring) replace earlier ones all together or not at all (:func:`uiest.atomic.staged_folder`);
    the folder is held against other runs while they are written (:mod:`uiest.lock`). ``manifest.json`` holds
    ``manifest`` (where the record and the model came from) and the names of the files written; without
    ``manifest`` none is written. Then the ``estimates_*.csv`` files of an earlier run that this one did not write,
    and without ``manifest`` an earlier run's ``manifest.json``, are removed with a warning naming them: they
    belong to another record or other estimators.
    """
    out = Path(out)
    names = {label: plain_name(label, "results") for label in results}
    written = [out / f"estimates_{names[label]}.csv" for label in results] + [out / "estimates.png"]
    figure = plot_record(system, record, results)
    with staged_folder(out) as stage:
        for label, result in results.items():
            frame = result.to_pandas()
            frame["t"] = record.t  # the data's own times
            write_file(stage / f"estimates_{names[label]}.csv", frame.to_csv)
        save_figure(figure, stage / "estimates.png")
        if manifest is not None:
            files = sorted(path.name for path in written)
            write_text(stage / "manifest.json", json_text({**manifest, "files": files}))
    if manifest is not None:
        written.append(out / "manifest.json")
    _remove_stale(out, written)
    return written


def _remove_stale(out: Path, written: list[Path]) -> None:
    """Remove the ``estimates_*.csv`` and ``manifest.json`` in ``out`` that are not ``written``, naming them."""
    stale = remove_unwritten([*out.glob("estimates_*.csv"), out / "manifest.json"], written)
    if stale:
        warnings.warn(
            f"out: removed {', '.join(path.name for path in stale)} from {out}: written by an earlier run (another "
            "record or other estimators), not by this one",
            UserWarning,
            stacklevel=user_stacklevel(),
        )


def errors_against_truth(record: Trajectory, results: dict[str, EstimationResult]) -> dict[str, FloatArray]:
    """Each estimator's RMSE per state (nx,), in the states' units, where the record has true states (NaN otherwise).

    The delayed UISE (``"delayed"``) is scored on its lagged estimate ``x_lag`` (of ``x[k - lag]``, what it
    delivers; its ``x_hat`` is a prediction), the others on ``x_hat``; rows without an estimate are left out.
    """
    errors = {}
    for label, result in results.items():
        estimate = result.x_lag if label == "delayed" and result.x_lag is not None else result.x_hat
        error = record.x - estimate if record.has_states else np.full(estimate.shape, np.nan)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # a state without any estimate: NaN, no warning
            errors[label] = np.sqrt(np.nanmean(error**2, axis=0))
    return errors


UNITLESS = ("", "-", "1")
"""Units :func:`error_text` does not print."""


def error_text(system: System, rmse: FloatArray, *, lagged: bool = False) -> str:
    """``rmse (nx,)`` as ``"c_A 0.0012 mol/L, T 0.05 K"`` (``lagged``: of x[k - lag]); "no truth in the data" if NaN."""
    if np.all(np.isnan(rmse)):
        return "no truth in the data"
    parts = [f"{name} {value:.3g}{f' {unit}' if unit not in UNITLESS else ''}"
             for name, unit, value in zip(system.x.names, system.x.units, rmse, strict=True)]  # fmt: skip
    return ", ".join(parts) + (" (of x[k-lag])" if lagged else "")
