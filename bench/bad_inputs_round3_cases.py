"""The cases of bench/bad_inputs_round3.py: new bad inputs for uiest (issue 35), none from tests/bad_inputs.py.

A :class:`Case` is ``call()`` plus what counts as right:

- ``names``: a regular expression a typed error's message (or a CLI ``error:`` line) must match: the argument;
- ``check(result) -> str | None``: for a call that may legitimately return, None when the result is correct and
  otherwise why it is wrong (what "silent" means for this case). Without a check, returning at all is silent;
- ``error_ok``: False for valid inputs given in an unusual form (a numpy integer, a str path): refusing them is not
  good.

Fixtures are small: the closed-form model (nx = 2) and a 40-step record from its setup; every case runs in its own
scratch folder (the current directory while it runs).
"""

from __future__ import annotations

import contextlib
import functools
import math
import os
import shutil
import tempfile
import textwrap
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

REFERENCE_RMSE = 0.05  # a correct estimate of the 40-step closed-form record: RMSE after k = 10 about 0.004-0.01


@dataclass(frozen=True)
class Case:
    id: str
    given: str
    call: Callable[[], Any]
    names: str = "."
    check: Callable[[Any], str | None] | None = None
    error_ok: bool = True
    warning_suffices: bool = False
    """The data cannot show the defect (e.g. rows dropped from a record without k or t): a UserWarning matching
    ``names`` is the specified answer (the issue: "a record without k or t says it is taken as contiguous")."""


@dataclass
class CliResult:
    code: int
    text: str
    exception: str | None
    is_cli: bool = field(default=True)


_current: dict[str, Path] = {}


@contextlib.contextmanager
def scratch_for(case_id: str) -> Iterator[Path]:
    """A fresh folder for the case, the working directory while it runs."""
    root = os.environ.get("UIEST_R3_SCRATCH") or tempfile.mkdtemp(prefix="uiest-bad-inputs-r3-")
    os.environ["UIEST_R3_SCRATCH"] = root  # the harness sets it and removes the folder at the end
    folder = Path(root) / case_id.replace("/", "_")
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir(parents=True)
    previous = Path.cwd()
    os.chdir(folder)
    _current["dir"] = folder
    from uiest import models

    registry = dict(models._REGISTRY)  # a case that loads a model file must not change the next case's models
    try:
        yield folder
    finally:
        os.chdir(previous)
        models._REGISTRY.clear()
        models._REGISTRY.update(registry)


def here() -> Path:
    return _current.get("dir", Path.cwd())


# ------------------------------------------------------------------------------------------------ fixtures
@functools.cache
def entry() -> Any:
    from uiest.models import get

    return get("closed-form")


def system() -> Any:
    return entry().build()


@functools.cache
def record() -> Any:
    from uiest import simulate

    setup = entry().simulation()
    return simulate(system(), setup.x0, 40, u=setup.u, w=setup.w, v=setup.noise, seed=0)


X0 = [0.5, 1.0]


def weights(mu: float = 0.64) -> Any:
    from uiest.estimators import UISEWeights

    return UISEWeights.from_scales(system(), mu, output=1e4)


def uise(**kw: Any) -> Any:
    from uiest.estimators import UISE

    return UISE(system(), **{"weights": weights(), "N": 3, "x0_prior": X0, **kw})


def ekf(**kw: Any) -> Any:
    from uiest.estimators import EKF

    return EKF(system(), **{"w_variance": 1.0, "x0_prior": X0, **kw})


def callables(**changes: Any) -> Any:
    from uiest import System

    spec = {"nx": 2, "nw": 1, "nv": 1, "x_bounds": (-5.0, 5.0), **changes}
    f = spec.pop("f", lambda x, u, w: [0.5 * x[0] + w[0], 0.8 * x[1] + 0.1 * x[0]])
    h = spec.pop("h", lambda x, v: [x[0] + v[0]])
    return System.from_callables(f, h, **spec)


def rmse(result: Any, skip: int = 10) -> float:
    err = np.asarray(result.error(record().x))[skip:]
    return float(np.sqrt(np.mean(err**2)))


def accurate(result: Any) -> str | None:
    """A run on the 40-step record: finite and as accurate as a correct run, else why not (with its status)."""
    x_hat = np.asarray(result.x_hat)
    status = sorted({str(s) for s in np.asarray(result.status)})[:3]
    if not np.all(np.isfinite(x_hat)):
        return f"non-finite estimates, status {status}"
    error = rmse(result)
    if error > REFERENCE_RMSE:
        return f"RMSE {error:.3g} (a correct run: < {REFERENCE_RMSE}), status {status}"
    return None


def finite_result(result: Any) -> str | None:
    x_hat = np.asarray(result.x_hat)
    if not np.all(np.isfinite(x_hat)):
        return f"non-finite estimates, status {sorted({str(s) for s in np.asarray(result.status)})[:3]}"
    return None


def write(name: str, text: str) -> Path:
    path = here() / name
    path.write_text(textwrap.dedent(text))
    return path


def record_csv(name: str = "data.csv", frame: Any = None) -> Path:
    path = here() / name
    (record().to_pandas() if frame is None else frame).to_csv(path)
    return path


def frame(**columns: Any) -> Any:
    data = record().to_pandas()
    for key, value in columns.items():
        data[key] = value
    return data


def read(path: Any) -> Any:
    from uiest.results import read_record

    return read_record(path, system())


def cli(*args: str) -> CliResult:
    from typer.testing import CliRunner

    from uiest.cli import app

    result = CliRunner().invoke(app, [str(a) for a in args])
    text = result.output + (result.stderr if result.stderr_bytes is not None else "")
    exc = result.exception
    if exc is not None and not isinstance(exc, SystemExit):
        return CliResult(result.exit_code, text, f"{type(exc).__name__}: {str(exc)[:200]}")
    return CliResult(result.exit_code, text, None)


def steps_are(n: int) -> Callable[[Any], str | None]:
    def check(traj: Any) -> str | None:
        return None if traj.steps == n else f"{traj.steps} steps, expected {n}"

    return check


def has_missing(rows: tuple[int, ...], total: int) -> Callable[[Any], str | None]:
    """A record read from a table with ``rows`` dropped: the gaps kept as missing samples."""

    def check(traj: Any) -> str | None:
        if traj.steps != total:
            return f"rows {rows} dropped read as a contiguous record of {traj.steps} steps (expected {total})"
        if not all(np.all(np.isnan(traj.y[r])) for r in rows):
            return "the dropped rows are not missing"
        return None

    return check


def nothing_outside(check_dir: str, pattern: str = "*") -> Callable[[Any], str | None]:
    def check(_: Any) -> str | None:
        escaped = list((here() / check_dir).glob(pattern)) if (here() / check_dir).exists() else []
        return f"wrote {len(escaped)} files outside the output folder ({check_dir})" if escaped else None

    return check


def files_written(*names: str) -> Callable[[Any], str | None]:
    def check(_: Any) -> str | None:
        missing = [n for n in names if not (here() / n).exists()]
        return f"exit 0 without writing {missing}" if missing else None

    return check


# ------------------------------------------------------------------------------------------------ model files
GOOD_MODEL = '''
"""A scalar stable model with a gain read from this file."""
import numpy as np
from uiest import System
from uiest.models import SimulationSetup
from uiest.noise import UniformNoise

GAIN = {gain}
system = System.from_callables(
    lambda x, u, w: [GAIN * x[0] + w[0]], lambda x, v: [x[0] + v[0]], nx=1, nw=1, nv=1,
    x_bounds=(-100.0, 100.0), v_bounds=(-0.01, 0.01), name="gainy",
)

def setup():
    return SimulationSetup(x0=np.zeros(1), steps=20, u=None, w=np.array([0.5]), noise=UniformNoise.symmetric(0.01))
'''


def model_file(name: str, body: str) -> Path:
    return write(name, body)


# ------------------------------------------------------------------------------------------------ the cases
def cases() -> list[Case]:
    return [*system_cases(), *simulate_cases(), *estimator_cases(), *kalman_cases(), *design_cases(),
            *certificate_cases(), *analyse_cases(), *record_cases(), *study_cases(), *sweep_cases(),
            *plot_cases(), *cli_cases()]  # fmt: skip


def system_cases() -> list[Case]:
    from uiest import System
    from uiest.models import linear

    def bounds(lower: list[float], upper: list[float]) -> Callable[[Any], str | None]:
        def check(s: Any) -> str | None:
            got = (list(s.x.bounds.lower), list(s.x.bounds.upper))
            return None if got == (lower, upper) else f"X read as lower {got[0]}, upper {got[1]}"

        return check

    ma = np.ma.masked_array([-5.0, 5.0], mask=[False, True])
    return [
        Case(
            "sys-nx-int64",
            "nx = np.int64(2)",
            lambda: callables(nx=np.int64(2)),
            "nx",
            lambda s: None if s.nx == 2 else f"nx {s.nx}",
            error_ok=False,
        ),
        Case(
            "sys-nx-float-2.0",
            "nx = 2.0 (a float)",
            lambda: callables(nx=2.0),
            "nx",
            lambda s: None if s.nx == 2 and isinstance(s.nx, int) else f"nx {s.nx!r}",
        ),
        Case(
            "sys-nx-huge", "nx = 10**8", lambda: callables(nx=10**8, f=lambda x, u, w: x, h=lambda x, v: [x[0]]), "nx"
        ),
        Case("sys-nx-str", "nx = '2'", lambda: callables(nx="2"), "nx"),
        Case("sys-nv-none", "nv = None", lambda: callables(nv=None), "nv"),
        Case(
            "sys-xb-pairs",
            "x_bounds = ((0, 10), (5, 20)) for nx = 2 (per-state pairs)",
            lambda: callables(x_bounds=((0.0, 10.0), (5.0, 20.0))),
            "x_bounds",
            bounds([0.0, 5.0], [10.0, 20.0]),
        ),
        Case(
            "sys-xb-masked",
            "x_bounds lower a masked array ([-5, 5] with 5 masked)",
            lambda: callables(x_bounds=(ma, (6.0, 6.0))),
            "x_bounds",
            bounds([-5.0, -np.inf], [6.0, 6.0]),
        ),
        Case(
            "sys-xb-str",
            "x_bounds = ('0', '1') (numbers as strings)",
            lambda: callables(x_bounds=("0", "1")),
            "x_bounds",
            bounds([0.0, 0.0], [1.0, 1.0]),
        ),
        Case("sys-xb-bool", "x_bounds = (False, True)", lambda: callables(x_bounds=(False, True)), "x_bounds"),
        Case("sys-xb-3tuple", "x_bounds = (0, 1, 2)", lambda: callables(x_bounds=(0, 1, 2)), "x_bounds"),
        Case(
            "sys-xb-dict",
            "x_bounds = {'lower': 0, 'upper': 1}",
            lambda: callables(x_bounds={"lower": 0, "upper": 1}),
            "x_bounds",
        ),
        Case(
            "sys-vb-equal",
            "v_bounds = (0.1, 0.1) (a zero-width noise box off zero)",
            lambda: callables(v_bounds=(0.1, 0.1)),
            "v_bounds",
            lambda s: None if float(s.v.bounds.lower[0]) == 0.1 else "V changed",
        ),
        Case("sys-vb-inf-lower", "v_bounds = (inf, inf)", lambda: callables(v_bounds=(np.inf, np.inf)), "v_bounds"),
        Case(
            "sys-names-int",
            "x_names = (1, 2)",
            lambda: callables(x_names=(1, 2)),
            "names",
            lambda s: None if all(isinstance(n, str) for n in s.x.names) else f"names kept as {s.x.names!r}",
        ),
        Case("sys-names-empty", "x_names = ('', 'b')", lambda: callables(x_names=("", "b")), "names"),
        Case("sys-units-len", "x_units of length 3 for nx = 2", lambda: callables(x_units=("m", "m", "m")), "units"),
        Case("sys-name-int", "name = 123", lambda: callables(name=123), "name"),
        Case("sys-dt-inf", "dt = inf", lambda: callables(dt=math.inf), "dt"),
        Case("sys-dt-complex", "dt = 1j", lambda: callables(dt=1j), "dt"),
        Case("sys-f-none", "f returns None", lambda: callables(f=lambda x, u, w: None), r"\bf\b"),
        Case("sys-f-str", "f returns a string", lambda: callables(f=lambda x, u, w: "x+w"), r"\bf\b"),
        Case("sys-f-raises", "f raises KeyError inside", lambda: callables(f=lambda x, u, w: {}["a"]), r"\bf\b"),
        Case("sys-h-index", "h reads v[1] with nv = 1", lambda: callables(h=lambda x, v: [x[0] + v[1]]), "h|v"),
        Case("sys-h-empty", "h returns [] (no output)", lambda: callables(h=lambda x, v: []), r"\bh\b|ny|output"),
        Case("sys-xscale-nan", "x_scale = NaN", lambda: callables(x_scale=math.nan), "x_scale"),
        Case("sys-xscale-len", "x_scale of length 3", lambda: callables(x_scale=[1.0, 1.0, 1.0]), "x_scale"),
        Case("sys-wrange-swapped", "w_range = (1, -1)", lambda: callables(w_range=(1.0, -1.0)), "w_range"),
        Case("sys-unknown-kw", "x_bound = (0, 1) (a typo)", lambda: callables(x_bound=(0, 1)), "x_bound"),
        Case(
            "sys-ode-rhs-len",
            "from_ode: rhs of length 2 for nx = 1",
            lambda: System.from_ode(lambda x, u, w: [w[0], x[0]], lambda x, v: [x[0]], nx=1, nw=1, nv=1, dt=0.1),
            "rhs",
        ),
        Case(
            "sys-ode-method",
            "from_ode: method = 'euler'",
            lambda: System.from_ode(
                lambda x, u, w: [w[0] - x[0]], lambda x, v: [x[0]], nx=1, nw=1, nv=1, dt=0.1, method="euler"
            ),
            "method",
        ),
        Case(
            "sys-ode-dt-inf",
            "from_ode: dt = inf",
            lambda: System.from_ode(lambda x, u, w: [w[0] - x[0]], lambda x, v: [x[0]], nx=1, nw=1, nv=1, dt=math.inf),
            "dt",
        ),
        Case(
            "sys-lin-bool",
            "linear_system with a boolean A",
            lambda: linear.linear_system(np.eye(2, dtype=bool), [[1], [0]], [[1, 0]]),
            r"\bA\b",
        ),
        Case(
            "sys-lin-str",
            "linear_system with A of strings",
            lambda: linear.linear_system([["1", "0"], ["0", "1"]], [[1], [0]], [[1, 0]]),
            r"\bA\b",
        ),
        Case(
            "sys-lin-B-none",
            "linear_system with B = None",
            lambda: linear.linear_system(np.eye(2), None, [[1, 0]]),
            r"\bB\b",
        ),
        Case(
            "sys-lin-inf",
            "linear_system with C = [[inf, 0]]",
            lambda: linear.linear_system(0.5 * np.eye(2), [[1], [0]], [[np.inf, 0]]),
            r"\bC\b",
        ),
        Case(
            "sys-zeros-nw-float",
            "with_invariant_zeros([0.5], nw=1.5)",
            lambda: linear.with_invariant_zeros([0.5], nw=1.5),
            "nw",
        ),
    ]


def simulate_cases() -> list[Case]:
    from uiest import GaussianNoise, UniformNoise, simulate

    s = system
    u0 = [0.0]

    def shape(n: int) -> Callable[[Any], str | None]:
        return lambda t: None if t.x.shape == (n + 1, 2) and np.isfinite(t.x).all() else f"x {t.x.shape}"

    return [
        Case(
            "sim-steps-int64",
            "steps = np.int64(4)",
            lambda: simulate(s(), X0, np.int64(4), u=u0),
            "steps",
            shape(4),
            error_ok=False,
        ),
        Case("sim-steps-0", "steps = 0", lambda: simulate(s(), X0, 0, u=u0), "steps", shape(0)),
        Case("sim-steps-float-int", "steps = 4.0", lambda: simulate(s(), X0, 4.0, u=u0), "steps", shape(4)),
        Case(
            "sim-steps-huge",
            "steps = 10**7 (beyond MAX_SAMPLES? 80 MB per array)",
            lambda: simulate(s(), X0, 10**7, u=u0),
            "steps|memory",
        ),
        Case(
            "sim-x0-masked",
            "x0 a masked array with x0[1] masked",
            lambda: simulate(s(), np.ma.masked_array([0.5, 1.0], mask=[False, True]), 3, u=u0),
            "x0",
        ),
        Case("sim-x0-bool", "x0 = [True, False]", lambda: simulate(s(), [True, False], 3, u=u0), "x0"),
        Case(
            "sim-x0-dict", "x0 = {'x1': 0.5, 'x2': 1.0}", lambda: simulate(s(), {"x1": 0.5, "x2": 1.0}, 3, u=u0), "x0"
        ),
        Case("sim-x0-2d", "x0 of shape (1, 2)", lambda: simulate(s(), [[0.5, 1.0]], 3, u=u0), "x0", shape(3)),
        Case("sim-u-str", "u = '0'", lambda: simulate(s(), X0, 3, u="0"), r"\bu\b"),
        Case("sim-u-object", "u an object array [None]", lambda: simulate(s(), X0, 3, u=np.array([None])), r"\bu\b"),
        Case(
            "sim-u-masked",
            "u a masked array (3, 1) with one entry masked",
            lambda: simulate(s(), X0, 3, u=np.ma.masked_array(np.zeros((3, 1)), mask=[[0], [1], [0]])),
            r"\bu\b",
        ),
        Case("sim-u-bool", "u = [True] (bool input)", lambda: simulate(s(), X0, 3, u=[True]), r"\bu\b"),
        Case(
            "sim-w-raises",
            "w a callable that raises",
            lambda: simulate(s(), X0, 3, u=u0, w=lambda k, x: 1 / 0),
            r"\bw\b",
        ),
        Case(
            "sim-w-nan-callable",
            "w a callable returning NaN at k = 2",
            lambda: simulate(s(), X0, 3, u=u0, w=lambda k, x: [math.nan if k == 2 else 0.0]),
            r"\bw\b",
        ),
        Case(
            "sim-w-huge",
            "w = [1e308] (overflows the state)",
            lambda: simulate(s(), X0, 3, u=u0, w=[1e308]),
            r"non-finite|\bw\b|overflow",
            lambda t: None if np.isfinite(t.x).all() else "non-finite states returned",
        ),
        Case(
            "sim-gauss-negative",
            "v = GaussianNoise(-0.1)",
            lambda: simulate(s(), X0, 3, u=u0, v=GaussianNoise(-0.1)),
            "GaussianNoise|std|sigma|variance",
        ),
        Case(
            "sim-uniform-nan",
            "v = UniformNoise.symmetric(NaN)",
            lambda: simulate(s(), X0, 3, u=u0, v=UniformNoise.symmetric(math.nan)),
            "UniformNoise",
        ),
        Case("sim-seed-2-64", "seed = 2**64", lambda: simulate(s(), X0, 3, u=u0, seed=2**64), "seed", shape(3)),
        Case(
            "sim-seed-int64",
            "seed = np.int64(3)",
            lambda: simulate(s(), X0, 3, u=u0, seed=np.int64(3)),
            "seed",
            shape(3),
            error_ok=False,
        ),
        Case("sim-progress-int", "progress = 3", lambda: simulate(s(), X0, 3, u=u0, progress=3), "progress"),
        Case("sim-system-none", "system = None", lambda: simulate(None, X0, 3), "system"),
    ]


def estimator_cases() -> list[Case]:
    from uiest.estimators import (
        FIE,
        UISE,
        DelayedUISE,
        LinearUIO,
        MHEWeights,
        SmoothInputMHE,
        StandardMHE,
        TwoStageUISE,
        TwoStageWeights,
        UISEWeights,
    )
    from uiest.models import closed_form, linear

    r = record
    s = system

    def masked_outlier() -> Any:
        y = np.ma.masked_array(r().y.copy(), mask=np.zeros_like(r().y, dtype=bool))
        y[20, 0] = 1e6
        y.mask[20, 0] = True
        return uise().run(r().u, y)

    def run_with(w: Any) -> Any:
        return UISE(s(), weights=w, N=3, x0_prior=X0).run(r().u, r().y)

    def base_w() -> Any:
        return weights()

    def lin() -> Any:
        return linear.with_invariant_zeros([0.5, 0.2], seed=3, x_bounds=(-10, 10), v_bounds=(-1e-3, 1e-3))[0]

    return [
        Case("est-y-masked", "y a masked array whose masked sample is 1e6", masked_outlier, r"\by\b|mask", accurate),
        Case("est-y-bool", "y a boolean array", lambda: uise().run(r().u, r().y > 0.5), r"\by\b"),
        Case("est-y-str", "y an array of numeric strings", lambda: uise().run(r().u, r().y.astype(str)), r"\by\b"),
        Case(
            "est-y-object-none",
            "y an object array with None for missing",
            lambda: uise().run(r().u, np.where(np.arange(41)[:, None] == 5, None, r().y).astype(object)),
            r"\by\b",
            accurate,
        ),
        Case("est-y-3d", "y of shape (41, 1, 1)", lambda: uise().run(r().u, r().y[:, :, None]), r"\by\b"),
        Case("est-y-transposed", "y transposed (1, 41)", lambda: uise().run(r().u, r().y.T), r"\by\b"),
        Case("est-u-bool", "u a boolean array", lambda: uise().run(r().u.astype(bool), r().y), r"\bu\b"),
        Case(
            "est-u-longer",
            "u with K+1 rows (one too many)",
            lambda: uise().run(np.zeros((41, 1)), r().y),
            r"\bu\b|length",
        ),
        Case(
            "est-mu-1e-300",
            "UISEWeights mu = 1e-300",
            lambda: run_with(UISEWeights(1e-300, base_w().P, base_w().R_y, base_w().R_v)),
            "mu",
            accurate,
        ),
        Case(
            "est-P-1e300",
            "UISEWeights P = 1e300 I",
            lambda: run_with(UISEWeights(0.64, 1e300 * np.eye(2), base_w().R_y, base_w().R_v)),
            r"\bP\b",
            accurate,
        ),
        Case(
            "est-P-zero",
            "UISEWeights P = 0",
            lambda: run_with(UISEWeights(0.64, np.zeros((2, 2)), base_w().R_y, base_w().R_v)),
            r"\bP\b",
            accurate,
        ),
        Case(
            "est-Ry-inf",
            "UISEWeights R_y = [[inf]]",
            lambda: UISEWeights(0.64, base_w().P, [[np.inf]], base_w().R_v),
            "R_y",
        ),
        Case(
            "est-Rv-nan",
            "UISEWeights R_v = [[NaN]]",
            lambda: UISEWeights(0.64, base_w().P, base_w().R_y, [[np.nan]]),
            "R_v",
        ),
        Case(
            "est-Ry-1e-300",
            "UISEWeights R_y = [[1e-300]] (output ignored)",
            lambda: run_with(UISEWeights(0.64, base_w().P, [[1e-300]], base_w().R_v)),
            "R_y",
            accurate,
        ),
        Case("est-mu-nan", "UISEWeights mu = NaN", lambda: UISEWeights(math.nan, np.eye(2), [[1.0]], [[1.0]]), "mu"),
        Case(
            "est-mu-str",
            "UISEWeights mu = '0.5'",
            lambda: UISEWeights("0.5", np.eye(2), [[1.0]], [[1.0]]),
            "mu",
            lambda w: None if w.mu == 0.5 else f"mu read as {w.mu!r}",
        ),
        Case(
            "est-N-huge",
            "UISE N = 10**7 run on a 40-step record",
            lambda: uise(N=10**7).run(r().u, r().y),
            r"\bN\b",
            accurate,
        ),
        Case(
            "est-N-int64",
            "UISE N = np.int64(3)",
            lambda: uise(N=np.int64(3)).run(r().u, r().y),
            r"\bN\b",
            accurate,
            error_ok=False,
        ),
        Case(
            "est-N-above-K",
            "UISE N = 100 on a 40-step record",
            lambda: uise(N=100).run(r().u, r().y),
            r"\bN\b",
            accurate,
        ),
        Case("est-force-str", "UISE force = 'yes'", lambda: uise(force="yes"), "force"),
        Case(
            "est-system-str", "UISE(system='closed-form')", lambda: UISE("closed-form", weights=base_w(), N=3), "system"
        ),
        Case(
            "est-maxiter-0",
            "solver_options max_iter = 0",
            lambda: uise(solver_options={"max_iter": 0}).run(r().u, r().y),
            "max_iter",
        ),
        Case(
            "est-x0-masked",
            "x0_prior a masked array with x0[0] masked",
            lambda: uise(x0_prior=np.ma.masked_array(X0, mask=[True, False])),
            "x0_prior",
        ),
        Case(
            "est-x0-run-kw",
            "run(x0_prior=[NaN, 1])",
            lambda: uise().run(r().u, r().y, x0_prior=[math.nan, 1.0]),
            "x0_prior",
        ),
        Case(
            "est-step-after-run",
            "step() after run() (continues the run)",
            lambda: (lambda e: (e.run(r().u, r().y), e.step([0.0], [0.5]))[1])(uise()),
            r"\by\b|u_prev",
            lambda st: None if np.all(np.isfinite(st.x_hat)) else "non-finite step",
        ),
        Case(
            "delayed-lag-0",
            "DelayedUISE lag = 0 (a double integrator, relative degree 2)",
            lambda: DelayedUISE.design(double_integrator(), x0_prior=[0.0, 0.0], lag=0),
            "lag",
        ),
        Case(
            "delayed-lag-str",
            "DelayedUISE lag = '1' (a double integrator)",
            lambda: DelayedUISE.design(double_integrator(), x0_prior=[0.0, 0.0], lag="1"),
            "lag",
        ),
        Case(
            "delayed-lag-huge",
            "DelayedUISE.design lag = 10**6 (a double integrator)",
            lambda: DelayedUISE.design(double_integrator(), x0_prior=[0.0, 0.0], lag=10**6),
            "lag",
        ),
        Case(
            "fie-max-steps-huge",
            "FIE max_steps = 10**12",
            lambda: FIE(s(), weights=base_w(), max_steps=10**12),
            "max_steps",
            lambda e: None,
        ),
        Case("fie-x0-str", "FIE x0_prior = 'a,b'", lambda: FIE(s(), weights=base_w(), x0_prior="a,b"), "x0_prior"),
        Case(
            "mhe-weights-nan",
            "MHEWeights Q_w = [[NaN]]",
            lambda: MHEWeights(0.5, np.eye(2), [[np.nan]], [[1.0]], [[1.0]]),
            "Q_w",
        ),
        Case(
            "mhe-eta-1e-300",
            "StandardMHE with MHEWeights eta = 1e-300",
            lambda: StandardMHE(
                s(), weights=MHEWeights(1e-300, np.eye(2), [[1.0]], [[1e4]], [[1e4]]), N=3, x0_prior=X0
            ).run(r().u, r().y),
            "eta",
            finite_result,
        ),
        Case(
            "mhe-normalise-str",
            "StandardMHE normalise = 'yes'",
            lambda: StandardMHE(
                s(), weights=MHEWeights(0.5, np.eye(2), [[1.0]], [[1.0]], [[1.0]]), N=3, normalise="yes"
            ),
            "normalise",
        ),
        Case(
            "mhe-w-prior-len",
            "StandardMHE w_prior of length 3",
            lambda: StandardMHE(
                s(), weights=MHEWeights(0.5, np.eye(2), [[1.0]], [[1.0]], [[1.0]]), N=3, w_prior=[0.0, 0.0, 0.0]
            ),
            "w_prior",
        ),
        Case(
            "smooth-dwvar-inf",
            "SmoothInputMHE.design dw_variance = inf",
            lambda: SmoothInputMHE.design(s(), dw_variance=math.inf, x0_prior=X0),
            "dw_variance",
        ),
        Case(
            "smooth-dwbound-neg",
            "SmoothInputMHE.design dw_bound = -1",
            lambda: SmoothInputMHE.design(s(), dw_bound=-1.0, x0_prior=X0),
            "dw_bound",
        ),
        Case(
            "smooth-wbounds-swapped",
            "SmoothInputMHE.design w_bounds = (1, -1)",
            lambda: SmoothInputMHE.design(s(), dw_variance=0.01, w_bounds=(1.0, -1.0), x0_prior=X0),
            "w_bounds",
        ),
        Case(
            "smooth-maxh-0",
            "SmoothInputMHE.design max_horizon = 0",
            lambda: SmoothInputMHE.design(s(), dw_variance=0.01, max_horizon=0, x0_prior=X0),
            "max_horizon",
        ),
        Case(
            "smooth-both",
            "SmoothInputMHE.design dw_variance and dw_bound both given, disagreeing",
            lambda: SmoothInputMHE.design(s(), dw_variance=1e-6, dw_bound=100.0, x0_prior=X0, N=3),
            "dw_variance|dw_bound",
            lambda e: None,
        ),
        Case(
            "two-stage-projection",
            "TwoStageUISE projection = 'round'",
            lambda: TwoStageUISE(
                closed_form.reduction(),
                weights=TwoStageWeights.from_scales(closed_form.reduction(), 0.5),
                N=3,
                projection="round",
            ),
            "projection",
        ),
        Case(
            "two-stage-constraints-str",
            "TwoStageUISE state_constraints = 'no'",
            lambda: TwoStageUISE(
                closed_form.reduction(),
                weights=TwoStageWeights.from_scales(closed_form.reduction(), 0.5),
                N=3,
                state_constraints="no",
            ),
            "state_constraints",
        ),
        Case(
            "two-stage-system",
            "TwoStageUISE given a System, not a ReducedModel",
            lambda: TwoStageUISE(s(), weights=base_w(), N=3),
            "reduced",
        ),
        Case("uio-rtol-neg", "LinearUIO rtol = -1", lambda: LinearUIO(lin(), rtol=-1.0), "rtol"),
        Case(
            "uio-poles-complex",
            "LinearUIO poles not in conjugate pairs",
            lambda: LinearUIO(lin(), poles=[0.1 + 0.2j, 0.1, 0.2]),
            "poles",
        ),
        Case("uio-poles-str", "LinearUIO poles = 'fast'", lambda: LinearUIO(lin(), poles="fast"), "poles"),
        Case(
            "result-error-shape",
            "result.error(x of shape (41, 3))",
            lambda: uise().run(r().u, r().y).error(np.zeros((41, 3))),
            r"\bx\b",
        ),
        Case("result-error-none", "result.error(None)", lambda: uise().run(r().u, r().y).error(None), r"\bx\b"),
    ]


def kalman_cases() -> list[Case]:
    from uiest.estimators import EKF, UKF

    r, s = record, system
    return [
        Case("ekf-wvar-nan", "EKF w_variance = NaN", lambda: ekf(w_variance=math.nan), "w_variance"),
        Case("ekf-wvar-inf", "EKF w_variance = inf", lambda: ekf(w_variance=math.inf), "w_variance"),
        Case("ekf-wvar-str", "EKF w_variance = 'big'", lambda: ekf(w_variance="big"), "w_variance"),
        Case("ekf-wvar-neg", "EKF w_variance = -1", lambda: ekf(w_variance=-1.0), "w_variance"),
        Case(
            "ekf-wvar-1e300",
            "EKF w_variance = 1e300 run on the record",
            lambda: ekf(w_variance=1e300).run(r().u, r().y),
            "w_variance",
            accurate,
        ),
        Case(
            "ekf-wvar-shape",
            "EKF w_variance a (2, 2) matrix for nw = 1",
            lambda: ekf(w_variance=np.eye(2)),
            "w_variance",
        ),
        Case("ekf-P0-neg", "EKF P0 = -1", lambda: ekf(P0=-1.0), "P0"),
        Case(
            "ekf-P0-1e300", "EKF P0 = 1e300 run on the record", lambda: ekf(P0=1e300).run(r().u, r().y), "P0", accurate
        ),
        Case(
            "ekf-vcov-zero",
            "EKF v_covariance = 0 (exact outputs claimed) on noisy data",
            lambda: ekf(v_covariance=0.0).run(r().u, r().y),
            "v_covariance",
            finite_result,
        ),
        Case("ekf-input-model", "EKF input_model = 'brownian'", lambda: ekf(input_model="brownian"), "input_model"),
        Case("ekf-x0-bool", "EKF x0_prior = [True, True]", lambda: ekf(x0_prior=[True, True]), "x0_prior"),
        Case(
            "ekf-step-no-prior",
            "EKF without x0_prior: step()",
            lambda: EKF(s(), w_variance=1.0).step(None, [0.5]),
            "x0_prior",
        ),
        Case(
            "ekf-y-masked",
            "EKF.run with y masked at an outlier 1e6",
            lambda: ekf().run(
                r().u,
                np.ma.masked_array(
                    np.where(np.arange(41)[:, None] == 20, 1e6, r().y), mask=np.arange(41)[:, None] == 20
                ),
            ),
            r"\by\b|mask",
            accurate,
        ),
        Case("ukf-alpha-0", "UKF alpha = 0", lambda: UKF(s(), w_variance=1.0, alpha=0.0), "alpha"),
        Case("ukf-alpha-nan", "UKF alpha = NaN", lambda: UKF(s(), w_variance=1.0, alpha=math.nan), "alpha"),
        Case(
            "ukf-beta-inf",
            "UKF beta = inf run on the record",
            lambda: UKF(s(), w_variance=1.0, beta=math.inf, x0_prior=X0).run(r().u, r().y),
            "beta",
            finite_result,
        ),
        Case(
            "fit-grid-empty",
            "EKF.fit variances = []",
            lambda: EKF.fit(s(), r().u, r().y, x0_prior=X0, variances=[]),
            "variances",
        ),
        Case(
            "fit-grid-nan",
            "EKF.fit variances = [NaN, 1]",
            lambda: EKF.fit(s(), r().u, r().y, x0_prior=X0, variances=[math.nan, 1.0]),
            "variances",
        ),
        Case(
            "fit-grid-huge",
            "EKF.fit variances of 10**6 values",
            lambda: EKF.fit(s(), r().u, r().y, x0_prior=X0, variances=np.logspace(-6, 2, 10**6)),
            "variances",
        ),
        Case(
            "fit-models-bogus",
            "EKF.fit input_models = ['bogus']",
            lambda: EKF.fit(s(), r().u, r().y, x0_prior=X0, input_models=["bogus"]),
            "input_models|input_model",
        ),
        Case(
            "fit-prior-zero",
            "EKF.fit prior_factors = [0]",
            lambda: EKF.fit(s(), r().u, r().y, x0_prior=X0, prior_factors=[0.0]),
            "prior_factors",
        ),
        Case(
            "fit-all-missing",
            "UKF.fit on a record whose y is all NaN",
            lambda: UKF.fit(s(), r().u, np.full_like(r().y, np.nan), x0_prior=X0),
            r"\by\b|measurement",
        ),
        Case(
            "fit-one-sample",
            "EKF.fit on a one-sample record (K = 0)",
            lambda: EKF.fit(s(), np.zeros((0, 1)), r().y[:1], x0_prior=X0),
            r"\by\b|sample|record|variances",
        ),
        Case("fit-y-bool", "EKF.fit with a boolean y", lambda: EKF.fit(s(), r().u, r().y > 0.5, x0_prior=X0), r"\by\b"),
    ]


def design_cases() -> list[Case]:
    from uiest.design import design_uise
    from uiest.estimators import UISE

    s = system
    return [
        Case(
            "design-maxh-1e6",
            "UISE.design max_horizon = 10**6",
            lambda: UISE.design(s(), x0_prior=X0, max_horizon=10**6),
            "max_horizon",
        ),
        Case(
            "design-maxh-str",
            "UISE.design max_horizon = '30'",
            lambda: UISE.design(s(), x0_prior=X0, max_horizon="30"),
            "max_horizon",
        ),
        Case("design-rates-1.5", "design_uise rates = (1.5,)", lambda: design_uise(s(), X0, rates=(1.5,)), "rates"),
        Case(
            "design-rates-nan", "design_uise rates = (NaN,)", lambda: design_uise(s(), X0, rates=(math.nan,)), "rates"
        ),
        Case("design-budget-neg", "design_uise budget = -1", lambda: design_uise(s(), X0, budget=-1.0), "budget"),
        Case("design-trials-0", "design_uise trials = 0", lambda: design_uise(s(), X0, trials=0), "trials"),
        Case("design-steps-2", "design_uise steps = 2", lambda: design_uise(s(), X0, steps=2), "steps"),
        Case(
            "design-records-str",
            "design_uise records = ['a.csv']",
            lambda: design_uise(s(), X0, records=["a.csv"]),
            "records",
        ),
        Case(
            "design-x0-outside",
            "UISE.design x0_prior = [100, 100] (outside X)",
            lambda: UISE.design(s(), x0_prior=[100.0, 100.0]),
            "x0",
        ),
        Case(
            "design-colour",
            "UISE.design colour = 'red' (unknown option)",
            lambda: UISE.design(s(), x0_prior=X0, colour="red"),
            "colour",
        ),
        Case(
            "design-certify-typo",
            "design_uise certify_options = {'sample': 10}",
            lambda: design_uise(s(), X0, certify_options={"sample": 10}),
            "sample",
        ),
    ]


def certificate_cases() -> list[Case]:
    from uiest.detectability import (
        certify_delta_ioss,
        certify_reduced_ioss,
        certify_strong_detectability,
        linear_strong_detectability,
        window_information,
    )

    s, r = system, record
    return [
        Case(
            "cert-mu-nan",
            "certify_strong_detectability mu = NaN",
            lambda: certify_strong_detectability(s(), math.nan),
            "mu",
        ),
        Case(
            "cert-mu-tiny",
            "certify_strong_detectability mu = 1e-300",
            lambda: certify_strong_detectability(s(), 1e-300),
            "mu",
            lambda c: None if not c.certified or np.isfinite(c.min_horizon()) else "certified with no horizon",
        ),
        Case(
            "cert-maxcond-0",
            "max_condition = 0",
            lambda: certify_strong_detectability(s(), max_condition=0.0),
            "max_condition",
        ),
        Case(
            "cert-maxcond-nan",
            "max_condition = NaN",
            lambda: certify_strong_detectability(s(), max_condition=math.nan),
            "max_condition",
        ),
        Case("cert-tol-inf", "tol = inf", lambda: certify_strong_detectability(s(), tol=math.inf), "tol"),
        Case(
            "cert-samples-float", "samples = 100.5", lambda: certify_strong_detectability(s(), samples=100.5), "samples"
        ),
        Case("cert-cover-none", "cover = None", lambda: certify_strong_detectability(s(), cover=None), "cover"),
        Case("delta-eta-0", "certify_delta_ioss eta = 0", lambda: certify_delta_ioss(s(), 0.0), "eta"),
        Case("delta-eta-nan", "certify_delta_ioss eta = NaN", lambda: certify_delta_ioss(s(), math.nan), "eta"),
        Case(
            "delta-wspread-inf",
            "certify_delta_ioss w_spread = inf",
            lambda: certify_delta_ioss(s(), w_spread=math.inf),
            "w_spread",
        ),
        Case(
            "delta-maxcond-neg",
            "certify_delta_ioss max_condition = -1",
            lambda: certify_delta_ioss(s(), max_condition=-1.0),
            "max_condition",
        ),
        Case(
            "delta-wbounds-pairs",
            "certify_delta_ioss w_bounds = ((0, 1), (2, 3)) for nw = 1",
            lambda: certify_delta_ioss(s(), w_bounds=((0.0, 1.0), (2.0, 3.0))),
            "w_bounds",
        ),
        Case(
            "delta-structure-none",
            "certify_delta_ioss structure = None",
            lambda: certify_delta_ioss(s(), structure=None),
            "structure",
        ),
        Case(
            "reduced-bounds-swapped",
            "certify_reduced_ioss z_bounds = (1, 0)",
            lambda: certify_reduced_ioss(
                *_reduced_functions(), z_bounds=(1.0, 0.0), gamma_bounds=(0, 1), v_bounds=(0, 1)
            ),
            "z_bounds",
        ),
        Case(
            "hautus-B-none",
            "linear_strong_detectability B = None",
            lambda: linear_strong_detectability(np.eye(2) * 0.5, None, [[1, 0]]),
            r"\bB\b",
        ),
        Case(
            "verify-str",
            "verify(n_pairs='10')",
            lambda: linear_strong_detectability(np.eye(2) * 0.5, [[1], [0]], [[1, 0]]).verify("10"),
            "n_pairs",
        ),
        Case(
            "info-N-0",
            "window_information N = 0",
            lambda: window_information(s(), r().x, r().u, r().w, k=10, N=0, noise_std=0.01),
            r"\bN\b",
        ),
        Case(
            "info-k-beyond",
            "window_information k = 500 on a 40-step record",
            lambda: window_information(s(), r().x, r().u, r().w, k=500, N=3, noise_std=0.01),
            r"\bk\b",
        ),
        Case(
            "info-noise-neg",
            "window_information noise_std = -0.01",
            lambda: window_information(s(), r().x, r().u, r().w, k=10, N=3, noise_std=-0.01),
            "noise_std",
        ),
    ]


def double_integrator() -> Any:
    """x1+ = x1 + x2, x2+ = x2 + w, y = x1 + v: the unknown input has relative degree 2."""
    return callables(f=lambda x, u, w: [x[0] + 0.1 * x[1], 0.9 * x[1] + w[0]], v_bounds=(-0.01, 0.01))


def _reduced_functions() -> tuple[Any, Any]:
    from uiest.models import closed_form

    red = closed_form.reduction()
    return red.f_sharp, red.h_sharp


def analyse_cases() -> list[Case]:
    from uiest.analysis import analyse

    s = system
    return [
        Case(
            "analyse-x0-masked",
            "analyse x0 a masked array",
            lambda: analyse(s(), x0=np.ma.masked_array(X0, mask=[True, False])),
            "x0",
        ),
        Case(
            "analyse-maxh-huge", "analyse max_horizon = 10**7", lambda: analyse(s(), max_horizon=10**7), "max_horizon"
        ),
        Case("analyse-points-huge", "analyse points = 10**9", lambda: analyse(s(), points=10**9), "points"),
        Case("analyse-points-float", "analyse points = 1.5", lambda: analyse(s(), points=1.5), "points"),
        Case("analyse-seed-str", "analyse seed = 'x'", lambda: analyse(s(), seed="x"), "seed"),
        Case(
            "analyse-x0-outside", "analyse x0 = [100, 100] (outside X)", lambda: analyse(s(), x0=[100.0, 100.0]), "x0"
        ),
        Case("analyse-trajectory", "analyse(a Trajectory)", lambda: analyse(record()), "system"),
    ]


def record_cases() -> list[Case]:
    import pandas as pd

    from uiest import Trajectory

    s = system

    def drop(rows: tuple[int, ...], keep: tuple[str, ...] = ("u", "y")) -> Path:
        data = record().to_pandas().reset_index(drop=True)[list(keep)].drop(index=list(rows))
        path = here() / "dropped.csv"
        data.to_csv(path, index=False)
        return path

    def parquet(frame_: Any, name: str = "data.parquet") -> Path:
        path = here() / name
        frame_.to_parquet(path)
        return path

    def bool_parquet() -> Path:
        data = record().to_pandas()
        data["y"] = data["y"] > 0.5
        return parquet(data)

    def corrupt_parquet() -> Path:
        path = parquet(record().to_pandas())
        raw = bytearray(path.read_bytes())
        raw[len(raw) // 2 : len(raw) // 2 + 40] = b"\x00" * 40
        path.write_bytes(bytes(raw))
        return path

    def parquet_named_csv() -> Path:
        path = parquet(record().to_pandas(), "data.csv")
        return path

    full = record().steps
    return [
        Case("rec-path-int", "read_record(12345, system)", lambda: read(12345), "data|path"),
        Case("rec-path-none", "read_record(None, system)", lambda: read(None), "data|path"),
        Case("rec-path-dir", "read_record(a folder)", lambda: read(here()), "data|folder|file"),
        Case("rec-path-txt", "read_record(data.txt)", lambda: read(write("data.txt", "u,y\n0,1\n")), "data"),
        Case(
            "rec-system-str",
            "read_record(path, 'closed-form')",
            lambda: __import__("uiest.results", fromlist=["read_record"]).read_record(record_csv(), "closed-form"),
            "system",
        ),
        Case("rec-csv-empty", "an empty CSV file", lambda: read(write("e.csv", "")), "data"),
        Case("rec-csv-header", "a CSV with only its header", lambda: read(write("h.csv", "k,u,y\n")), "data|row"),
        Case(
            "rec-csv-bool",
            "a CSV whose y column is True/False",
            lambda: read(record_csv(frame=frame(y=record().y[:, 0] > 0.5))),
            r"\by\b|bool",
        ),
        Case(
            "rec-csv-ystr",
            "a CSV whose y column has the word 'abc' in one row",
            lambda: read(record_csv(frame=frame(y=["abc", *list(record().y[1:, 0])]))),
            r"\by\b",
        ),
        Case(
            "rec-csv-yinf",
            "a CSV with y = inf in one row, read and run by a UISE",
            lambda: (lambda t: uise().run(t.u, t.y))(
                read(record_csv(frame=frame(y=[np.inf, *list(record().y[1:, 0])])))
            ),
            r"\by\b|inf",
            lambda res: "inf in y estimated from without error",
        ),
        Case(
            "rec-csv-u-gap",
            "a CSV with u empty in row 5",
            lambda: read(record_csv(frame=frame(u=[np.nan if i == 5 else 0.0 for i in range(41)]))),
            r"\bu\b",
        ),
        Case(
            "rec-csv-dropped",
            "a CSV of u, y without k or t, rows 10-19 dropped",
            lambda: read(drop(tuple(range(10, 20)))),
            "contiguous",
            has_missing(tuple(range(10, 20)), full),
            warning_suffices=True,
        ),
        Case(
            "rec-csv-k-gap",
            "a CSV with k and rows 10-19 dropped",
            lambda: read(drop(tuple(range(10, 20)), keep=("u", "y")) if False else _k_gap()),
            r"\bk\b",
            has_missing(tuple(range(10, 20)), full),
        ),
        Case(
            "rec-csv-k-float",
            "a CSV whose k column is 0.0, 0.5, 1.0, ...",
            lambda: read(_k_column(np.arange(41) * 0.5)),
            r"\bk\b",
        ),
        Case(
            "rec-csv-k-str",
            "a CSV whose k column is words",
            lambda: read(_k_column([f"row{i}" for i in range(41)])),
            r"\bk\b",
        ),
        Case(
            "rec-csv-t-dates",
            "a CSV with t as ISO timestamps",
            lambda: read(record_csv(frame=frame(t=pd.date_range("2024-01-01", periods=41, freq="s").astype(str)))),
            r"\bt\b",
        ),
        Case(
            "rec-csv-t-reversed",
            "a CSV with t decreasing",
            lambda: read(record_csv(frame=frame(t=np.arange(41.0)[::-1]))),
            r"\bt\b",
        ),
        Case(
            "rec-csv-dup-col",
            "a CSV with two y columns",
            lambda: read(write("dup.csv", "u,y,y\n" + "0,0.5,0.6\n" * 5)),
            r"\by\b|duplicate",
        ),
        Case(
            "rec-csv-semicolon",
            "a CSV separated by ';'",
            lambda: read(write("semi.csv", "u;y\n" + "0;0.5\n" * 5)),
            r"\by\b|column|separat",
        ),
        Case("rec-csv-latin1", "a CSV in Latin-1 with a non-ASCII header", lambda: read(_latin1()), "data|column"),
        Case(
            "rec-csv-extra-k-repeat",
            "a CSV with k repeated (0, 0, 1, ...)",
            lambda: read(_k_column([0, *list(range(40))])),
            r"\bk\b",
        ),
        Case("rec-parquet-bool", "a Parquet file whose y column is bool", lambda: read(bool_parquet()), r"\by\b|bool"),
        Case(
            "rec-parquet-corrupt",
            "a Parquet file with 40 zeroed bytes in the middle",
            lambda: read(corrupt_parquet()),
            "data",
            lambda t: None if np.allclose(t.y, record().y, equal_nan=True) else "damaged data read as numbers",
        ),
        Case("rec-parquet-as-csv", "a Parquet file named data.csv", lambda: read(parquet_named_csv()), "data"),
        Case(
            "pandas-series",
            "Trajectory.from_pandas(a Series)",
            lambda: Trajectory.from_pandas(record().to_pandas()["y"], s()),
            "frame",
        ),
        Case(
            "pandas-nullable",
            "from_pandas with y a nullable Float64 column holding pd.NA",
            lambda: Trajectory.from_pandas(frame(y=pd.array([pd.NA, *list(record().y[1:, 0])], dtype="Float64")), s()),
            r"\by\b",
            lambda t: None if np.isnan(t.y[0, 0]) and np.isfinite(t.y[1:]).all() else "NA misread",
        ),
        Case(
            "pandas-categorical",
            "from_pandas with y a categorical column",
            lambda: Trajectory.from_pandas(frame(y=pd.Categorical(record().y[:, 0].round(1))), s()),
            r"\by\b",
            lambda t: None if np.allclose(t.y[:, 0], record().y[:, 0].round(1)) else "categories misread",
        ),
        Case(
            "pandas-multiindex",
            "from_pandas with MultiIndex columns",
            lambda: Trajectory.from_pandas(_multi(), s()),
            "frame|column",
            lambda t: None if np.allclose(t.y, record().y) else "y misread",
        ),
        Case(
            "pandas-y-object",
            "from_pandas with y an object column mixing floats and None",
            lambda: Trajectory.from_pandas(frame(y=[None, *list(record().y[1:, 0])]), s()),
            r"\by\b",
            lambda t: None if np.isnan(t.y[0, 0]) and np.isfinite(t.y[1:]).all() else "None misread",
        ),
        Case(
            "pandas-complex",
            "from_pandas with a complex y column",
            lambda: Trajectory.from_pandas(frame(y=record().y[:, 0] + 1j), s()),
            r"\by\b",
        ),
    ]


def _k_column(values: Any) -> Path:
    data = record().to_pandas().reset_index(drop=True)[["u", "y"]]
    data.insert(0, "k", values)
    path = here() / "k.csv"
    data.to_csv(path, index=False)
    return path


def _k_gap() -> Path:
    data = record().to_pandas()[["u", "y"]].drop(index=list(range(10, 20)))
    path = here() / "kgap.csv"
    data.to_csv(path)
    return path


def _latin1() -> Path:
    path = here() / "latin.csv"
    path.write_bytes("u,y,temp\xe9rature\n0,0.5,1\n0,0.6,1\n".encode("latin-1"))
    return path


def _multi() -> Any:
    import pandas as pd

    data = record().to_pandas()
    data.columns = pd.MultiIndex.from_tuples([(c, "") for c in data.columns])
    return data


def scenario(**changes: Any) -> Any:
    from uiest.experiments import EstimatorSpec, Scenario

    base = {"name": "tiny", "model": "closed-form", "steps": 12, "runs": 1, "cases": ("noisy",), "settle": 2,
            "estimators": (EstimatorSpec("UISE", "uise", N=3, mu=0.64, output_weight=1e4),)}  # fmt: skip
    return Scenario(**{**base, **changes})


def study_cases() -> list[Case]:
    from uiest.experiments import EstimatorSpec, Scenario, run_study, write_report

    def study_ok(result: Any) -> str | None:
        return None if result is not None else "no study"

    def report_named(name: str) -> Any:
        out = here() / "out" / "report"
        write_report(run_study(scenario(name=name), solver="gn"), out, wall_time=1.0)
        return out

    def escapes(result: Any) -> str | None:
        inside = here() / "out" / "report"
        outside = [p for p in here().rglob("*") if p.is_file() and inside not in p.parents]
        return f"wrote {len(outside)} files outside the output folder, e.g. {outside[0]}" if outside else None

    def report_spec(name: str) -> Any:
        out = here() / "out" / "report"
        spec = (EstimatorSpec(name, "uise", N=3, mu=0.64, output_weight=1e4),)
        write_report(run_study(scenario(estimators=spec), solver="gn"), out, wall_time=1.0)
        return out

    def from_toml(text: str) -> Any:
        return Scenario.from_toml(write("s.toml", text))

    toml_head = "name = 'x'\nmodel = 'closed-form'\nsteps = 12\nruns = 1\nsettle = 2\ncases = ['noisy']\n"
    est = "[[estimators]]\nname = 'U'\nkind = 'uise'\nN = 3\n"
    return [
        Case("study-workers-str", "run_study(workers='2')", lambda: run_study(scenario(), workers="2"), "workers"),
        Case(
            "study-progress-str", "run_study(progress='yes')", lambda: run_study(scenario(), progress="yes"), "progress"
        ),
        Case("study-workers-0", "run_study(workers=0)", lambda: run_study(scenario(), workers=0), "workers"),
        Case("study-workers-neg", "run_study(workers=-5)", lambda: run_study(scenario(), workers=-5), "workers"),
        Case(
            "study-model-str",
            "run_study(model='closed-form') (a name, not an entry)",
            lambda: run_study(scenario(), model="closed-form"),
            "model",
            study_ok,
        ),
        Case("study-scenario-dict", "run_study(a dict)", lambda: run_study({"name": "x"}), "scenario"),
        Case(
            "study-name-dotdot",
            "Scenario name '../escaped' written by write_report",
            lambda: report_named("../escaped"),
            "name",
            escapes,
        ),
        Case(
            "study-name-abs",
            "Scenario name '/tmp/abs-escape' written by write_report",
            lambda: report_named(str(here() / "abs-escape")),
            "name",
            escapes,
        ),
        Case("study-name-empty", "Scenario name ''", lambda: scenario(name=""), "name"),
        Case(
            "study-steps-huge",
            "run_study of a Scenario with steps = 10**9",
            lambda: run_study(scenario(steps=10**9), solver="gn"),
            "steps",
        ),
        Case(
            "study-runs-huge",
            "run_study of a Scenario with runs = 10**8",
            lambda: run_study(scenario(runs=10**8), solver="gn"),
            "runs",
        ),
        Case("study-x0-nan", "Scenario x0 = (NaN, 1)", lambda: run_study(scenario(x0=(math.nan, 1.0))), "x0"),
        Case("study-noise-nan", "Scenario noise_scale = NaN", lambda: scenario(noise_scale=math.nan), "noise_scale"),
        Case("study-settle-neg", "Scenario settle = -1", lambda: scenario(settle=-1), "settle"),
        Case(
            "spec-N-huge",
            "run_study with EstimatorSpec N = 10**7 on 12 steps",
            lambda: run_study(
                scenario(estimators=(EstimatorSpec("u", "uise", N=10**7, mu=0.64, output_weight=1e4),)), solver="gn"
            ),
            r"\bN\b",
            study_ok,
        ),
        Case("spec-mu-nan", "EstimatorSpec mu = NaN", lambda: EstimatorSpec("u", "uise", mu=math.nan), "mu"),
        Case(
            "spec-wvar-neg",
            "EstimatorSpec w_variance = -1",
            lambda: EstimatorSpec("u", "ekf", w_variance=-1.0),
            "w_variance",
        ),
        Case(
            "spec-output-inf",
            "EstimatorSpec output_weight = inf",
            lambda: EstimatorSpec("u", "uise", output_weight=math.inf),
            "output_weight",
        ),
        Case(
            "spec-name-dotdot",
            "an estimator named '../../b' in a study written by write_report",
            lambda: report_spec("../../b"),
            "name",
            escapes,
        ),
        Case(
            "toml-dup-key",
            "a scenario TOML with 'steps' twice",
            lambda: from_toml(toml_head + "steps = 5\n" + est),
            "steps|cannot read|duplicate",
        ),
        Case(
            "toml-steps-str",
            "a scenario TOML with steps = 'ten'",
            lambda: from_toml(toml_head.replace("steps = 12", "steps = 'ten'") + est),
            "steps",
        ),
        Case(
            "toml-estimators-table",
            "a scenario TOML with [estimators] a table, not an array",
            lambda: from_toml(toml_head + "[estimators]\nname = 'U'\nkind = 'uise'\n"),
            "estimators",
        ),
        Case("toml-folder", "Scenario.from_toml(a folder)", lambda: Scenario.from_toml(here()), "cannot read|folder"),
        Case(
            "toml-model-missing",
            "a scenario naming model = 'nowhere.py'",
            lambda: run_study(from_toml(toml_head.replace("closed-form", "nowhere.py") + est)),
            "model",
        ),
        Case(
            "toml-model-raises",
            "a scenario whose model file raises at import",
            lambda: run_study(
                from_toml(
                    toml_head.replace("closed-form", str(model_file("bad_model.py", "raise RuntimeError('boom')\n")))
                    + est
                )
            ),
            "model",
        ),
        Case(
            "toml-model-sysexit",
            "a scenario whose model file calls sys.exit(3) at import",
            lambda: run_study(
                from_toml(
                    toml_head.replace("closed-form", str(model_file("exit_model.py", "import sys\nsys.exit(3)\n")))
                    + est
                )
            ),
            "model|exit",
        ),
        Case(
            "model-builtin-name",
            "a model file named closed-form.py, then the built-in by name",
            _shadow_builtin,
            "closed-form|name",
            lambda name: None if name == "closed-form" else f"the built-in 'closed-form' is now {name!r}",
        ),
        Case(
            "model-syntax",
            "load() of a model file with a syntax error",
            lambda: __import__("uiest.models", fromlist=["load"]).load(str(model_file("syn.py", "def (:\n"))),
            "model|syntax",
        ),
        Case(
            "model-build-none",
            "a model file whose build() returns None",
            lambda: (
                __import__("uiest.models", fromlist=["load"])
                .load(str(model_file("nobuild.py", "def build():\n    return None\n")))
                .build()
            ),
            "build",
        ),
        Case(
            "report-walltime-nan",
            "write_report wall_time = NaN",
            lambda: write_report(run_study(scenario(), solver="gn"), here() / "r", wall_time=math.nan),
            "wall_time",
        ),
        Case(
            "report-study-none", "write_report(None)", lambda: write_report(None, here() / "r", wall_time=1.0), "study"
        ),
    ]


def _shadow_builtin() -> str:
    from uiest import models

    models.load(str(write("closed-form.py", GOOD_MODEL.format(gain=0.5))))
    return models.get("closed-form").build().name


def sweep_cases() -> list[Case]:
    from uiest.experiments.sweep import sweep
    from uiest.experiments.sweep_design import Sweep

    def tiny() -> Any:
        return Sweep(scenario(), grid={"N": (2, 3)})

    def stale() -> Any:
        from uiest.experiments import EstimatorSpec

        path = model_file("gainy.py", GOOD_MODEL.format(gain=0.5))
        spec = (EstimatorSpec("EKF", "ekf", w_variance=1.0),)
        design = Sweep(scenario(model=str(path), steps=12, estimators=spec), grid={"noise_scale": (1.0,)})
        first = sweep(design, here() / "out", workers=1)
        path.write_text(GOOD_MODEL.format(gain=1.5))
        second = sweep(design, here() / "out", workers=1)
        return first, second

    def fresh_rows(pair: Any) -> str | None:
        first, second = pair
        numeric = first.select_dtypes("number").columns
        if first[numeric].equals(second[numeric]):
            return "the model file was edited (gain 0.5 -> 1.5) but the resumed sweep returned the old rows"
        return None

    return [
        Case("sweep-grid-N-huge", "Sweep grid N = [10**6]", lambda: Sweep(scenario(), grid={"N": (10**6,)}), r"\bN\b"),
        Case("sweep-grid-mu-nan", "Sweep grid mu = [NaN]", lambda: Sweep(scenario(), grid={"mu": (math.nan,)}), "mu"),
        Case("sweep-grid-bool", "Sweep grid N = [True]", lambda: Sweep(scenario(), grid={"N": (True,)}), r"\bN\b"),
        Case(
            "sweep-ranges-mu-01",
            "Sweep ranges mu = (0, 1)",
            lambda: Sweep(scenario(), random=2, ranges={"mu": (0.0, 1.0)}),
            "mu",
        ),
        Case(
            "sweep-ranges-steps-huge",
            "Sweep ranges steps = (1e9, 1e9)",
            lambda: Sweep(scenario(), random=1, ranges={"steps": (1e9, 1e9)}),
            "steps",
        ),
        Case(
            "sweep-out-file",
            "sweep(out = an existing file)",
            lambda: sweep(tiny(), write("outfile", "x"), workers=1),
            "out|folder",
        ),
        Case(
            "sweep-max-tasks-neg",
            "sweep(max_tasks=-1)",
            lambda: sweep(tiny(), here() / "o", workers=1, max_tasks=-1),
            "max_tasks",
        ),
        Case(
            "sweep-scheduler-garbage",
            "sweep(scheduler='garbage')",
            lambda: sweep(tiny(), here() / "o", scheduler="garbage"),
            "scheduler",
        ),
        Case(
            "sweep-retry-str",
            "sweep(retry_failed='yes')",
            lambda: sweep(tiny(), here() / "o", workers=1, retry_failed="yes"),
            "retry_failed",
        ),
        Case(
            "sweep-workers-huge",
            "sweep(workers=10**6)",
            lambda: sweep(tiny(), here() / "o", workers=10**6),
            "workers",
            lambda rows: None if len(rows) == 2 and (rows["error"] == "").all() else f"{len(rows)} rows",
        ),
        Case(
            "sweep-stale",
            "a sweep of a model file, the file's gain edited 0.5 -> 1.5, resumed",
            stale,
            "model",
            fresh_rows,
        ),
        Case(
            "sweep-toml-name-dotdot",
            "a sweep file with scenario name '../up'",
            lambda: sweep(
                Sweep.from_toml(
                    write(
                        "sw.toml",
                        "[scenario]\nname = '../up'\nmodel = 'closed-form'\n"
                        "steps = 12\nruns = 1\ncases = ['noisy']\nsettle = 2\n"
                        "[[scenario.estimators]]\nname = 'U'\nkind = 'uise'\nN = 3\n"
                        "[sweep]\ngrid = {N = [3]}\n",
                    )
                ),
                here() / "o" / "sweep",
                workers=1,
            ),
            "name",
            lambda _: _outside(here() / "o" / "sweep"),
        ),
    ]


def _outside(inside: Path) -> str | None:
    stray = [p for p in here().rglob("*") if p.is_file() and inside not in p.parents and p.suffix != ".toml"]
    return f"wrote {len(stray)} files outside the output folder, e.g. {stray[0].relative_to(here())}" if stray else None


def plot_cases() -> list[Case]:
    from uiest.plotting import plot_estimates, plot_record, plot_trajectory, save_figure

    r = record
    return [
        Case("plot-traj-none", "plot_trajectory(None)", lambda: plot_trajectory(None), "traj"),
        Case(
            "plot-units-int",
            "plot_trajectory units = {'x': (1, 2)}",
            lambda: plot_trajectory(r(), units={"x": (1, 2)}),
            "units",
            lambda fig: None,
        ),
        Case(
            "plot-units-key",
            "plot_trajectory units = {'q': ('m',)}",
            lambda: plot_trajectory(r(), units={"q": ("m",)}),
            "units|q",
        ),
        Case(
            "plot-log-str",
            "plot_estimates log_error = 'no'",
            lambda: plot_estimates(r(), {"u": uise().run(r().u, r().y)}, log_error="no"),
            "log_error",
        ),
        Case(
            "plot-estimates-empty",
            "plot_estimates(traj, {})",
            lambda: plot_estimates(r(), {}),
            "results",
            lambda fig: None,
        ),
        Case(
            "plot-record-system-str",
            "plot_record('closed-form', ...)",
            lambda: plot_record("closed-form", r(), {"u": uise().run(r().u, r().y)}),
            "system",
        ),
        Case("save-none", "save_figure(None, 'f.png')", lambda: save_figure(None, here() / "f.png"), "fig"),
        Case(
            "save-no-suffix",
            "save_figure(fig, 'figure') (no suffix)",
            lambda: save_figure(plot_trajectory(r()), here() / "figure"),
            "path",
            lambda p: None if Path(p).exists() else "no file written",
        ),
        Case(
            "save-dir",
            "save_figure(fig, an existing folder)",
            lambda: save_figure(plot_trajectory(r()), _dir_named("f.png")),
            "path|folder",
        ),
    ]


def _dir_named(name: str) -> Path:
    path = here() / name
    path.mkdir()
    return path


def cli_cases() -> list[Case]:
    def est(*args: str, data: Any = None) -> CliResult:
        return cli("estimate", "closed-form", "--data", data or record_csv(), "--out", here() / "out", *args)

    def written(result: CliResult) -> str | None:
        return None if (here() / "out").exists() and any((here() / "out").iterdir()) else "exit 0, nothing written"

    def lag_columns(result: CliResult) -> str | None:
        import pandas as pd

        files = list((here() / "out").glob("estimates_*.csv"))
        if not files:
            return "no estimates written"
        data = pd.read_csv(files[0])
        lagged = [c for c in data.columns if c.endswith("_lag")]
        if lagged and data[lagged].isna().all().all():
            return "the lag columns are all NaN"
        return None

    def scenario_file(name: str = "x", model: str = "closed-form", extra: str = "") -> Path:
        return write("s.toml", f"name = '{name}'\nmodel = '{model}'\nsteps = 12\nruns = 1\nsettle = 2\n"
                                f"cases = ['noisy']\n{extra}[[estimators]]\nname = 'U'\nkind = 'uise'\nN = 3\n"
                                "mu = 0.64\n")  # fmt: skip

    def sweep_file(grid: str) -> Path:
        return write("sw.toml", "[scenario]\nname = 'x'\nmodel = 'closed-form'\nsteps = 12\nruns = 1\nsettle = 2\n"
                                "cases = ['noisy']\n[[scenario.estimators]]\nname = 'U'\nkind = 'uise'\nN = 3\n"
                                f"[sweep]\n{grid}\n")  # fmt: skip

    bool_csv = lambda: record_csv(frame=frame(y=record().y[:, 0] > 0.5))  # noqa: E731
    return [
        Case(
            "cli-sim-steps-huge",
            "uiest simulate closed-form --steps 1000000000",
            lambda: cli("simulate", "closed-form", "--steps", "1000000000", "--out", "o"),
            "--steps",
        ),
        Case(
            "cli-sim-out-file",
            "uiest simulate --out an existing file",
            lambda: cli("simulate", "closed-form", "--out", write("afile", "x")),
            "--out|folder",
        ),
        Case(
            "cli-sim-model-syntax",
            "uiest simulate with a model file with a syntax error",
            lambda: cli("simulate", model_file("syn.py", "def (:\n"), "--out", "o"),
            "model|syntax",
        ),
        Case(
            "cli-sim-model-sysexit",
            "uiest simulate with a model file calling sys.exit() at import",
            lambda: cli("simulate", model_file("ex.py", "import sys\nsys.exit()\n"), "--out", "o"),
            "model|exit",
        ),
        Case(
            "cli-sim-model-nosystem",
            "uiest simulate with a model file defining nothing",
            lambda: cli("simulate", model_file("empty_model.py", "x = 1\n"), "--out", "o"),
            "system|build",
        ),
        Case(
            "cli-sim-model-dir",
            "uiest simulate with a folder named m.py",
            lambda: cli("simulate", _dir_named("m.py"), "--out", "o"),
            "model",
        ),
        Case("cli-est-data-missing", "uiest estimate --data nowhere.csv", lambda: est(data=here() / "no.csv"), "data"),
        Case("cli-est-data-dir", "uiest estimate --data a folder", lambda: est(data=_dir_named("d.csv")), "data"),
        Case(
            "cli-est-data-bool",
            "uiest estimate --data a CSV with boolean y",
            lambda: est(data=bool_csv()),
            r"\by\b|bool",
        ),
        Case(
            "cli-est-lag-horizon",
            "uiest estimate --estimator uise --horizon 5 --lag 1000",
            lambda: est("--estimator", "uise", "--horizon", "5", "--lag", "1000"),
            "--lag",
            lag_columns,
        ),
        Case(
            "cli-est-horizon-huge",
            "uiest estimate --estimator uise --horizon 1000000",
            lambda: est("--estimator", "uise", "--horizon", "1000000"),
            "--horizon",
        ),
        Case("cli-est-horizon-0", "uiest estimate --horizon 0", lambda: est("--horizon", "0"), "--horizon"),
        Case(
            "cli-est-wvar-nan",
            "uiest estimate --estimator ekf --w-variance nan",
            lambda: est("--estimator", "ekf", "--w-variance", "nan"),
            "--w-variance",
        ),
        Case(
            "cli-est-wvar-inf",
            "uiest estimate --estimator ekf --w-variance inf",
            lambda: est("--estimator", "ekf", "--w-variance", "inf"),
            "--w-variance",
        ),
        Case("cli-est-x0-len", "uiest estimate --x0 1,2,3", lambda: est("--estimator", "ekf", "--x0", "1,2,3"), "--x0"),
        Case("cli-est-x0-nan", "uiest estimate --x0 nan,1", lambda: est("--estimator", "ekf", "--x0", "nan,1"), "--x0"),
        Case("cli-est-x0-empty", "uiest estimate --x0 ''", lambda: est("--estimator", "ekf", "--x0", ""), "--x0"),
        Case(
            "cli-est-kind",
            "uiest estimate --estimator kalman",
            lambda: est("--estimator", "kalman"),
            "--estimator|kalman",
        ),
        Case(
            "cli-est-twice",
            "uiest estimate --estimator ekf --estimator ekf",
            lambda: est("--estimator", "ekf", "--estimator", "ekf", "--w-variance", "1"),
            "--estimator",
            written,
        ),
        Case(
            "cli-est-parquet-corrupt",
            "uiest estimate --data a damaged Parquet file",
            lambda: est(data=write("bad.parquet", "PAR1 not really")),
            "data",
        ),
        Case(
            "cli-est-dropped-rows",
            "uiest estimate --data a u,y CSV with rows 10-19 dropped (no k, no t)",
            lambda: _est_dropped(est),
            "contiguous|gap|missing",
            lambda res: _says_contiguous(res),
        ),
        Case("cli-est-data-ext", "uiest estimate --data data.xlsx", lambda: est(data=write("d.xlsx", "x")), "data"),
        Case(
            "cli-est-model-other",
            "uiest estimate crop-growth --data a closed-form record",
            lambda: cli("estimate", "crop-growth", "--data", record_csv(), "--out", "o"),
            "column|data",
        ),
        Case(
            "cli-cert-verify-neg",
            "uiest certify --verify -1",
            lambda: cli("certify", "closed-form", "--verify", "-1"),
            "--verify",
        ),
        Case(
            "cli-cert-structure-empty",
            "uiest certify --structure ''",
            lambda: cli("certify", "closed-form", "--structure", ""),
            "--structure",
        ),
        Case(
            "cli-cert-model-raises",
            "uiest certify a model file whose build() raises",
            lambda: cli("certify", model_file("rb.py", "def build():\n    raise ValueError('no')\n")),
            "model|build",
        ),
        Case(
            "cli-analyse-maxh-huge",
            "uiest analyse --max-horizon 10000000",
            lambda: cli("analyse", "closed-form", "--max-horizon", "10000000"),
            "--max-horizon",
        ),
        Case(
            "cli-analyse-json-dir",
            "uiest analyse --json an existing folder",
            lambda: cli("analyse", "closed-form", "--json", here()),
            "--json|folder",
        ),
        Case(
            "cli-analyse-shadow",
            "uiest analyse closed-form.py (a model file named like a built-in), then "
            "uiest analyse closed-form in the same process",
            lambda: (
                cli("analyse", write("closed-form.py", GOOD_MODEL.format(gain=0.5))),
                cli("analyse", "closed-form"),
            )[1],
            "closed-form|name",
            lambda res: "the built-in closed-form now runs the user's file" if "gainy" in res.text else None,
        ),
        Case(
            "cli-repro-default-out",
            "uiest reproduce --scenario with name = '../escaped' and the default --out",
            lambda: cli(
                "reproduce", "--scenario", scenario_file(name="../escaped"), "--workers", "1", "--solver", "gn"
            ),
            "name",
            lambda _: _outside(here() / "out"),
        ),
        Case(
            "cli-repro-runs-huge",
            "uiest reproduce --runs 100000000 --steps 5",
            lambda: cli("reproduce", "--scenario", scenario_file(), "--runs", "100000000", "--out", "o"),
            "--runs",
        ),
        Case(
            "cli-repro-steps-huge",
            "uiest reproduce --steps 1000000000",
            lambda: cli("reproduce", "--scenario", scenario_file(), "--steps", "1000000000", "--out", "o"),
            "--steps",
        ),
        Case(
            "cli-repro-workers-0",
            "uiest reproduce --workers 0",
            lambda: cli("reproduce", "--scenario", scenario_file(), "--workers", "0", "--out", "o"),
            "--workers",
        ),
        Case(
            "cli-repro-workers-neg",
            "uiest reproduce --workers -3",
            lambda: cli("reproduce", "--scenario", scenario_file(), "--workers", "-3", "--out", "o"),
            "--workers",
        ),
        Case(
            "cli-repro-name-dotdot",
            "uiest reproduce --scenario with name = '../escaped'",
            lambda: cli(
                "reproduce",
                "--scenario",
                scenario_file(name="../escaped"),
                "--out",
                here() / "o" / "r",
                "--workers",
                "1",
                "--solver",
                "gn",
            ),
            "name",
            lambda _: _outside(here() / "o" / "r"),
        ),
        Case(
            "cli-repro-dup-key",
            "uiest reproduce --scenario with a key given twice",
            lambda: cli("reproduce", "--scenario", write("d.toml", "name = 'a'\nname = 'b'\n"), "--out", "o"),
            "cannot read|name|duplicate",
        ),
        Case(
            "cli-repro-model-missing",
            "uiest reproduce --scenario naming model = 'gone.py'",
            lambda: cli("reproduce", "--scenario", scenario_file(model="gone.py"), "--out", "o"),
            "model",
        ),
        Case(
            "cli-repro-model-relative",
            "a scenario in sub/ naming model = 'm.py' that sits in sub/",
            _relative_model,
            "model",
            lambda res: None,
            error_ok=False,
        ),
        Case(
            "cli-repro-x0-str",
            "uiest reproduce --scenario with x0 = 'abc'",
            lambda: cli("reproduce", "--scenario", scenario_file(extra="x0 = 'abc'\n"), "--out", "o"),
            "x0",
        ),
        Case(
            "cli-sweep-N-huge",
            "uiest sweep with grid N = [1000000]",
            lambda: cli("sweep", sweep_file("grid = {N = [1000000]}"), "--out", "o", "--workers", "1"),
            r"\bN\b",
        ),
        Case(
            "cli-sweep-workers-huge",
            "uiest sweep --workers 1000000",
            lambda: cli("sweep", sweep_file("grid = {N = [3]}"), "--out", "o", "--workers", "1000000"),
            "--workers",
            files_written("o/results.parquet"),
        ),
        Case(
            "cli-sweep-grid-bool",
            "uiest sweep with grid mu = [true]",
            lambda: cli("sweep", sweep_file("grid = {mu = [true]}"), "--out", "o", "--workers", "1"),
            "mu",
        ),
        Case(
            "cli-sweep-toml-bad",
            "uiest sweep a file that is not TOML (unbalanced quote)",
            lambda: cli("sweep", write("q.toml", "[scenario]\nname = 'x\n"), "--out", "o"),
            "cannot read|toml",
        ),
        Case(
            "cli-sweep-out-file",
            "uiest sweep --out an existing file",
            lambda: cli("sweep", sweep_file("grid = {N = [3]}"), "--out", write("f", "x"), "--workers", "1"),
            "--out|folder",
        ),
        Case("cli-bench-N-0", "uiest bench -N 0", lambda: cli("bench", "--quick", "-N", "0"), "-N|--horizon"),
        Case("cli-bench-N-huge", "uiest bench -N 100000", lambda: cli("bench", "-N", "100000"), "-N|--horizon"),
        Case(
            "cli-bench-estimator",
            "uiest bench --estimator Kalman",
            lambda: cli("bench", "--quick", "--estimator", "Kalman"),
            "--estimator|Kalman",
        ),
        Case("cli-models-arg", "uiest models extra", lambda: cli("models", "extra"), "extra|argument"),
        Case(
            "cli-est-concurrent",
            "two uiest estimate into one --out at once",
            _concurrent_estimates,
            "--out|lock|in use",
            lambda pair: "both runs exit 0 writing one folder (last writer wins)",
        ),
    ]


def _est_dropped(est: Callable[..., CliResult]) -> CliResult:
    data = record().to_pandas().reset_index(drop=True)[["u", "y"]].drop(index=list(range(10, 20)))
    path = here() / "dropped.csv"
    data.to_csv(path, index=False)
    return est("--estimator", "ekf", "--w-variance", "1", data=path)


def _says_contiguous(res: CliResult) -> str | None:
    if "contiguous" in res.text or "gap" in res.text or "no k or t" in res.text:
        return None
    return "a record with 10 rows dropped and no k or t estimated as contiguous without a word"


def _relative_model() -> CliResult:
    sub = here() / "sub"
    sub.mkdir()
    (sub / "m.py").write_text(GOOD_MODEL.format(gain=0.5))
    (sub / "s.toml").write_text("name = 'x'\nmodel = 'm.py'\nsteps = 12\nruns = 1\nsettle = 2\ncases = ['noisy']\n"
                                "[[estimators]]\nname = 'E'\nkind = 'ekf'\nw_variance = 1.0\n")  # fmt: skip
    return cli("reproduce", "--scenario", sub / "s.toml", "--out", here() / "o", "--workers", "1", "--solver", "gn")


def _concurrent_estimates() -> Any:
    """Two ``uiest estimate`` processes into one --out: one must be refused (not both exit 0)."""
    import subprocess
    import sys

    data = record_csv()
    command = [sys.executable, "-m", "uiest", "estimate", "closed-form", "--data", str(data), "--out",
               str(here() / "shared"), "--estimator", "ekf", "--w-variance", "1"]  # fmt: skip
    procs = [subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True) for _ in range(2)]
    outputs = [p.communicate(timeout=50)[0] for p in procs]
    codes = [p.returncode for p in procs]
    if any("Traceback" in o for o in outputs):
        raise RuntimeError("a traceback: " + next(o for o in outputs if "Traceback" in o).strip().splitlines()[-1])
    if codes == [0, 0]:
        return ("both exit 0", codes)
    from uiest.errors import OptionError

    raise OptionError(f"--out: in use (exit codes {codes}): " + " ".join(outputs)[-200:])
