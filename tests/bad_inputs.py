"""Bad inputs a new user would try, each with what uiest must do (shared by a test and bench/bad_inputs.py).

A case either expects a typed error (a :class:`~uiest.errors.UiestError` subclass whose message
matches) or a recorded outcome (a predicate on what the call returned). :func:`classify` sorts an
outcome into "good" (the typed error), "handled" (recorded as expected), "traceback" (any other
exception) or "silent" (returned without the error, or with the wrong record).
"""

from __future__ import annotations

import functools
import math
import re
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import casadi as ca
import numpy as np

from uiest import DataError, GaussianNoise, ModelError, OptionError, System, Trajectory, UniformNoise, simulate
from uiest.analysis import analyse
from uiest.detectability import (
    certify_delta_ioss,
    certify_reduced_ioss,
    certify_reduced_model,
    certify_strong_detectability,
    linear_strong_detectability,
    window_information,
)
from uiest.errors import CertificationError, UiestError
from uiest.estimators import (
    EKF,
    FIE,
    UISE,
    LinearUIO,
    MHEWeights,
    Outcome,
    SmoothInputMHE,
    StandardMHE,
    TwoStageUISE,
    TwoStageWeights,
    UISEWeights,
)
from uiest.experiments import EstimatorSpec, Scenario, run_study, write_report
from uiest.experiments.solver_bench import bench_window_solvers
from uiest.experiments.sweep import Sweep, sweep
from uiest.models import closed_form, linear
from uiest.plotting import plot_estimates, plot_trajectory, save_figure
from uiest.results import read_record

UNWRITABLE = Path("/proc/uiest-cannot-write-here")


@dataclass(frozen=True)
class Case:
    """One bad input: ``call()`` must raise ``error`` matching ``match``, or return ``ok(result)`` true."""

    name: str
    call: Callable[[], Any]
    error: type[UiestError] | None = None
    match: str = ""
    ok: Callable[[Any], bool] | None = None


def classify(case: Case) -> tuple[str, str]:
    """("good" | "handled" | "traceback" | "silent", detail)."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            result = case.call()
    except UiestError as exc:
        if case.error is not None and isinstance(exc, case.error) and re.search(case.match, str(exc)):
            return "good", f"{type(exc).__name__}: {exc}"
        return "traceback", f"unexpected {type(exc).__name__}: {exc}"
    except Exception as exc:
        return "traceback", f"{type(exc).__name__}: {exc}"
    if case.error is not None:
        return "silent", f"returned {type(result).__name__} instead of raising {case.error.__name__}"
    if case.ok is not None and case.ok(result):
        return "handled", "recorded"
    return "silent", f"returned {result!r:.200}"


# ------------------------------------------------------------------------------------------------ fixtures
@functools.cache
def system() -> System:
    return closed_form.system()


@functools.cache
def trajectory() -> Any:
    return simulate(system(), [0.5, 1.0], 8, u=np.zeros((8, 1)), w=np.zeros((8, 1)))


@functools.cache
def weights() -> UISEWeights:
    return UISEWeights.from_scales(system(), 0.64, output=1e4)


def two_stage(**kwargs: Any) -> TwoStageUISE:
    reduced = closed_form.reduction()
    return TwoStageUISE(reduced, **{"weights": TwoStageWeights.from_scales(reduced, 0.5), "N": 3, **kwargs})


def uise(**kwargs: Any) -> UISE:
    return UISE(system(), **{"weights": weights(), "N": 3, "x0_prior": [0.5, 1.0], **kwargs})


@functools.cache
def linear_case() -> tuple[System, np.ndarray, np.ndarray, np.ndarray]:
    return linear.with_invariant_zeros([0.5, 0.2], seed=3, x_bounds=(-10, 10), v_bounds=(-1e-3, 1e-3))


def scenario(**changes: Any) -> Scenario:
    base = {
        "name": "tiny",
        "model": "closed-form",
        "steps": 8,
        "runs": 1,
        "cases": ("noisy",),
        "prior": (math.nan, 0.0),
        "prior_from_output": ((0, 0),),
        "settle": 2,
        "focus_state": 1,
        "estimators": (EstimatorSpec("UISE", "uise", N=3, mu=0.64, output_weight=1e4),),
    }
    return Scenario(**{**base, **changes})


def callables(**changes: Any) -> System:
    spec = {"nx": 2, "nw": 1, "nv": 1, "x_bounds": (-1.0, 1.0), **changes}
    f = spec.pop("f", lambda x, u, w: [0.5 * x[0] + w[0], 0.5 * x[1]])
    h = spec.pop("h", lambda x, v: [x[0] + v[0]])
    return System.from_callables(f, h, **spec)


def raises_inside(*_: Any, **__: Any) -> Any:
    raise ZeroDivisionError("injected")


def flaky_uise() -> Any:
    est = uise()
    original = est._solve_window
    calls = {"n": 0}

    def flaky(*args: Any, **kwargs: Any) -> Any:
        calls["n"] += 1
        return raises_inside() if calls["n"] == 3 else original(*args, **kwargs)

    est._solve_window = flaky  # type: ignore[method-assign]
    return est.run(trajectory().u, trajectory().y)


def _sweep_file(tmp: Path, grid: str, extra: str = "") -> Path:
    text = (
        "[scenario]\nname = 'x'\nmodel = 'closed-form'\nsteps = 8\nruns = 1\ncases = ['noisy']\nsettle = 2\n"
        "[[scenario.estimators]]\nname = 'UISE'\nkind = 'uise'\nN = 3\nmu = 0.64\n"
        f"[sweep]\n{grid}\n{extra}"
    )
    path = tmp / f"sweep-{abs(hash(grid + extra))}.toml"
    path.write_text(text)
    return path


def _tiny_sweep() -> Sweep:
    return Sweep(scenario(), grid={"N": (2, 3)})


# ------------------------------------------------------------------------------------------------ API cases
def api_cases(tmp: Path) -> list[Case]:
    s, traj = system, trajectory
    X = "x_bounds"
    cases = [
        # systems
        Case("nx = 0", lambda: callables(nx=0), ModelError, "nx"),
        Case("nx = -1", lambda: callables(nx=-1), ModelError, "nx"),
        Case("nx = 1.5", lambda: callables(nx=1.5), ModelError, "nx"),
        Case("nw a string", lambda: callables(nw="a"), ModelError, "nw"),
        Case("f of the wrong length", lambda: callables(f=lambda x, u, w: [x[0]]), ModelError, "f"),
        Case("math.sin in f", lambda: callables(f=lambda x, u, w: [math.sin(x[0]) + w[0], x[1]]), ModelError, "math"),
        Case("h returns a matrix", lambda: callables(h=lambda x, v: ca.SX.zeros(2, 2)), ModelError, "h"),
        Case("X lower > upper", lambda: callables(**{X: (1.0, -1.0)}), ModelError, "x_bounds"),
        Case("X of the wrong length", lambda: callables(**{X: ((0, 0, 0), (1, 1, 1))}), ModelError, "x_bounds"),
        Case("X with NaN", lambda: callables(**{X: (math.nan, 1.0)}), ModelError, "NaN"),
        Case("V of the wrong length", lambda: callables(v_bounds=((0, 0), (1, 1))), ModelError, "v_bounds"),
        Case("negative x_scale", lambda: callables(x_scale=-1.0), ModelError, "x_scale"),
        Case("zero x_scale", lambda: callables(x_scale=0.0), ModelError, "x_scale"),
        Case("wrong number of names", lambda: callables(x_names=("a",)), ModelError, "names"),
        Case("a name used twice", lambda: callables(x_names=("a", "y[0]")), ModelError, "unique"),
        Case("dt = 0", lambda: callables(dt=0.0), ModelError, "dt"),
        Case("dt < 0", lambda: callables(dt=-1.0), ModelError, "dt"),
        Case("dt = NaN", lambda: callables(dt=math.nan), ModelError, "dt"),
        Case(
            "f not finite at the centre",
            lambda: callables(f=lambda x, u, w: [np.log(x[0]) + w[0], x[1]]),
            ModelError,
            "not finite",
        ),
        Case("from_functions: not a Function", lambda: System.from_functions("f", "h"), ModelError, "f"),
        Case("from_functions: wrong inputs", lambda: System.from_functions(s().h, s().h), ModelError, "f"),
        Case("w_range of the wrong size", lambda: callables(w_range=((0, 0), (1, 1))), ModelError, "w_range"),
        Case(
            "from_ode: substeps 0",
            lambda: System.from_ode(
                lambda x, u, w: [w[0] - x[0]], lambda x, v: [x[0]], nx=1, nw=1, nv=1, dt=0.1, substeps=0
            ),
            OptionError,
            "substeps",
        ),
        Case(
            "from_ode: unknown input channel",
            lambda: System.from_ode(
                lambda x, u, w: [w[0] - x[0]], lambda x, v: [x[0]], nx=1, nw=1, nv=1, dt=0.1, input_channel="euler"
            ),
            OptionError,
            "input_channel",
        ),
        Case(
            "from_ode: dt < 0",
            lambda: System.from_ode(lambda x, u, w: [w[0] - x[0]], lambda x, v: [x[0]], nx=1, nw=1, nv=1, dt=-0.1),
            ModelError,
            "dt",
        ),
        Case(
            "from_ode: nx = 0",
            lambda: System.from_ode(lambda x, u, w: [], lambda x, v: [v[0]], nx=0, nw=1, nv=1, dt=0.1),
            ModelError,
            "nx",
        ),
        Case(
            "linear: A not square", lambda: linear.linear_system(np.ones((2, 3)), [[1], [0]], [[1, 0]]), ModelError, "A"
        ),
        Case(
            "linear: B of the wrong rows",
            lambda: linear.linear_system(np.eye(2), [[1], [0], [0]], [[1, 0]]),
            ModelError,
            "B",
        ),
        Case(
            "linear: C of the wrong columns",
            lambda: linear.linear_system(np.eye(2), [[1], [0]], [[1, 0, 0]]),
            ModelError,
            "C",
        ),
        Case(
            "linear: NaN in A",
            lambda: linear.linear_system([[math.nan, 0], [0, 1]], [[1], [0]], [[1, 0]]),
            ModelError,
            "A",
        ),
        # simulate
        Case("steps = -1", lambda: simulate(s(), [0, 0], -1, u=[0.0]), DataError, "steps"),
        Case("steps = 1.5", lambda: simulate(s(), [0, 0], 1.5, u=[0.0]), DataError, "steps"),
        Case("steps = True", lambda: simulate(s(), [0, 0], True, u=[0.0]), DataError, "steps"),
        Case("x0 of the wrong length", lambda: simulate(s(), [0, 0, 0], 3, u=[0.0]), DataError, "x0"),
        Case("x0 NaN", lambda: simulate(s(), [math.nan, 0], 3, u=[0.0]), DataError, "x0"),
        Case("x0 outside X", lambda: simulate(s(), [50.0, 0], 3, u=[0.0]), DataError, "x0"),
        Case("u of the wrong shape", lambda: simulate(s(), [0, 0], 3, u=np.zeros((2, 1))), DataError, "u"),
        Case("u NaN", lambda: simulate(s(), [0, 0], 3, u=[math.nan]), DataError, "u"),
        Case("w of the wrong shape", lambda: simulate(s(), [0, 0], 3, u=[0.0], w=np.zeros((3, 2))), DataError, "w"),
        Case(
            "w callable of the wrong size",
            lambda: simulate(s(), [0, 0], 3, u=[0.0], w=lambda k, x: [1, 2]),
            DataError,
            "w",
        ),
        Case("w NaN", lambda: simulate(s(), [0, 0], 3, u=[0.0], w=[math.nan]), DataError, "w"),
        Case("v of the wrong shape", lambda: simulate(s(), [0, 0], 3, u=[0.0], v=np.zeros((3, 1))), DataError, "v"),
        Case("v with inf", lambda: simulate(s(), [0, 0], 3, u=[0.0], v=np.full((4, 1), np.inf)), DataError, "v"),
        Case("seed = -1", lambda: simulate(s(), [0, 0], 3, u=[0.0], seed=-1), DataError, "seed"),
        Case("seed = 1.5", lambda: simulate(s(), [0, 0], 3, u=[0.0], seed=1.5), DataError, "seed"),
        Case("seed a string", lambda: simulate(s(), [0, 0], 3, u=[0.0], seed="1"), DataError, "seed"),
        Case("system not a System", lambda: simulate("crop", [0, 0], 3), DataError, "system"),
        Case("u required", lambda: simulate(callables(nu=1, u_bounds=(0, 1)), [0, 0], 3), DataError, "u"),
        Case(
            "f overflows",
            lambda: simulate(callables(f=lambda x, u, w: [np.exp(x[0]) * 1e300 + w[0], x[1]]), [0.5, 0], 3),
            ModelError,
            "non-finite",
        ),
        Case(
            "the state leaves X",
            lambda: simulate(s(), [0, 0], 20, u=[0.0], w=[3.0]),
            ok=lambda t: bool(t.x_outside.any()),
        ),
        Case(
            "the noise leaves V",
            lambda: simulate(s(), [0, 0], 5, u=[0.0], v=UniformNoise.symmetric(1.0)),
            ok=lambda t: bool(t.v_outside.any()),
        ),
        # estimators
        Case("N = 0", lambda: uise(N=0), OptionError, "N"),
        Case("N = -3", lambda: uise(N=-3), OptionError, "N"),
        Case("N = 2.5", lambda: uise(N=2.5), OptionError, "N"),
        Case("N = True", lambda: uise(N=True), OptionError, "N"),
        Case(
            "weights and certificate",
            lambda: UISE(s(), weights=weights(), certificate=weights(), N=3),
            OptionError,
            "exactly one",
        ),
        Case("neither weights nor certificate", lambda: UISE(s(), N=3), OptionError, "exactly one"),
        Case("explicit weights without N", lambda: UISE(s(), weights=weights()), OptionError, "N"),
        Case(
            "weights.P of the wrong shape",
            lambda: UISE(s(), weights=UISEWeights(0.5, np.eye(3), [[1.0]], [[1.0]]), N=3),
            OptionError,
            r"weights\.P",
        ),
        Case("weights.mu = 1", lambda: UISEWeights(1.0, np.eye(2), [[1.0]], [[1.0]]), OptionError, "mu"),
        Case("weights.mu < 0", lambda: UISEWeights(-0.1, np.eye(2), [[1.0]], [[1.0]]), OptionError, "mu"),
        Case("weights.R_y negative", lambda: UISEWeights(0.5, np.eye(2), [[-1.0]], [[1.0]]), OptionError, "R_y"),
        Case("weights.P not symmetric", lambda: UISEWeights(0.5, [[1, 2], [0, 1]], [[1.0]], [[1.0]]), OptionError, "P"),
        Case("solver newton", lambda: uise(solver="newton"), OptionError, "solver"),
        Case("solver_options not a mapping", lambda: uise(solver_options=[1]), OptionError, "solver_options"),
        Case("x0_prior of the wrong length", lambda: uise(x0_prior=[0.0]), DataError, "x0_prior"),
        Case("x0_prior outside X", lambda: uise(x0_prior=[50.0, 0.0]), DataError, "x0_prior"),
        Case("x0_prior NaN", lambda: uise(x0_prior=[math.nan, 0.0]), DataError, "x0_prior"),
        Case("v_prior outside V", lambda: uise(v_prior=[1.0]), DataError, "v_prior"),
        Case("step without a prior", lambda: uise(x0_prior=None).step(None, [0.0]), OptionError, "x0_prior"),
        Case("y of the wrong shape", lambda: uise().run(traj().u, np.zeros((9, 2))), DataError, "y"),
        Case("y 1-D", lambda: uise().run(traj().u, np.zeros(9)), DataError, "y"),
        Case("y with inf", lambda: uise().run(traj().u, np.full((9, 1), np.inf)), DataError, "y"),
        Case("u, y lengths", lambda: uise().run(np.zeros((3, 1)), traj().y), DataError, "length"),
        Case("u NaN in a run", lambda: uise().run(np.full((8, 1), np.nan), traj().y), DataError, "u"),
        Case("u missing in a run", lambda: uise().run(None, traj().y), DataError, "u"),
        Case("u_prev at k = 0", lambda: uise().step([1.0], [0.0]), DataError, "u_prev"),
        Case("y of the wrong length in a step", lambda: uise().step(None, [0.0, 1.0]), DataError, "y"),
        Case("y a string", lambda: uise().step(None, "abc"), DataError, "y"),
        Case(
            "an unproven certificate",
            lambda: UISE(
                s(),
                certificate=certify_strong_detectability(
                    linear.with_invariant_zeros([1.5], seed=3, x_bounds=(-10, 10), v_bounds=(-1e-3, 1e-3))[0]
                ),
            ),
            CertificationError,
            "not certified",
        ),
        Case(
            "a certificate of another kind", lambda: UISE(s(), certificate=weights(), N=3), OptionError, "certificate"
        ),
        Case(
            "a long outage",
            lambda: uise().run(traj().u, np.vstack([traj().y[:2], np.full((7, 1), np.nan)])),
            ok=lambda r: Outcome.PROPAGATED in set(r.outcome) and r.propagated_steps > 0,
        ),
        Case(
            "y[0] missing",
            lambda: uise().run(traj().u, np.vstack([[[np.nan]], traj().y[1:]])),
            ok=lambda r: r.outcome[0] == Outcome.PROPAGATED and np.isfinite(r.x_hat).all(),
        ),
        Case(
            "an exception inside a solve",
            flaky_uise,
            ok=lambda r: (
                "ZeroDivisionError: injected" in set(r.reason[r.outcome == Outcome.ERROR])
                and np.isfinite(r.x_hat).all()
            ),
        ),
        Case(
            "an estimate held on the boundary of X",
            lambda: uise().run(np.zeros((30, 1)), simulate(s(), [0, 0.5], 30, u=[0.0], w=[1.0]).y),
            ok=lambda r: r.on_boundary.any() and r.at_bound.any(),
        ),
        Case(
            "standard MHE: w_prior outside its range",
            lambda: StandardMHE(
                callables(w_range=(-1, 1)), weights=MHEWeights(0.5, np.eye(2), [[1]], [[1]], [[1]]), N=3, w_prior=[5.0]
            ),
            DataError,
            "w_prior",
        ),
        Case(
            "smooth-input MHE without a bound or variance of the increments",
            lambda: SmoothInputMHE(s(), weights=MHEWeights(0.5, np.eye(3), [[1]], [[1]], [[1]]), N=3),
            OptionError,
            "dw_bound, dw_variance",
        ),
        Case(
            "smooth-input MHE: a negative increment variance",
            lambda: SmoothInputMHE.design(s(), dw_variance=-0.1),
            OptionError,
            "dw_variance",
        ),
        Case(
            "smooth-input MHE with the certificate of the model itself",
            lambda: SmoothInputMHE(s(), certificate=certify_delta_ioss(s(), w_bounds=(-1, 1))),
            OptionError,
            "augmented_system",
        ),
        Case(
            "FIE beyond max_steps",
            lambda: FIE(s(), weights=weights(), x0_prior=[0.5, 1.0], max_steps=5).run(traj().u, traj().y),
            OptionError,
            "max_steps",
        ),
        Case("FIE max_steps = 0", lambda: FIE(s(), weights=weights(), max_steps=0), OptionError, "max_steps"),
        Case(
            "two-stage without weights or certificate",
            lambda: TwoStageUISE(closed_form.reduction(), weights=None, certificate=None, N=3),
            OptionError,
            "exactly one",
        ),
        Case("two-stage N = 0", lambda: two_stage(N=0), OptionError, "N: expected an integer >= 1"),
        Case("two-stage N = 2.5", lambda: two_stage(N=2.5), OptionError, "N: expected an integer >= 1"),
        Case(
            "FIE: ragged y",
            lambda: FIE(s(), weights=weights(), x0_prior=[0.5, 1.0]).run(np.zeros((2, 1)), [[0.1], [0.2, 0.3]]),
            DataError,
            "y",
        ),
        Case("skip without a prior", lambda: uise(x0_prior=None).skip(None, [0.0], "r"), OptionError, "x0_prior"),
        Case("step with y = None", lambda: uise().step(None, None), DataError, "y"),
        Case(
            "a record without any measurement",
            lambda: uise().run(np.zeros((9, 1)), np.full((9, 1), np.nan)),
            DataError,
            "every measurement is missing",
        ),
        Case(
            "a solver_options typo raises from run",
            lambda: uise(solver_options={"max_iterr": 5}).run(traj().u, traj().y),
            OptionError,
            "max_iterr",
        ),
        Case(
            "an IPOPT option of the wrong type raises from run",
            lambda: uise(solver="ipopt", solver_options={"max_iter": "abc"}).run(traj().u, traj().y),
            OptionError,
            "solver_options",
        ),
        Case("linear UIO on a nonlinear system", lambda: LinearUIO(s()), ModelError, "linear"),
        Case(
            "linear UIO: poles of the wrong count",
            lambda: LinearUIO(linear_case()[0], poles=[0.1]),
            OptionError,
            "poles",
        ),
        Case(
            "linear UIO: gain of the wrong shape",
            lambda: LinearUIO(linear_case()[0], gain=np.eye(2)),
            OptionError,
            "gain",
        ),
        Case(
            "linear UIO: poles and gain",
            lambda: LinearUIO(linear_case()[0], poles=[0.1] * 3, gain=np.zeros((3, 1))),
            OptionError,
            "poles",
        ),
        Case(
            "from_scales: prior of the wrong length",
            lambda: UISEWeights.from_scales(s(), 0.5, prior=[1, 2, 3]),
            OptionError,
            "prior",
        ),
        Case(
            "from_scales: negative disturbance",
            lambda: MHEWeights.from_scales(s(), 0.5, disturbance=-1.0),
            OptionError,
            "disturbance",
        ),
        Case(
            "from_variances: a zero variance",
            lambda: MHEWeights.from_variances(s(), 0.5, w_variance=0.0),
            OptionError,
            "w_variance: expected a positive definite",
        ),
        Case(
            "EKF.fit: a negative variance on the grid",
            lambda: EKF.fit(s(), trajectory().u, trajectory().y, x0_prior=[0.5, 1.0], variances=[1e-3, -1.0]),
            OptionError,
            "variances",
        ),
        Case(
            "EKF.fit: y of the wrong shape",
            lambda: EKF.fit(s(), trajectory().u, trajectory().y[:, :0], x0_prior=[0.5, 1.0]),
            DataError,
            "y",
        ),
        # certificates
        Case("certify: mu = 1.5", lambda: certify_strong_detectability(s(), 1.5), OptionError, "mu"),
        Case("certify: mu = 0", lambda: certify_strong_detectability(s(), 0.0), OptionError, "mu"),
        Case("certify: mu a string", lambda: certify_strong_detectability(s(), "a"), OptionError, "mu"),
        Case("certify: samples = 2", lambda: certify_strong_detectability(s(), samples=2), OptionError, "samples"),
        Case(
            "certify: samples = True", lambda: certify_strong_detectability(s(), samples=True), OptionError, "samples"
        ),
        Case("certify: tol = 0", lambda: certify_strong_detectability(s(), tol=0), OptionError, "tol"),
        Case(
            "certify: unbounded X",
            lambda: certify_strong_detectability(linear.linear_system(0.5 * np.eye(2), [[1], [0]], [[1, 0]])),
            ModelError,
            "bounded",
        ),
        Case(
            "certify: a nonlinear output",
            lambda: certify_strong_detectability(callables(h=lambda x, v: [x[0] ** 2 + v[0]])),
            ModelError,
            "affine",
        ),
        Case(
            "certify: matching fails",
            lambda: certify_strong_detectability(
                linear.linear_system([[0.5, 1], [0, 0.3]], [[0], [1]], [[1, 0]], x_bounds=(-1, 1))
            ),
            ModelError,
            r"rank\(C B\)",
        ),
        Case(
            "certify: parameters not affine",
            lambda: certify_strong_detectability(s(), parameters=lambda x, u: [np.tanh(x[0])]),
            ModelError,
            "affine",
        ),
        Case(
            "certify: no parameters",
            lambda: certify_strong_detectability(s(), parameters=lambda x, u: []),
            ModelError,
            "parameters",
        ),
        Case(
            "certify: parameters that fail",
            lambda: certify_strong_detectability(s(), parameters=lambda x, u: [math.tanh(x[0])]),
            ModelError,
            "parameters",
        ),
        Case(
            "certify: an unknown cover",
            lambda: certify_strong_detectability(s(), cover="fitted"),
            OptionError,
            "cover: expected one of",
        ),
        Case(
            "certify: parameters the expressions do not carry",
            lambda: certify_strong_detectability(
                s(), parameters=lambda x, u: [x[1] / np.cosh(x[0]) ** 2, np.tanh(x[0])]
            ),
            ModelError,
            "not exact combinations",
        ),
        Case("delta-IOSS: a cover by fitting", lambda: certify_delta_ioss(s(), cover="fit"), OptionError, "cover"),
        Case("delta-IOSS: gird = 2", lambda: certify_delta_ioss(s(), gird=2), OptionError, "gird"),
        Case(
            "delta-IOSS: structure diagonal",
            lambda: certify_delta_ioss(s(), structure="diagonal"),
            OptionError,
            "structure",
        ),
        Case(
            "delta-IOSS: unbounded w",
            lambda: certify_delta_ioss(s(), w_bounds=(-np.inf, np.inf)),
            ModelError,
            "w_bounds",
        ),
        Case(
            "reduced: f_sharp not a Function",
            lambda: certify_reduced_ioss("f", "h", z_bounds=(0, 1), gamma_bounds=(0, 1), v_bounds=(0, 1)),
            ModelError,
            "f_sharp",
        ),
        Case(
            "reduced: unknown option",
            lambda: certify_reduced_model(closed_form.reduction(), grid=3),
            OptionError,
            "grid",
        ),
        Case("reduced: mu = 2", lambda: certify_reduced_model(closed_form.reduction(), mu=2.0), OptionError, "mu"),
        Case(
            "Hautus: rtol = 0",
            lambda: linear_strong_detectability(np.eye(2), [[1], [0]], [[1, 0]], rtol=0),
            OptionError,
            "rtol",
        ),
        Case(
            "Hautus: A not square",
            lambda: linear_strong_detectability(np.ones((2, 3)), [[1], [0]], [[1, 0]]),
            ModelError,
            "A",
        ),
        Case(
            "Hautus: complex A",
            lambda: linear_strong_detectability(1j * np.eye(2), [[1], [0]], [[1, 0]]),
            ModelError,
            "A",
        ),
        Case("verify(0)", lambda: linear_strong_detectability(*linear_case()[1:]).verify(0), OptionError, "n_pairs"),
        Case(
            "verify(1.5)", lambda: linear_strong_detectability(*linear_case()[1:]).verify(1.5), OptionError, "n_pairs"
        ),
        Case(
            "min_horizon of an unproven certificate",
            lambda: linear_strong_detectability(np.eye(2) * 1.5, [[1], [0]], [[1, 0]]).min_horizon(),
            CertificationError,
            "does not hold",
        ),
        Case(
            "weights of an unproven certificate",
            lambda: UISEWeights.from_certificate(linear_strong_detectability(np.eye(2) * 1.5, [[1], [0]], [[1, 0]])),
            CertificationError,
            "not certified",
        ),
        Case(
            "a zero outside the unit disk",
            lambda: certify_strong_detectability(
                linear.with_invariant_zeros([1.5], seed=3, x_bounds=(-10, 10), v_bounds=(-1e-3, 1e-3))[0]
            ),
            ok=lambda c: c.status == "infeasible" and not c.certified,
        ),
        # scenarios
        Case("runs = 0", lambda: scenario(runs=0), OptionError, "runs"),
        Case("steps = 1.5", lambda: scenario(steps=1.5), OptionError, "steps"),
        Case("seed = 1.5", lambda: scenario(seed=1.5), OptionError, "seed"),
        Case("seed = -1", lambda: scenario(seed=-1), OptionError, "seed"),
        Case("an unknown case", lambda: scenario(cases=("windy",)), OptionError, "cases"),
        Case(
            "x0_lower > x0_upper", lambda: scenario(x0_lower=(1.0, 1.0), x0_upper=(0.0, 0.0)), OptionError, "x0_lower"
        ),
        Case("focus_state = -1", lambda: scenario(focus_state=-1), OptionError, "focus_state"),
        Case("focus_state out of range", lambda: run_study(scenario(focus_state=5)), OptionError, "focus_state"),
        Case(
            "prior_from_output out of range",
            lambda: run_study(scenario(prior_from_output=((0, 3),))),
            OptionError,
            "prior_from_output",
        ),
        Case("prior of the wrong length", lambda: run_study(scenario(prior=(0.0,))), OptionError, "prior"),
        Case("settle >= steps", lambda: scenario(settle=8), OptionError, "settle"),
        Case("noise_scale < 0", lambda: scenario(noise_scale=-1.0), OptionError, "noise_scale"),
        Case("noise_scale a string", lambda: scenario(noise_scale="a"), OptionError, "noise_scale"),
        Case("w_gain a string", lambda: scenario(w_gain="a"), OptionError, "w_gain"),
        Case("x0 of strings", lambda: scenario(x0=("a", "b")), OptionError, "x0"),
        Case("initial_error a string", lambda: scenario(initial_error="a"), OptionError, "initial_error"),
        Case(
            "prior_from_output 1.7", lambda: scenario(prior_from_output=((1.7, 0),)), OptionError, "prior_from_output"
        ),
        Case("cases = 3", lambda: scenario(cases=3), OptionError, "cases"),
        Case("repeated cases", lambda: scenario(cases=("noisy", "noisy")), OptionError, "cases"),
        Case(
            "Trajectory flags of the wrong length",
            lambda: _trajectory_with(x_outside=np.zeros(5)),
            DataError,
            "x_outside",
        ),
        Case("simulate 10**12 steps", lambda: simulate(s(), [0.5, 1.0], 10**12, u=[0.0]), DataError, "steps|memory"),
        Case("ranges N = 1e300", lambda: Sweep(scenario(), random=1, ranges={"N": (1e300, 1e300)}), OptionError, "N"),
        Case(
            "random = 0 with ranges", lambda: Sweep(scenario(), random=0, ranges={"N": (2, 3)}), OptionError, "random"
        ),
        Case("repeated grid values", lambda: Sweep(scenario(), grid={"N": (2, 2, 3)}), OptionError, "distinct"),
        Case(
            "scenario = 3 in a sweep file",
            lambda: Sweep.from_toml(_file(tmp, "sc3.toml", "scenario = 3\n[sweep]\n")),
            OptionError,
            "scenario",
        ),
        Case("a binary scenario file", lambda: Scenario.from_toml(_binary(tmp)), OptionError, "cannot read"),
        Case(
            "sweep: out/runs is a file", lambda: sweep(_tiny_sweep(), _runs_file(tmp), workers=1), OptionError, "runs"
        ),
        Case("w_gain = inf", lambda: scenario(w_gain=math.inf), OptionError, "w_gain"),
        Case("no estimators", lambda: scenario(estimators=()), OptionError, "estimators"),
        Case(
            "two estimators with one name",
            lambda: scenario(estimators=(EstimatorSpec("a", "uise"), EstimatorSpec("a", "fie"))),
            OptionError,
            "unique",
        ),
        Case("estimator kind kalman", lambda: EstimatorSpec("x", "kalman"), OptionError, "kind"),
        Case("estimator mu = 1", lambda: EstimatorSpec("x", "uise", mu=1.0), OptionError, "mu"),
        Case("estimator N = 0 with explicit weights", lambda: EstimatorSpec("x", "uise", N=0), OptionError, "N"),
        Case(
            "estimator output_weight < 0",
            lambda: EstimatorSpec("x", "uise", output_weight=-1.0),
            OptionError,
            "output_weight",
        ),
        Case("estimator weights guess", lambda: EstimatorSpec("x", "uise", weights="guess"), OptionError, "weights"),
        Case(
            "an empty scenario file", lambda: Scenario.from_toml(_file(tmp, "empty.toml", "")), OptionError, "missing"
        ),
        Case(
            "a scenario file that is not TOML",
            lambda: Scenario.from_toml(_file(tmp, "bad.toml", "[[[")),
            OptionError,
            "cannot read",
        ),
        Case(
            "estimators not a list",
            lambda: Scenario.from_dict({"name": "x", "model": "closed-form", "estimators": 3}),
            OptionError,
            "estimators",
        ),
        Case(
            "an unknown scenario key",
            lambda: Scenario.from_dict({"name": "x", "model": "closed-form", "colour": 1}),
            OptionError,
            "colour",
        ),
        Case(
            "x0 of strings",
            lambda: Scenario.from_dict(
                {"name": "x", "model": "closed-form", "x0": ["a", "b"], "estimators": [{"name": "u", "kind": "uise"}]}
            ),
            OptionError,
            "x0",
        ),
        Case("an unknown model", lambda: run_study(scenario(model="no-such-model")), OptionError, "model"),
        Case("UISE weights mu = 1e-300", lambda: uise(weights=_weights_with(mu=1e-300)), OptionError, "weights.mu"),
        Case("UISE weights P = 1e300 I", lambda: uise(weights=_weights_with(P=1e300 * np.eye(2))), OptionError, "P"),
        Case("UISE weights P = 0", lambda: uise(weights=_weights_with(P=np.zeros((2, 2)))), OptionError, "P"),
        Case(
            "StandardMHE eta = 1e-300",
            lambda: StandardMHE(system(), weights=_mhe_weights_with(eta=1e-300), N=3, x0_prior=[0.5, 1.0]),
            OptionError,
            "weights.eta",
        ),
        Case("a boolean y", lambda: uise().run(trajectory().u, trajectory().y > 0.5), DataError, "y"),
        Case(
            "x_bounds per-state pairs for nx = 2",
            lambda: closed_form.system(x_bounds=((0, 10), (5, 20))),
            ModelError,
            "ambiguous",
        ),
        Case("UISE N = 10**6", lambda: uise(N=10**6), OptionError, r"N: expected a horizon <= [\d_]+ for this model"),
        Case(
            "UISE.design max_horizon = 10**6",
            lambda: UISE.design(system(), x0_prior=[0.5, 1.0], max_horizon=10**6),
            OptionError,
            "max_horizon: expected a horizon <=",
        ),
        Case(
            "bench_window_solvers horizons = (100000,)",
            lambda: bench_window_solvers(horizons=(100_000,)),
            OptionError,
            "horizons",
        ),
        Case("run_study: workers a string", lambda: run_study(scenario(), workers="2"), OptionError, "workers"),
        Case("run_study: workers = 0", lambda: run_study(scenario(), workers=0), OptionError, "workers"),
        Case("run_study: workers = -5", lambda: run_study(scenario(), workers=-5), OptionError, "workers"),
        Case("run_study: workers = True", lambda: run_study(scenario(), workers=True), OptionError, "workers"),
        Case("run_study: progress a string", lambda: run_study(scenario(), progress="yes"), OptionError, "progress"),
        Case("run_study: scenario a name", lambda: run_study("settle-2"), OptionError, "scenario"),
        Case("read_record: a number as path", lambda: read_record(12345, system()), DataError, "path"),
        Case("read_record: None as path", lambda: read_record(None, system()), DataError, "path"),
        # sweeps
        Case("grid N = 2.7", lambda: Sweep(scenario(), grid={"N": (2.7,)}), OptionError, "N"),
        Case("grid N = []", lambda: Sweep(scenario(), grid={"N": ()}), OptionError, "non-empty"),
        Case("grid N a string", lambda: Sweep(scenario(), grid={"N": ("a",)}), OptionError, "N"),
        Case("grid N a bare value", lambda: Sweep(scenario(), grid={"N": 3}), OptionError, "list"),
        Case("grid mu = 1.5", lambda: Sweep(scenario(), grid={"mu": (1.5,)}), OptionError, "mu"),
        Case("grid steps below settle", lambda: Sweep(scenario(), grid={"steps": (2,)}), OptionError, "settle"),
        Case("grid colour", lambda: Sweep(scenario(), grid={"colour": (1,)}), OptionError, "colour"),
        Case(
            "grid estimator unknown",
            lambda: Sweep(scenario(), grid={"estimator": ("Kalman",)}),
            OptionError,
            "estimator",
        ),
        Case("grid solver newton", lambda: Sweep(scenario(), grid={"solver": ("newton",)}), OptionError, "solver"),
        Case("ranges low > high", lambda: Sweep(scenario(), random=1, ranges={"N": (5, 2)}), OptionError, "low"),
        Case("ranges of strings", lambda: Sweep(scenario(), random=1, ranges={"mu": ("a", "b")}), OptionError, "mu"),
        Case(
            "ranges of the estimator",
            lambda: Sweep(scenario(), random=1, ranges={"estimator": (0, 1)}),
            OptionError,
            "estimator",
        ),
        Case("random = -1", lambda: Sweep(scenario(), random=-1, ranges={"N": (2, 3)}), OptionError, "random"),
        Case("random = 2.5", lambda: Sweep(scenario(), random=2.5, ranges={"N": (2, 3)}), OptionError, "random"),
        Case("random without ranges", lambda: Sweep(scenario(), random=2), OptionError, "ranges"),
        Case(
            "an empty sweep file", lambda: Sweep.from_toml(_file(tmp, "empty-sweep.toml", "")), OptionError, "scenario"
        ),
        Case("grid not a table", lambda: Sweep.from_toml(_sweep_file(tmp, "grid = 3")), OptionError, "grid"),
        Case("sweep: workers = 0", lambda: sweep(_tiny_sweep(), tmp / "w0", workers=0), OptionError, "workers"),
        Case("sweep: workers = -1", lambda: sweep(_tiny_sweep(), tmp / "w1", workers=-1), OptionError, "workers"),
        Case(
            "sweep: an unwritable folder",
            lambda: sweep(_tiny_sweep(), UNWRITABLE, workers=1),
            OptionError,
            "cannot write",
        ),
        Case(
            "sweep: solver newton",
            lambda: sweep(_tiny_sweep(), tmp / "sn", workers=1, solver="newton"),
            OptionError,
            "solver",
        ),
        Case(
            "sweep: a run file with a damaged page",
            lambda: _corrupted_resume(tmp, page=True),
            ok=lambda r: len(r) == 2 and r["key"].is_unique and (r["error"] == "").all(),
        ),
        Case(
            "sweep: a corrupted run file",
            lambda: _corrupted_resume(tmp),
            ok=lambda r: len(r) == 2 and r["key"].is_unique and (r["error"] == "").all(),
        ),
        Case(
            "sweep: an estimator that raises anything",
            lambda: _raising_sweep(tmp),
            ok=lambda r: (r["error"] == "ZeroDivisionError: injected").all(),
        ),
        *_fuzz_cases(tmp),
        # model analysis
        Case("analyse: a model name, not a System", lambda: analyse("closed-form"), OptionError, "system"),
        Case("analyse: max_horizon = 0", lambda: analyse(s(), max_horizon=0), OptionError, "max_horizon"),
        Case("analyse: points = 0", lambda: analyse(s(), points=0), OptionError, "points"),
        Case("analyse: x0 of the wrong length", lambda: analyse(s(), x0=[1.0, 2.0, 3.0]), DataError, "x0"),
        # issue 35, round 3: bounds before work, flags, names, objects of the wrong kind
        Case("nx = 10**8 (beyond the window memory)", lambda: callables(nx=10**8), ModelError, "nx.*GiB"),
        Case("h returns no output", lambda: callables(h=lambda x, v: []), ModelError, r"\bh\b.*ny = 0"),
        Case("x_bound (a typo)", lambda: callables(x_bound=(0, 1)), OptionError, "did you mean x_bounds"),
        Case("X a dict", lambda: callables(**{X: {"lower": 0, "upper": 1}}), ModelError, "x_bounds"),
        Case("X (False, True)", lambda: callables(**{X: (False, True)}), ModelError, "x_bounds"),
        Case("V = (inf, inf)", lambda: callables(v_bounds=(math.inf, math.inf)), ModelError, "v_bounds.*inf"),
        Case("an empty state name", lambda: callables(x_names=("", "b")), ModelError, r"x_names\[0\]"),
        Case("name = 123", lambda: callables(name=123), ModelError, "name"),
        Case(
            "X lower side masked",
            lambda: callables(**{X: (np.ma.masked_array([-5.0, 5.0], mask=[False, True]), (6.0, 6.0))}),
            ok=lambda sys_: sys_.x.bounds.lower[1] == -math.inf and sys_.x.bounds.lower[0] == -5.0,
        ),
        Case("simulate 10**7 steps", lambda: simulate(s(), [0.5, 1.0], 10**7, u=[0.0]), DataError, "steps.*at most"),
        Case(
            "simulate: w raises",
            lambda: simulate(s(), [0.5, 1.0], 3, u=[0.0], w=lambda k, x: 1 / 0),
            DataError,
            r"\bw\b.*ZeroDivisionError.*k=0",
        ),
        Case("UISE force = 'yes'", lambda: uise(force="yes"), OptionError, "force: expected True or False"),
        Case(
            "two-stage state_constraints = 'no'",
            lambda: two_stage(state_constraints="no"),
            OptionError,
            "state_constraints",
        ),
        Case(
            "plot_estimates log_error = 'no'",
            lambda: plot_estimates(traj(), {}, log_error="no"),
            OptionError,
            "log_error",
        ),
        Case(
            "sweep retry_failed = 'yes'",
            lambda: sweep(_tiny_sweep(), tmp / "r3-sweep", retry_failed="yes"),
            OptionError,
            "retry_failed",
        ),
        Case(
            "bench: horizons (0,) with quick",
            lambda: bench_window_solvers(quick=True, horizons=(0,)),
            OptionError,
            "horizons",
        ),
        Case("analyse max_horizon = 10**7", lambda: analyse(s(), max_horizon=10**7), OptionError, "max_horizon.*GiB"),
        Case(
            "EKF.fit: 10**4 variances",
            lambda: EKF.fit(s(), traj().u, traj().y, x0_prior=[0.5, 1.0], variances=np.logspace(-6, 2, 10**4)),
            OptionError,
            "variances.*at most",
        ),
        Case(
            "EKF.fit: a one-sample record",
            lambda: EKF.fit(s(), np.zeros((0, 1)), traj().y[:1], x0_prior=[0.5, 1.0]),
            DataError,
            r"\by\b.*after k = 0",
        ),
        Case("design budget = -1", lambda: UISE.design(s(), x0_prior=[0.5, 1.0], budget=-1.0), OptionError, "budget"),
        Case("design steps = 2", lambda: UISE.design(s(), x0_prior=[0.5, 1.0], steps=2), OptionError, "steps"),
        Case(
            "design certify_options typo",
            lambda: UISE.design(s(), x0_prior=[0.5, 1.0], certify_options={"sample": 10}),
            OptionError,
            "certify_options.*sample",
        ),
        Case(
            "read_record(path, 'closed-form')",
            lambda: read_record(_file(tmp, "r3.csv", "u,y\n0,1\n"), "closed-form"),
            DataError,
            "system",
        ),
        Case(
            "a CSV with two y columns",
            lambda: read_record(_file(tmp, "r3-dup.csv", "u,y,y\n0,1,2\n0,1,2\n"), s()),
            DataError,
            "y.1",
        ),
        Case("save_figure(None)", lambda: save_figure(None, tmp / "r3.png"), DataError, "fig"),
        Case("write_report(None)", lambda: write_report(None, tmp / "r3-report", wall_time=1.0), OptionError, "study"),
        Case("Scenario runs = 10**8", lambda: scenario(runs=10**8), OptionError, "runs"),
    ]
    return cases


def _fuzz_cases(tmp: Path) -> list[Case]:
    """Issue 16, third fuzz run: inputs that gave tracebacks, silent results or hangs."""
    s, traj, lin = system, trajectory, linear_case
    p = ca.SX.sym("p")
    x, u, w, v = ca.SX.sym("x", 2), ca.SX.sym("u", 0), ca.SX.sym("w", 1), ca.SX.sym("v", 1)
    ode = {"nx": 1, "nw": 1, "nv": 1, "dt": 0.1}
    rhs, out = (lambda x, u, w: [w[0] - x[0]]), (lambda x, v: [x[0] + v[0]])
    with_u = functools.partial(callables, nu=1, u_bounds=(0.0, 1.0))
    reduced = closed_form.reduction
    return [
        # systems
        Case("nu = True", lambda: callables(nu=True), ModelError, "nu: expected an integer"),
        Case("dt a word", lambda: callables(dt="fast"), ModelError, "dt"),
        Case("dt = True", lambda: callables(dt=True), ModelError, "dt"),
        Case("from_ode: dt a word", lambda: System.from_ode(rhs, out, **{**ode, "dt": "fast"}), ModelError, "dt"),
        Case(
            "from_ode: substeps = 10**9",
            lambda: System.from_ode(rhs, out, **ode, substeps=10**9),
            OptionError,
            r"substeps: expected an integer in \[1, 1_000\]",
        ),
        Case(
            "from_expressions: a free symbol",
            lambda: System.from_expressions(x, u, w, v, ca.vertcat(x[0] + p + w, x[1]), x[0] + v),
            ModelError,
            r"x_next: uses the symbols \['p'\]",
        ),
        Case("step: x a word", lambda: s().step("ab", [0.0], [0.0]), DataError, "x: expected real numbers"),
        Case("step: u None for nu = 1", lambda: s().step([0.5, 1.0], None, [0.0]), DataError, "u: expected"),
        Case(
            "step: batches of 3 and 4",
            lambda: s().step(np.zeros((3, 2)), np.zeros((4, 1)), [0.0]),
            DataError,
            "x, u: batched",
        ),
        Case("linear: nw = 0", lambda: linear.with_invariant_zeros([0.5], nw=0), ModelError, "nw"),
        # simulate, trajectories, results, figures
        Case(
            "simulate: progress a word",
            lambda: simulate(s(), [0, 0], 3, u=[0.0], progress="yes"),
            OptionError,
            "progress",
        ),
        Case(
            "simulate: UniformNoise(1, -1)",
            lambda: simulate(s(), [0, 0], 3, u=[0.0], v=UniformNoise(1.0, -1.0)),
            DataError,
            "UniformNoise: ",
        ),
        Case(
            "simulate: GaussianNoise mean NaN",
            lambda: simulate(s(), [0, 0], 3, u=[0.0], v=GaussianNoise(0.01, mean=np.nan)),
            DataError,
            "GaussianNoise.mean",
        ),
        Case(
            "Trajectory of disagreeing lengths",
            lambda: Trajectory(
                t=np.arange(3.0),
                x=np.zeros((5, 2)),
                u=np.zeros((2, 1)),
                w=np.zeros((2, 1)),
                v=np.zeros((3, 1)),
                y=np.zeros((3, 1)),
            ),
            DataError,
            r"x: expected shape \(K\+1, nx\)",
        ),
        Case(
            "result.error(a Trajectory)",
            lambda: uise().run(traj().u, traj().y).error(traj()),
            DataError,
            "x: expected the true states",
        ),
        Case("plot_estimates: a list of results", lambda: plot_estimates(traj(), [1]), DataError, "results"),
        Case("plot_estimates: arguments swapped", lambda: plot_estimates({"a": traj()}, traj()), DataError, "traj"),
        Case("plot_estimates: a result of another system", lambda: _plot_other_system(), DataError, "x_hat"),
        Case(
            "plot_trajectory: units too short",
            lambda: plot_trajectory(traj(), units={"x": ("m",)}),
            DataError,
            r"units\['x'\]",
        ),
        Case("save_figure: a str path", lambda: _saved(str(tmp / "fig.png")), ok=lambda r: r.stat().st_size > 0),
        Case("save_figure: an unknown format", lambda: _saved(tmp / "fig.xyz"), OptionError, "path"),
        Case("save_figure: an unwritable folder", lambda: _saved(UNWRITABLE / "f.png"), OptionError, "cannot write"),
        # estimators
        Case(
            "linear UIO: gain with NaN", lambda: LinearUIO(lin()[0], gain=np.full((3, 1), np.nan)), OptionError, "gain"
        ),
        Case("linear UIO: unstable poles", lambda: LinearUIO(lin()[0], poles=[0.5, 0.2, 1.5]), OptionError, "poles: F"),
        Case("y complex in a run", lambda: uise().run(traj().u, traj().y + 1j), DataError, "y: expected"),
        Case(
            "u outside U in a run",
            lambda: _uise_of(with_u()).run([[5.0]] * 2, np.zeros((3, 1))),
            DataError,
            r"u: expected values in U",
        ),
        Case(
            "u_prev outside U in a step",
            lambda: _step_twice(_uise_of(with_u()), [5.0]),
            DataError,
            r"u_prev: expected values in U",
        ),
        Case(
            "Gauss-Newton max_iter = -5",
            lambda: uise(solver_options={"max_iter": -5}).run(traj().u, traj().y),
            OptionError,
            "max_iter",
        ),
        Case(
            "Gauss-Newton max_iter a word",
            lambda: uise(solver_options={"max_iter": "abc"}).run(traj().u, traj().y),
            OptionError,
            "max_iter",
        ),
        Case(
            "Gauss-Newton step_tol < 0",
            lambda: uise(solver_options={"step_tol": -1.0}).run(traj().u, traj().y),
            OptionError,
            "step_tol",
        ),
        # certificates
        Case("certify: a model name", lambda: certify_strong_detectability("crop"), OptionError, "system"),
        Case(
            "certify: samples = 10**9",
            lambda: certify_strong_detectability(s(), samples=10**9),
            OptionError,
            r"samples: expected an integer in \[10, 1_000_000\]",
        ),
        Case("certify: seed = -1", lambda: certify_strong_detectability(s(), seed=-1), OptionError, "seed"),
        Case("certify: seed = 1.5", lambda: certify_strong_detectability(s(), seed=1.5), OptionError, "seed"),
        Case("delta-IOSS: samples = -1", lambda: certify_delta_ioss(s(), samples=-1), OptionError, "samples"),
        Case("delta-IOSS: eta = 1.5", lambda: certify_delta_ioss(s(), 1.5), OptionError, "eta"),
        Case("delta-IOSS: w_spread < 0", lambda: certify_delta_ioss(s(), w_spread=-1.0), OptionError, "w_spread"),
        Case(
            "verify(10**12)",
            lambda: linear_strong_detectability(*lin()[1:]).verify(10**12),
            OptionError,
            r"n_pairs: expected an integer in \[1, 1_000_000\]",
        ),
        Case(
            "verify seed = -1",
            lambda: linear_strong_detectability(*lin()[1:]).verify(100, seed=-1),
            OptionError,
            "seed",
        ),
        Case(
            "window_information: noise_std a word",
            lambda: window_information(s(), traj().x, traj().u, traj().w, k=4, N=2, noise_std="small"),
            OptionError,
            "noise_std",
        ),
        Case(
            "window_information: w of width 2",
            lambda: window_information(s(), traj().x, traj().u, np.zeros((8, 2)), k=4, N=2, noise_std=0.01),
            DataError,
            "w: expected shape",
        ),
        Case(
            "window_information: x a Trajectory",
            lambda: window_information(s(), traj(), traj().u, traj().w, k=4, N=2, noise_std=0.01),
            DataError,
            "x: expected",
        ),
        Case("full_state: y of length 3", lambda: reduced().full_state(np.zeros(3), np.zeros(1)), DataError, "y"),
        Case("check_assumptions(n_points=0)", lambda: reduced().check_assumptions(n_points=0), OptionError, "n_points"),
        # scenarios, reports, sweeps
        Case(
            "x0 box beyond X",
            lambda: run_study(scenario(runs=2, x0_lower=(0.0, 0.0), x0_upper=(100.0, 100.0)), solver="gn"),
            OptionError,
            "x0_upper: expected a point in X",
        ),
        Case("run_study: solver x", lambda: run_study(scenario(), solver="x"), OptionError, "solver"),
        Case("estimators of strings", lambda: scenario(estimators=("uise",)), OptionError, "estimators"),
        Case("to_toml: a str path", lambda: scenario().to_toml(str(tmp / "s.toml")), ok=lambda r: r.exists()),
        Case(
            "to_toml: an unwritable folder",
            lambda: scenario().to_toml(UNWRITABLE / "s.toml"),
            OptionError,
            "cannot write",
        ),
        Case(
            "write_report: an unwritable folder",
            lambda: write_report(run_study(scenario(), solver="gn"), UNWRITABLE / "report", wall_time=1.0),
            OptionError,
            "cannot write",
        ),
        Case("Sweep of a name", lambda: Sweep("x", grid={"N": (2,)}), OptionError, "scenario"),
        Case(
            "Sweep grid a list of pairs",
            lambda: Sweep(scenario(), grid=[("N", (2, 3))]),
            OptionError,
            "sweep.grid: expected a mapping",
        ),
        Case(
            "Sweep random = 10**8",
            lambda: Sweep(scenario(), random=10**8, ranges={"mu": (0.1, 0.9)}),
            OptionError,
            "expected at most 100_000",
        ),
        Case(
            "sweep: progress a word",
            lambda: sweep(_tiny_sweep(), tmp / "progress", workers=1, progress="yes"),
            OptionError,
            "progress",
        ),
        Case(
            "sweep: out/results.parquet is a folder",
            lambda: sweep(_tiny_sweep(), _results_folder(tmp), workers=1),
            OptionError,
            "results.parquet is a folder",
        ),
    ]


def _uise_of(system_: System) -> UISE:
    return UISE(system_, weights=UISEWeights.from_scales(system_, 0.5, output=1e4), N=2, x0_prior=[0.0, 0.0])


def _step_twice(estimator: Any, u_prev: Any) -> Any:
    estimator.step(None, [0.0])
    return estimator.step(u_prev, [0.0])


def _plot_other_system() -> Any:
    system_, *_ = linear_case()
    truth = simulate(system_, np.zeros(3), 8, w=np.zeros((8, 1)))
    return plot_estimates(trajectory(), {"lin": LinearUIO(system_, x0_prior=np.zeros(3)).run(None, truth.y)})


def _saved(path: Any) -> Any:
    return save_figure(plot_trajectory(trajectory()), path)


def _results_folder(tmp: Path) -> Path:
    out = tmp / "results-is-a-folder"
    (out / "results.parquet").mkdir(parents=True, exist_ok=True)
    return out


def _file(tmp: Path, name: str, text: str) -> Path:
    path = tmp / name
    path.write_text(text)
    return path


def _corrupted_resume(tmp: Path, page: bool = False) -> Any:
    """A stored task whose file is damaged: no footer, or (``page``) a data page with an intact footer."""
    out = tmp / ("damaged-page" if page else "corrupt")
    sweep(_tiny_sweep(), out, workers=1, max_tasks=1)
    (stored,) = (out / "runs").glob("*.parquet")
    data = bytearray(stored.read_bytes())
    if page:
        data[40:120] = bytes(b ^ 0xFF for b in data[40:120])
    stored.write_bytes(bytes(data) if page else b"not parquet")
    return sweep(_tiny_sweep(), out, workers=1)


def _trajectory_with(**changes: Any) -> Any:
    from dataclasses import replace

    return replace(trajectory(), **changes)


def _binary(tmp: Path) -> Path:
    path = tmp / "binary.toml"
    path.write_bytes(b"\xff\xfe\x00binary")
    return path


def _runs_file(tmp: Path) -> Path:
    out = tmp / "runs-is-a-file"
    out.mkdir(exist_ok=True)
    (out / "runs").write_text("")
    return out


def _raising_sweep(tmp: Path) -> Any:
    from uiest.experiments import runner

    original = runner.BUILDERS["uise"]
    runner.BUILDERS["uise"] = raises_inside
    try:
        return sweep(_tiny_sweep(), tmp / "raising", workers=1)
    finally:
        runner.BUILDERS["uise"] = original


# ------------------------------------------------------------------------------------------------ CLI cases
@dataclass(frozen=True)
class CliCase:
    """``uiest ARGS`` must exit with ``code`` and print ``match`` (stdout or stderr), never a traceback."""

    name: str
    args: tuple[str, ...]
    code: int
    match: str


def cli_cases(tmp: Path) -> list[CliCase]:
    empty = _file(tmp, "cli-empty.toml", "")
    two_stage = Scenario(
        **{
            **scenario().__dict__,
            "model": "linear-example",
            "prior": (),
            "prior_from_output": (),
            "focus_state": 0,
            "estimators": (EstimatorSpec("2s", "two-stage", N=3),),
        }
    )
    failing = two_stage.to_toml(tmp / "cli-failing.toml")
    out = str(tmp / "cli-out")
    bad = str(UNWRITABLE)
    return [
        CliCase("unknown model (simulate)", ("simulate", "no-such"), 2, "unknown name"),
        CliCase("simulate --seed -1", ("simulate", "closed-form", "--seed", "-1", "--out", out), 2, "seed"),
        CliCase("simulate --steps -1", ("simulate", "closed-form", "--steps", "-1", "--out", out), 2, "--steps"),
        CliCase("simulate --steps abc", ("simulate", "closed-form", "--steps", "abc"), 2, "steps"),
        CliCase(
            "simulate --steps 10**9",
            ("simulate", "closed-form", "--steps", "1000000000", "--out", out),
            2,
            "--steps: expected at most",
        ),
        CliCase(
            "analyse --max-horizon 10**7", ("analyse", "closed-form", "--max-horizon", "10000000"), 2, "--max-horizon"
        ),
        CliCase("bench --quick -N 0", ("bench", "--quick", "-N", "0"), 2, "-N"),
        CliCase("simulate to an unwritable folder", ("simulate", "closed-form", "--out", bad), 2, "cannot write"),
        CliCase("certify --verify 0", ("certify", "closed-form", "--verify", "0"), 2, "--verify"),
        CliCase(
            "certify --structure diagonal", ("certify", "closed-form", "--structure", "diagonal"), 2, "--structure"
        ),
        CliCase("certify an unknown model", ("certify", "no-such"), 2, "unknown name"),
        CliCase(
            "certify to an unwritable file", ("certify", "closed-form", "--out", f"{bad}/c.json"), 2, "cannot write"
        ),
        CliCase("reproduce an unknown study", ("reproduce", "no-such", "--out", out), 2, "study"),
        CliCase("reproduce --solver newton", ("reproduce", "--solver", "newton", "--out", out), 2, "--solver"),
        CliCase("reproduce --runs 0", ("reproduce", "--runs", "0", "--out", out), 2, "--runs"),
        CliCase("reproduce --steps 0", ("reproduce", "--steps", "0", "--out", out), 2, "--steps"),
        CliCase("reproduce a missing scenario", ("reproduce", "--scenario", str(tmp / "none.toml")), 2, "cannot read"),
        CliCase("reproduce an empty scenario", ("reproduce", "--scenario", str(empty)), 2, "missing"),
        CliCase(  # the two TOML forms: a sweep file nests the scenario in [scenario]
            "reproduce a sweep file",
            ("reproduce", "--scenario", str(_sweep_file(tmp, "grid = {N = [2, 3]}")), "--out", out),
            2,
            "looks like a sweep file (a [scenario] table); run it with `uiest sweep`",
        ),
        CliCase("reproduce to an unwritable folder", ("reproduce", "--quick", "--out", bad), 2, "cannot write"),
        CliCase(
            "reproduce where every run fails",
            ("reproduce", "--scenario", str(failing), "--out", out),
            1,
            "every estimator raised",
        ),
        CliCase("sweep a missing file", ("sweep", str(tmp / "none.toml"), "--out", out), 2, "cannot read"),
        CliCase("sweep an empty file", ("sweep", str(empty), "--out", out), 2, "'scenario' and 'sweep'"),
        CliCase("sweep --solver newton", ("sweep", str(empty), "--solver", "newton"), 2, "--solver"),
        CliCase("sweep --workers -1", ("sweep", str(empty), "--workers", "-1"), 2, "--workers"),
        CliCase("sweep --workers 0", ("sweep", str(empty), "--workers", "0"), 2, "--workers"),
        CliCase(  # a valid sweep file: it is read before the output folder is made
            "sweep to an unwritable folder",
            ("sweep", str(_sweep_file(tmp, "grid = {N = [2]}")), "--out", bad),
            2,
            "cannot write",
        ),
        CliCase("sweep grid N = 2.7", ("sweep", str(_sweep_file(tmp, "grid = {N = [2.7]}")), "--out", out), 2, "N"),
        CliCase(
            "sweep ranges low > high",
            ("sweep", str(_sweep_file(tmp, "random = 1", "ranges = {N = [5, 2]}")), "--out", out),
            2,
            "low <= high",
        ),
        CliCase(
            "sweep grid of strings", ("sweep", str(_sweep_file(tmp, "grid = {mu = ['a']}")), "--out", out), 2, "mu"
        ),
        CliCase(
            "sweep where every task fails",
            ("sweep", str(_failing_sweep_file(tmp)), "--out", out, "--workers", "1"),
            1,
            "every task failed",
        ),
        CliCase(
            "bench --json to an unwritable file", ("bench", "--quick", "--json", f"{bad}/b.json"), 2, "cannot write"
        ),
        CliCase("an unknown command", ("colour",), 2, "No such command"),
        CliCase(
            "reproduce a binary scenario",
            ("reproduce", "--scenario", str(_binary(tmp)), "--out", out),
            2,
            "cannot read",
        ),
        CliCase("reproduce cases = 3", ("reproduce", "--scenario", str(_cases3(tmp)), "--out", out), 2, "cases"),
        CliCase(
            "sweep scenario = 3",
            ("sweep", str(_file(tmp, "cli-sc3.toml", "scenario = 3\n[sweep]\n")), "--out", out),
            2,
            "scenario",
        ),
        CliCase("certify --seed -1", ("certify", "closed-form", "--seed", "-1"), 2, "--seed"),
        CliCase("certify --out an existing folder", ("certify", "closed-form", "--out", str(tmp)), 2, "folder"),
        CliCase("bench --json an existing folder", ("bench", "--quick", "--json", str(tmp)), 2, "folder"),
        CliCase(
            "sweep where out/runs is a file",
            ("sweep", str(_failing_sweep_file(tmp)), "--out", str(_runs_file(tmp))),
            2,
            "runs",
        ),
        CliCase(
            "sweep --scheduler pointing at nothing",
            ("sweep", str(_failing_sweep_file(tmp)), "--out", f"{out}-s", "--scheduler", "tcp://127.0.0.1:9"),
            2,
            "no Dask scheduler answers",
        ),
        CliCase(
            "reproduce --steps 1 below the scenario's settle",
            ("reproduce", "--scenario", str(_scenario_file(tmp)), "--steps", "1", "--out", out),
            2,
            "--steps 1: settle",
        ),
        CliCase("certify --verify 10**12", ("certify", "closed-form", "--verify", str(10**12)), 2, "--verify"),
        CliCase("analyse an unknown model", ("analyse", "no-such"), 2, "unknown name"),
        CliCase("bench -N 100000", ("bench", "-N", "100000"), 2, "expected a horizon <= 16_383"),
        CliCase(
            "estimate --horizon 1000000",
            ("estimate", "closed-form", "--data", str(_record_file(tmp)), "--horizon", "1000000", "--out", out),
            2,
            "--horizon: expected a horizon <=",
        ),
        CliCase(
            "estimate --horizon 5 --lag 1000",
            (
                "estimate",
                "closed-form",
                "--data",
                str(_record_file(tmp)),
                "--estimator",
                "uise",
                "--horizon",
                "5",
                "--lag",
                "1000",
                "--out",
                out,
            ),
            2,
            "--lag: expected an integer below the horizon (--horizon = 5)",
        ),
        CliCase(
            "estimate --estimator uio on a nonlinear model",
            ("estimate", "closed-form", "--data", str(_record_file(tmp)), "--estimator", "uio", "--out", out),
            2,
            "--estimator uio: system: expected a linear",
        ),
        CliCase(
            "estimate --lag 5 --horizon 5",
            ("estimate", "closed-form", "--data", str(_record_file(tmp)), "--horizon", "5", "--lag", "5", "--out", out),
            2,
            "--lag",
        ),
        CliCase(
            "estimate --lag 1000 without --horizon",
            (
                "estimate",
                "closed-form",
                "--data",
                str(_record_file(tmp)),
                "--estimator",
                "uise",
                "--lag",
                "1000",
                "--out",
                out,
            ),
            2,
            "--lag",
        ),
        CliCase("analyse --max-horizon 0", ("analyse", "closed-form", "--max-horizon", "0"), 2, "--max-horizon"),
        CliCase("analyse --json unwritable", ("analyse", "closed-form", "--json", f"{bad}/a.json"), 2, "cannot write"),
        CliCase(
            "sweep where out/results.parquet is a folder",
            ("sweep", str(_sweep_file(tmp, "grid = {N = [3]}")), "--out", str(_results_folder(tmp)), "--workers", "1"),
            2,
            "results.parquet is a folder",
        ),
    ]


def _scenario_file(tmp: Path) -> Path:
    return scenario().to_toml(tmp / "settle-2.toml")


def _cases3(tmp: Path) -> Path:
    text = scenario().to_toml(tmp / "cases-base.toml").read_text()
    return _file(tmp, "cases3.toml", re.sub(r"(?m)^cases = .*$", "cases = 3", text))


def _failing_sweep_file(tmp: Path) -> Path:
    """A sweep whose only estimator cannot be built (the two-stage UISE of a model without a reduction)."""
    text = (
        "[scenario]\nname = 'x'\nmodel = 'linear-example'\nsteps = 8\nruns = 1\ncases = ['noisy']\nsettle = 2\n"
        "[[scenario.estimators]]\nname = '2s'\nkind = 'two-stage'\nN = 3\n[sweep]\ngrid = {N = [2, 3]}\n"
    )
    return _file(tmp, "failing-sweep.toml", text)


def _record_file(tmp: Path) -> Path:
    """A short closed-form record (8 steps) as uiest writes it."""
    path = tmp / "closed-form-record.csv"
    trajectory().to_pandas().to_csv(path)
    return path


def _weights_with(**changes: Any) -> UISEWeights:
    base = weights()
    return UISEWeights(**{"mu": base.mu, "P": base.P, "R_y": base.R_y, "R_v": base.R_v, **changes})


def _mhe_weights_with(**changes: Any) -> MHEWeights:
    base = MHEWeights.from_scales(system(), 0.9)
    return MHEWeights(**{"eta": base.eta, "P": base.P, "Q_w": base.Q_w, "Q_v": base.Q_v, "R": base.R, **changes})
