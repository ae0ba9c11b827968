"""Run a :class:`~uiest.experiments.scenario.Scenario`: simulate, estimate, record everything.

Every run and estimator is recorded even when a solve fails (the estimators propagate and
record the status); an estimator that raises on a run is recorded with the error message and
the study goes on.
"""

from __future__ import annotations

import contextlib
import numbers
import os
import time
from collections.abc import Callable, Generator
from concurrent.futures import as_completed
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from uiest import models
from uiest.augmented import augmented_system
from uiest.box import FloatArray
from uiest.checks import check_callable, shown
from uiest.errors import OptionError, UiestError
from uiest.estimators import (
    FIE,
    UISE,
    EstimationResult,
    MHEWeights,
    SmoothInputMHE,
    StandardMHE,
    TwoStageUISE,
    TwoStageWeights,
    UISEWeights,
)
from uiest.estimators.kalman import EKF, UKF
from uiest.estimators.smooth_mhe import increments, variance_weights
from uiest.experiments import executors
from uiest.experiments.certificates import summary
from uiest.experiments.scenario import EstimatorSpec, Scenario
from uiest.experiments.study_model import StudyModel, study_model
from uiest.experiments.study_store import StudyStore
from uiest.health import quiet_bound_warnings
from uiest.models import ModelEntry
from uiest.noise import GaussianNoise, NoiseModel, UniformNoise
from uiest.results import Trajectory, count_names
from uiest.simulate import simulate
from uiest.system import System
from uiest.window.backends import BACKENDS

if TYPE_CHECKING:
    import pandas as pd

    from uiest.estimators.base import WindowEstimator
    from uiest.estimators.kalman import KalmanFilter

__all__ = ["BUILDERS", "RunOutcome", "StudyResult", "noise_model", "run_study", "simulate_run"]

Builder = Callable[[StudyModel, EstimatorSpec, FloatArray, str], "WindowEstimator | KalmanFilter"]
"""``(study model, spec, prior, solver) -> estimator``."""

STUDY_MAX_STEPS = 10_000_000
"""A study's FIE runs as long as the scenario says: its length is the author's choice, not an accident."""


def _certificate(study: StudyModel, spec: EstimatorSpec) -> Any:
    """The certificate of a spec with ``weights = "certificate"``, else None."""
    return study.certificate(spec.kind, spec.mu, spec.w_variance) if spec.weights == "certificate" else None


def _uise(study: StudyModel, spec: EstimatorSpec, prior: FloatArray, solver: str) -> WindowEstimator | KalmanFilter:
    certificate, system = _certificate(study, spec), study.system
    if certificate is not None:
        return UISE(system, certificate=certificate, N=spec.N or None, x0_prior=prior, solver=solver)
    weights = UISEWeights.from_scales(
        system, spec.mu, prior=spec.prior_weight, output=spec.output_weight, noise=spec.noise_weight
    )
    return UISE(system, weights=weights, N=spec.N, x0_prior=prior, solver=solver)


def _fie(study: StudyModel, spec: EstimatorSpec, prior: FloatArray, solver: str) -> WindowEstimator | KalmanFilter:
    certificate, system = _certificate(study, spec), study.system
    if certificate is not None:
        return FIE(system, certificate=certificate, x0_prior=prior, solver=solver, max_steps=STUDY_MAX_STEPS)
    weights = UISEWeights.from_scales(
        system, spec.mu, prior=spec.prior_weight, output=spec.output_weight, noise=spec.noise_weight
    )
    return FIE(system, weights=weights, x0_prior=prior, solver=solver, max_steps=STUDY_MAX_STEPS)


def _standard_mhe(
    study: StudyModel, spec: EstimatorSpec, prior: FloatArray, solver: str
) -> WindowEstimator | KalmanFilter:
    certificate, system = _certificate(study, spec), study.system
    if certificate is not None:
        return StandardMHE(system, certificate=certificate, N=spec.N or None, x0_prior=prior, solver=solver)
    weights = MHEWeights.from_scales(
        system,
        spec.mu,
        prior=spec.prior_weight,
        output=spec.output_weight,
        noise=spec.noise_weight,
        disturbance=spec.disturbance_weight,
    )
    return StandardMHE(system, weights=weights, N=spec.N, x0_prior=prior, solver=solver)


def _two_stage(
    study: StudyModel, spec: EstimatorSpec, prior: FloatArray, solver: str
) -> WindowEstimator | KalmanFilter:
    reduced, certificate = study.reduction, _certificate(study, spec)
    if certificate is not None:
        return TwoStageUISE(reduced, certificate=certificate, N=spec.N or None, x0_prior=prior, solver=solver)
    weights = TwoStageWeights.from_scales(
        reduced, spec.mu, prior=spec.prior_weight, output=spec.output_weight, noise=spec.noise_weight
    )
    return TwoStageUISE(reduced, weights=weights, N=spec.N, x0_prior=prior, solver=solver)


def _kalman(study: StudyModel, spec: EstimatorSpec, prior: FloatArray, solver: str) -> WindowEstimator | KalmanFilter:

    factor = spec.w_variance if spec.w_variance > 0 else study.tuned_variance(spec.kind)
    system = study.system
    return (EKF if spec.kind == "ekf" else UKF)(system, w_variance=factor * system.w.scale**2, x0_prior=prior)


def _smooth_mhe(
    study: StudyModel, spec: EstimatorSpec, prior: FloatArray, solver: str
) -> WindowEstimator | KalmanFilter:
    system = study.system
    variance = study.increment_variance(spec.w_variance) * system.w.scale**2
    certificate = _certificate(study, spec)
    if certificate is not None:
        return SmoothInputMHE(system, certificate=certificate, dw_variance=variance, N=spec.N or None,
                              x0_prior=prior, solver=solver)  # fmt: skip
    bound, _ = increments(None, variance, system.nw)
    weights = variance_weights(augmented_system(system, bound), variance, spec.mu)
    return SmoothInputMHE(system, weights=weights, dw_variance=variance, N=spec.N, x0_prior=prior, solver=solver)


BUILDERS: dict[str, Builder] = {"uise": _uise, "fie": _fie, "standard-mhe": _standard_mhe, "two-stage": _two_stage,
                                "smooth-mhe": _smooth_mhe, "ekf": _kalman, "ukf": _kalman}  # fmt: skip
"""Estimator factories by ``EstimatorSpec.kind``."""


@dataclass(frozen=True, kw_only=True)
class StudyResult:
    """Everything a study produced, as tables (no pickles).

    Attributes
    ----------
    scenario : Scenario
    steps : pandas.DataFrame
        One row per (case, run, estimator, k): ``t``, true and estimated states
        (``<name>``, ``<name>_hat``), ``w`` and ``w_hat`` columns, ``solve_time`` (wall-clock seconds in
        the solver), ``cpu_time`` (CPU seconds of the whole step), ``status`` (the
        display line), ``outcome``, ``success``, ``fallback``, ``held_input``, ``window_at_bound`` and
        ``<name>_at_bound``.
    runs : pandas.DataFrame
        One row per (case, run, estimator): ``x0``, wall time, ``x_outside`` (samples where the true
        state left X), ``v_outside`` (samples where the noise left V; -1 for both where the run was not simulated),
        ``error`` (type and message if the estimator raised, else empty) and the step
        counts of :meth:`EstimationResult.counts` (``failures``, ``fallbacks``, ``at_bound``,
        ``at_bound_<state>``, ``held``, ``propagated``, ``on_boundary``, ``window_at_bound``; -1 when
        the estimator raised).
    truths : dict
        ``(case, run) -> Trajectory`` of the simulated truth.
    results : dict
        ``(case, run, estimator) -> EstimationResult``.
    model : StudyModel
        The model the study ran on (its system and default simulation, for the report).
    solver : str
        The window backend every estimator used (one of :data:`~uiest.window.backends.BACKENDS`).
    certificates : tuple of dict
        For each estimator with certificate weights: the certificate's rate, horizon, noise gain and
        coverage (:func:`uiest.experiments.certificates.summary`); the estimators' guarantees are in
        their results.

    """

    scenario: Scenario
    steps: pd.DataFrame
    runs: pd.DataFrame
    truths: dict[tuple[str, int], Trajectory]
    results: dict[tuple[str, int, str], EstimationResult]
    model: StudyModel
    solver: str = "ipopt"
    certificates: tuple[dict[str, object], ...] = ()


def initial_state(scenario: Scenario, default: FloatArray, run: int) -> FloatArray:
    """x0 of run ``run``: the nominal x0 for run 0, else uniform in ``[x0_lower, x0_upper]``."""
    nominal = np.asarray(scenario.x0 if scenario.x0 else default, dtype=float)
    if run == 0 or not scenario.x0_lower:
        return nominal
    rng = np.random.default_rng([scenario.seed, run, 17])
    return rng.uniform(np.asarray(scenario.x0_lower), np.asarray(scenario.x0_upper))


def prior_for(scenario: Scenario, system: System, y0: FloatArray) -> FloatArray:
    """The estimators' prior: ``scenario.prior`` with NaNs filled from ``y0`` (``prior_from_output``)."""
    prior = np.asarray(scenario.prior if scenario.prior else system.x.bounds.center, dtype=float).copy()
    if prior.shape != (system.nx,):
        raise OptionError(f"prior: expected {system.nx} values, got {prior.shape}")
    for state, output in scenario.prior_from_output:
        prior[state] = y0[output]
    if not np.all(np.isfinite(prior)):
        raise OptionError(f"prior: NaN entries not filled by prior_from_output: {prior.tolist()}")
    return prior


def noise_model(scenario: Scenario, noise: NoiseModel | None) -> NoiseModel | None:
    """The model's noise scaled by ``scenario.noise_scale``."""
    factor = scenario.noise_scale
    if noise is None or factor == 1.0:
        return noise
    if isinstance(noise, UniformNoise):
        return UniformNoise(
            np.asarray(noise.lower, dtype=float) * factor, np.asarray(noise.upper, dtype=float) * factor
        )
    if isinstance(noise, GaussianNoise):
        return GaussianNoise(np.asarray(noise.std, dtype=float) * factor, np.asarray(noise.mean, dtype=float) * factor)
    raise OptionError(f"noise_scale: cannot scale a {type(noise).__name__}")


def simulate_run(
    scenario: Scenario, case: str, run: int, study: StudyModel | None = None
) -> tuple[System, Trajectory, FloatArray]:
    """The system, the simulated truth and the estimators' prior of run ``run`` of ``case``.

    ``study``: the resolved model (default: ``scenario.model``'s, kept per process).
    Seeds depend only on (scenario.seed, run): the noise of run r is the same in every case and
    every design point of a sweep (common random numbers).
    """
    study = study_model(scenario.model) if study is None else study
    system, setup = study.system, study.setup
    x0 = initial_state(scenario, setup.x0, run)
    noise = noise_model(scenario, setup.noise) if case == "noisy" else None
    w = setup.w
    if scenario.w_gain != 1.0:
        law, gain = setup.w, scenario.w_gain
        w = (lambda k, x: gain * np.asarray(law(k, x), dtype=float)) if callable(law) else gain * np.asarray(law)
    truth = simulate(system, x0, scenario.steps, u=setup.u, w=w, v=noise, seed=scenario.seed + run)
    prior = prior_for(scenario, system, truth.y[0])
    if not np.isnan(scenario.initial_error):
        rng = np.random.default_rng([scenario.seed, run, 29])
        prior = x0 + scenario.initial_error * system.x.scale * rng.choice([-1.0, 1.0], size=system.nx)
        for state, output in scenario.prior_from_output:
            prior[state] = truth.y[0][output]
    return system, truth, prior


def run_study(
    scenario: Scenario,
    *,
    model: ModelEntry | StudyModel | None = None,
    solver: str = "ipopt",
    progress: Callable[[str], None] | None = None,
    workers: int | None = 1,
    store: Path | str | None = None,
) -> StudyResult:
    """Simulate every (case, run) and run every estimator on it, the runs spread over ``workers`` processes.

    ``model``: the model to study (a :class:`~uiest.models.ModelEntry` or a resolved
    :class:`StudyModel`); default: ``scenario.model``, a registered name or a model file. It is
    resolved once: its certificates and EKF/UKF tunings are computed here, once, and handed to
    the workers. ``workers``: 1 (default) runs in this process; None uses every core (``uiest
    reproduce`` does); a model given as an object, or registered at run time, runs in this process.
    Seeds depend only on (case, run), so the numbers do not depend on the number of workers (the
    timings do, through the load).
    ``progress(label)`` is called for each estimator run as its (case, run) completes.
    ``store``: a folder (:mod:`uiest.experiments.study_store`) where each (case, run) is written as it
    completes and from which a later call with the same study reads it back instead of computing it, so
    an interrupted or killed study resumes; runs read back are not reported to ``progress``. It needs the
    model by name or file (``scenario.model``), not as an object: the model file's bytes key the runs.
    """
    import pandas as pd

    if not isinstance(scenario, Scenario):
        raise OptionError(f"scenario: expected a Scenario, got {shown(scenario)}")
    if solver not in BACKENDS:
        raise OptionError(f"solver: expected one of {list(BACKENDS)}, got {solver!r}")
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, numbers.Integral) or workers < 1):
        raise OptionError(f"workers: expected an integer >= 1 or None (all cores), got {shown(workers)}")
    check_callable(progress, "progress")
    for spec in scenario.estimators:
        if spec.kind not in BUILDERS:
            raise OptionError(f"estimators: kind {spec.kind!r} is not available; available: {sorted(BUILDERS)}")
    if model is not None and not isinstance(model, ModelEntry | StudyModel):
        raise OptionError(f"model: expected a ModelEntry or a StudyModel (a name: scenario.model), got {model!r}")
    given = model is not None
    saved = None
    if store is not None:
        if given:
            raise OptionError("store: runs are stored only for scenario.model (a name or a model file), not for a "
                              "model given as an object (its content cannot key the stored runs)")  # fmt: skip
        saved = StudyStore(Path(store), scenario, solver)
        saved.prepare()
    study = model if isinstance(model, StudyModel) else StudyModel.of(scenario.model if model is None else model)
    system = study.system
    scenario.check_model(system.nx, system.ny, system.x.bounds)
    study.prepare(scenario.estimators)
    certificates = []
    for spec in scenario.estimators:
        if spec.weights == "certificate":
            try:
                certificates.append(summary(spec, study.certificate(spec.kind, spec.mu, spec.w_variance)))
            except UiestError as exc:  # the estimator's runs record the same error; the study goes on
                certificates.append(summary(spec, None, f"{type(exc).__name__}: {exc}"))
    step_frames, run_rows = [], []
    truths: dict[tuple[str, int], Trajectory] = {}
    results: dict[tuple[str, int, str], EstimationResult] = {}
    tasks = [(case, run) for case in scenario.cases for run in range(scenario.runs)]
    loaded = {task: saved.load(*task, expected=RunOutcome) for task in tasks} if saved is not None else {}
    kept = {task: outcome for task, outcome in loaded.items() if outcome is not None}

    def add(outcome: RunOutcome) -> None:
        if outcome.truth is not None:
            truths[(outcome.case, outcome.run)] = outcome.truth
        for name, result in outcome.results.items():
            results[(outcome.case, outcome.run, name)] = result
        step_frames.extend(outcome.frames)
        run_rows.extend(outcome.rows)

    for outcome in kept.values():
        add(outcome)
    todo = [task for task in tasks if task not in kept]
    with contextlib.closing(_outcomes(scenario, study, given, todo, solver, workers)) as outcomes:
        for outcome in outcomes:
            if saved is not None:
                saved.save(outcome.case, outcome.run, outcome)
            add(outcome)
            if progress is not None:
                for spec in scenario.estimators:
                    progress(f"{outcome.case} run {outcome.run + 1}/{scenario.runs}: {spec.name}")
    run_rows.sort(key=lambda row: (scenario.cases.index(row["case"]), row["run"]))
    step_frames.sort(key=lambda frame: (scenario.cases.index(frame["case"].iat[0]), int(frame["run"].iat[0])))
    steps = pd.concat(step_frames, ignore_index=True) if step_frames else pd.DataFrame()
    return StudyResult(
        scenario=scenario,
        steps=steps,
        runs=pd.DataFrame(run_rows),
        truths=truths,
        results=results,
        model=study,
        solver=solver,
        certificates=tuple(certificates),
    )


@dataclass(frozen=True, eq=False, kw_only=True)
class RunOutcome:
    """What one (case, run) of a study produces: the truth, each estimator's result, step frames and run rows.

    ``truth`` is None where the simulation itself failed (the rows then carry its error for every estimator).
    """

    case: str
    run: int
    truth: Trajectory | None
    results: dict[str, EstimationResult]
    frames: list[pd.DataFrame]
    rows: list[dict[str, Any]]


def run_case(
    scenario: Scenario, case: str, run: int, solver: str, study: StudyModel | dict[tuple[Any, ...], Any]
) -> RunOutcome:
    """Simulate run ``run`` of ``case`` and run every estimator on it (each one's exception recorded).

    ``study``: the resolved model, or (in a worker) what the parent computed for
    ``scenario.model`` (:meth:`StudyModel.resolved`).
    """
    if not isinstance(study, StudyModel):
        study = study_model(scenario.model, study)
    try:
        _, truth, prior = simulate_run(scenario, case, run, study)
    except Exception as exc:  # a run whose simulation fails (the model not finite there): recorded, the study goes on
        return _failed_simulation(scenario, case, run, study, f"simulation: {type(exc).__name__}: {exc}")
    results, frames, rows = {}, [], []
    for spec in scenario.estimators:
        start = time.perf_counter()
        error = ""
        try:
            estimator = BUILDERS[spec.kind](study, spec, prior, solver)
            with quiet_bound_warnings():  # counted in the run's row and reported
                result = estimator.run(truth.u, truth.y)
        except Exception as exc:  # recorded, whatever it is; the study goes on
            error = f"{type(exc).__name__}: {exc}"
            result = None
        wall = time.perf_counter() - start
        if result is not None:
            results[spec.name] = result
            frames.append(_step_frame(case, run, spec.name, truth, result))
        x_names = truth.names.get("x") or tuple(f"x[{i}]" for i in range(truth.x.shape[1]))
        counts = result.counts() if result is not None else dict.fromkeys(count_names(x_names), -1)
        rows.append({"case": case, "run": run, "estimator": spec.name, "x0": list(map(float, truth.x[0])),
                     "wall_time_s": wall, "x_outside": int(truth.x_outside.sum()),
                     "v_outside": int(truth.v_outside.sum()), "error": error, **counts})  # fmt: skip
    return RunOutcome(case=case, run=run, truth=truth, results=results, frames=frames, rows=rows)


def _failed_simulation(scenario: Scenario, case: str, run: int, study: StudyModel, error: str) -> RunOutcome:
    """The outcome of a run whose simulation failed: every estimator's row carries ``error``, counts -1."""
    names = study.system.x.names
    rows = [{"case": case, "run": run, "estimator": spec.name, "x0": [float("nan")] * len(names), "wall_time_s": 0.0,
             "x_outside": -1, "v_outside": -1, "error": error, **dict.fromkeys(count_names(names), -1)}
            for spec in scenario.estimators]  # fmt: skip
    return RunOutcome(case=case, run=run, truth=None, results={}, frames=[], rows=rows)


def _outcomes(
    scenario: Scenario, study: StudyModel, given: bool, tasks: list[tuple[str, int]], solver: str, workers: int | None
) -> Generator[RunOutcome, None, None]:
    """Each (case, run)'s outcome as it completes: in this process, or in a pool of ``workers`` processes.

    Spawned workers load built-in models and model files by name, with the certificates and
    tunings computed here; a model given as an object or registered at run time runs here. The
    pool is shut down when the generator ends or is closed; a pool that breaks (a worker killed)
    is abandoned and the remaining runs go on in this process.
    """
    width = min(len(tasks), os.cpu_count() or 1) if workers is None else min(workers, len(tasks))
    if width <= 1 or given or not models.loadable_elsewhere(scenario.model):
        for case, run in tasks:
            yield run_case(scenario, case, run, solver, study)
        return
    done: set[tuple[str, int]] = set()
    with executors.single_threaded_children():
        pool = executors.spawn_pool(width)
    broken = finished = False
    try:
        known = study.resolved()
        futures = [pool.submit(run_case, scenario, case, run, solver, known) for case, run in tasks]
        for future in as_completed(futures):
            outcome = future.result()
            done.add((outcome.case, outcome.run))
            yield outcome
        finished = True
    except BrokenProcessPool:
        broken = True
    finally:  # also when the consumer stops early: the workers end now
        executors.stop_pool(pool, abandon=not finished)
    if broken:
        for case, run in tasks:
            if (case, run) not in done:
                yield run_case(scenario, case, run, solver, study)


def _step_frame(case: str, run: int, name: str, truth: Trajectory, result: EstimationResult) -> pd.DataFrame:
    import pandas as pd

    x_names = truth.names.get("x") or tuple(f"x[{i}]" for i in range(truth.x.shape[1]))
    w_names = truth.names.get("w") or tuple(f"w[{i}]" for i in range(truth.w.shape[1]))
    data: dict[str, object] = {"case": case, "run": run, "estimator": name, "k": np.arange(truth.x.shape[0]),
                               "t": truth.t}  # fmt: skip
    for i, label in enumerate(x_names):
        data[label] = truth.x[:, i]
        data[f"{label}_hat"] = result.x_hat[:, i]
    for i, label in enumerate(w_names):
        data[label] = np.append(truth.w[:, i], np.nan)
        data[f"{label}_hat"] = np.append(result.w_hat[:, i], np.nan)
    data["solve_time"] = result.solve_time
    data["cpu_time"] = result.cpu_time
    data["status"] = result.status
    data["outcome"] = result.outcome
    data["success"] = result.success
    data["fallback"] = result.fallback
    data["held_input"] = result.held_input
    data["window_at_bound"] = result.window_at_bound
    for i, label in enumerate(x_names):
        data[f"{label}_at_bound"] = result.at_bound[:, i]
    return pd.DataFrame(data)
