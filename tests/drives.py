"""Test drives of `uiest analyse` and the default `uiest estimate` on mechanical and process models (issue 34).

Shared by ``tests/test_drives.py`` (a few records) and ``bench/drives.py`` (every record, the table). Each
:class:`Case` is a model file and two unknown inputs: a smooth one of amplitude ``A`` (``A (sin(0.8 t) + 0.5
sin(2.3 t + 1))`` on the mechanical models) and one that jumps by ``5 A`` (a held step; on the cart a push of 20
samples). Records are measured data: the continuous model (``system.sampled_from.rhs``) integrated by scipy's
``solve_ivp`` (tolerances 1e-10) with u and w held over each sample, not the model's own RK4 discretisation, and
noise uniform in V, drawn by seed; the truth starts off the estimators' prior (the model's ``setup().x0``).

Per record (:func:`drive`): ``uiest analyse MODEL --json`` and ``uiest estimate MODEL --data FILE`` without
``--estimator`` through typer's CliRunner, and optionally other estimators (``--estimator smooth --estimator ekf``);
the state RMSE after the first 20 % of the samples, per state and divided by the state scales
(``system.x.scale``, here X's widths), and over the 40 samples after the jump; and the EKF tuned on the truth: the
random-walk variance (times ``w.scale^2``) of :data:`uiest.likelihood.DEFAULT_GRID`, refined by quarter and
eighth decades around the best, whose scaled RMSE after 20 % on this record's own true states is smallest (the
best any EKF of that family does on this record; the same prior, ``P0`` and ``v_covariance`` as the CLI's EKF).
"""

from __future__ import annotations

import json
import re
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.integrate import solve_ivp
from typer.testing import CliRunner

from uiest import System
from uiest.cli import app
from uiest.estimators import EKF
from uiest.likelihood import DEFAULT_GRID
from uiest.models import ModelEntry, load
from uiest.results import Trajectory, read_record
from uiest.scales import data_scales

ROOT = Path(__file__).resolve().parents[1]
SKIP_SHARE = 0.2
"""The share of the samples left out of the RMSE (the estimators' transient from the prior)."""
JUMP_WINDOW = 40
"""Samples after the jump over which the jump RMSE is taken."""
JUMP_FACTOR = 5.0
"""The jump, in units of the smooth input's amplitude."""
Signal = Callable[[np.ndarray], np.ndarray]
"""Sample times t (K,) -> values (K, n)."""


def mechanical(amplitude: float) -> Signal:
    """``A (sin(0.8 t) + 0.5 sin(2.3 t + 1))``: a smooth unknown input of amplitude about A."""
    return lambda t: (amplitude * (np.sin(0.8 * t) + 0.5 * np.sin(2.3 * t + 1.0)))[:, None]


def step(smooth: Signal, size: float, start: float, end: float = np.inf) -> Signal:
    """Half the smooth input plus ``size`` for ``start <= t < end``."""
    return lambda t: 0.5 * smooth(t) + size * ((t >= start) & (t < end))[:, None]


@dataclass(frozen=True)
class Case:
    """A model file, its records' length, the truth's initial state, the known input and the two unknown inputs."""

    name: str
    path: Path
    steps: int
    x0: tuple[float, ...]
    smooth: Signal
    jump: Signal
    jump_at: int
    u: Signal | None = None
    amplitude: float = 1.0

    def entry(self) -> ModelEntry:
        return load(self.path)


def reactor_fault(t: np.ndarray) -> np.ndarray:
    """examples/reactor.py's fault: a drift towards -0.25 from t = 5 on, with a slow oscillation of 0.05."""
    return (-0.25 * (1.0 - np.exp(-np.maximum(t - 5.0, 0.0) / 4.0)) + 0.05 * np.sin(0.8 * t))[:, None]


def reactor_duty(t: np.ndarray) -> np.ndarray:
    """examples/reactor.py's duty: 0 and 0.2 in turn, every 100 samples."""
    return np.where((np.round(t / 0.05).astype(int) // 100) % 2 == 0, 0.0, 0.2)[:, None]


def tank_fault(t: np.ndarray) -> np.ndarray:
    """A slow pump-1 fault of about 0.1 V."""
    return (0.1 * (np.sin(0.01 * t) + 0.5 * np.sin(0.03 * t + 1.0)))[:, None]


CASES = {
    "pendulum": Case("pendulum", ROOT / "examples" / "pendulum.py", 400, (0.4, -0.3), mechanical(1.0),
                     step(mechanical(1.0), 5.0, 10.0), 200),
    "two masses": Case("two masses", ROOT / "tests" / "two_masses.py", 400, (0.05, 0.05, 0.0, 0.0),
                       mechanical(0.5), step(mechanical(0.5), 2.5, 8.0), 200, amplitude=0.5),
    "cart": Case("cart", ROOT / "tests" / "cart.py", 400, (0.1, 0.2), mechanical(1.0),
                 step(mechanical(1.0), 5.0, 10.0, 11.0), 200),
    "reactor": Case("reactor", ROOT / "examples" / "reactor.py", 400, (0.69, 1.09), reactor_fault,
                    lambda t: 0.05 * np.sin(0.8 * t)[:, None] - 0.25 * (t >= 10.0)[:, None], 200, u=reactor_duty,
                    amplitude=0.05),
    "quadruple tank": Case("quadruple tank", ROOT / "tests" / "quadruple_tank.py", 200, (12.7, 12.5, 1.9, 1.5),
                           tank_fault, step(tank_fault, 0.5, 300.0), 100, u=lambda t: np.full((len(t), 2), 3.0),
                           amplitude=0.1),
}  # fmt: skip


def ode_record(system: System, x0: np.ndarray, u: np.ndarray, w: np.ndarray, seed: int) -> Trajectory:
    """The continuous model integrated by solve_ivp with u[k], w[k] held over each sample; uniform noise in V."""
    continuous = system.sampled_from
    if continuous is None:
        raise ValueError(f"{system.name}: not a model sampled by System.from_ode")
    x = np.empty((len(w) + 1, system.nx))
    x[0] = x0
    for k in range(len(w)):

        def rhs(_t: float, z: np.ndarray, k: int = k) -> np.ndarray:
            return np.asarray(continuous.rhs(z, u[k], w[k]), dtype=float).reshape(-1)

        x[k + 1] = solve_ivp(rhs, (0.0, system.dt), x[k], rtol=1e-10, atol=1e-10).y[:, -1]
    V = system.v.bounds
    v = np.random.default_rng(seed).uniform(V.lower, V.upper, (len(x), system.nv))
    names = {"x": system.x.names, "u": system.u.names, "w": system.w.names, "v": system.v.names, "y": system.y.names}
    return Trajectory(t=system.dt * np.arange(len(x)), x=x, u=u, w=w, v=v, y=system.output(x, v), names=names,
                      system_name=system.name, seed=seed, time_unit=system.time_unit)  # fmt: skip


def make_record(case: Case, kind: str, seed: int = 0) -> Trajectory:
    """The case's ``kind`` ("smooth" or "jump") record."""
    system = case.entry().build()
    t = system.dt * np.arange(case.steps)
    u = np.zeros((case.steps, 0)) if case.u is None else case.u(t)
    w = (case.smooth if kind == "smooth" else case.jump)(t)
    record = ode_record(system, np.asarray(case.x0, dtype=float), u, w, seed)
    outside = ~system.x.bounds.contains(record.x)
    if np.any(outside):
        raise ValueError(f"{case.name}, {kind}: the true state leaves X at k = {np.flatnonzero(outside)[:5].tolist()}")
    return record


def scaled_rmse(system: System, x_hat: np.ndarray, x: np.ndarray, window: slice) -> np.ndarray:
    """Per state: the RMS of ``(x_hat - x) / x.scale`` over ``window`` (nx,)."""
    return np.sqrt(np.mean(((x_hat[window] - x[window]) / system.x.scale) ** 2, axis=0))


def overall(per_state: np.ndarray) -> float:
    """One number from the per-state scaled RMSEs: their quadratic mean."""
    return float(np.sqrt(np.mean(np.square(per_state))))


@dataclass
class TruthEKF:
    """The EKF tuned on the record's truth: the variance factor chosen, its estimates, every factor tried."""

    factor: float
    x_hat: np.ndarray
    tried: dict[float, float] = field(default_factory=dict)


def truth_tuned_ekf(system: System, record: Trajectory, prior: np.ndarray, window: slice) -> TruthEKF:
    """The EKF whose random-walk variance minimises the scaled state RMSE over ``window`` on the record's own truth."""
    u = record.u if system.nu else None
    runs: dict[float, np.ndarray] = {}

    def score(factor: float) -> float:
        if factor not in runs:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                runs[factor] = EKF(system, w_variance=factor * system.w.scale**2, x0_prior=prior).run(u, record.y).x_hat
        x_hat = runs[factor]
        return overall(scaled_rmse(system, x_hat, record.x, window)) if np.all(np.isfinite(x_hat)) else np.inf

    best = min(DEFAULT_GRID, key=score)
    for half_width in (0.25, 0.125):
        best = min((best * 10**-half_width, best, best * 10**half_width), key=score)
    tried = {factor: score(factor) for factor in sorted(runs)}
    return TruthEKF(float(best), runs[best], tried)


@dataclass
class Drive:
    """One record's drive: what the CLI said and estimated, and the truth-tuned EKF (module docstring)."""

    case: str
    record: str
    analysis: dict
    recommended: str
    first_line: str
    default: np.ndarray
    ekf_truth: TruthEKF
    system: System
    truth: Trajectory
    extra: dict[str, np.ndarray] = field(default_factory=dict)
    notes: dict[str, str] = field(default_factory=dict)
    commands: list[str] = field(default_factory=list)

    @property
    def settled(self) -> slice:
        return slice(int(np.ceil(SKIP_SHARE * (len(self.truth.y)))), None)

    def rmse(self, x_hat: np.ndarray, window: slice | None = None) -> np.ndarray:
        return scaled_rmse(self.system, x_hat, self.truth.x, self.settled if window is None else window)


def run_cli(arguments: list[str]) -> str:
    """``uiest ARGUMENTS`` in-process; its output (AssertionError with the output when it fails)."""
    result = CliRunner().invoke(app, arguments, terminal_width=400)
    if result.exit_code != 0:
        raise AssertionError(f"uiest {' '.join(arguments)} exited {result.exit_code}:\n{result.output}")
    return result.output


def estimates(out: Path, kind: str, system: System) -> np.ndarray:
    """x_hat (K+1, nx) from the CLI's ``estimates_<kind>.csv``."""
    frame = pd.read_csv(out / f"estimates_{kind}.csv")
    return frame[[f"{name}_hat" for name in system.x.names]].to_numpy()


def weights_notes(output: str) -> dict[str, str]:
    """The estimate table's weights column, per estimator (the rows of its table, joined where wrapped)."""
    notes: dict[str, list[str]] = {}
    current = None
    for line in output.split("steps: failed")[0].splitlines():  # the estimates' table, not the health table
        cells = [cell.strip() for cell in line.split("│")]
        if len(cells) < 4:
            current = None
            continue
        if cells[1]:
            current = cells[1] if cells[1] in ("uise", "delayed", "two-stage", "smooth", "ekf", "ukf", "mhe") else None
            if current is not None:
                notes[current] = []
        if current is not None and cells[2]:
            notes[current].append(cells[2])
    return {kind: " ".join(parts) for kind, parts in notes.items()}


def drive(case: Case, kind: str, folder: Path, *, seed: int = 0, others: tuple[str, ...] = ()) -> Drive:
    """Write the ``kind`` record as CSV, run ``uiest analyse`` and the default ``uiest estimate`` on it (module doc).

    ``others``: estimator kinds also run, by one ``uiest estimate --estimator ...`` (their estimates in ``extra``).
    """
    folder.mkdir(parents=True, exist_ok=True)
    record = make_record(case, kind, seed)
    entry = case.entry()
    data = folder / f"{kind}.csv"
    record.to_pandas().to_csv(data, float_format="%.10g")
    model = str(case.path)
    report = folder / "analysis.json"
    analyse_args = ["analyse", model, "--json", str(report)]
    run_cli(analyse_args)
    analysis = json.loads(report.read_text())
    out = folder / f"{kind}_default"
    estimate_args = ["estimate", model, "--data", str(data), "--out", str(out)]
    output = run_cli(estimate_args)
    first = output.splitlines()[0]
    match = re.match(r"recommended: ([\w-]+):", first)
    if match is None:
        raise AssertionError(f"no recommendation in the output:\n{output}")
    recommended = match.group(1)
    system = entry.build()
    measured = read_record(data, system)
    prior = np.asarray(entry.setup().x0, dtype=float)
    system = data_scales(system, prior, record=measured)  # as the CLI
    settled = slice(int(np.ceil(SKIP_SHARE * len(record.y))), None)
    result = Drive(case.name, kind, analysis, recommended, first, estimates(out, recommended, system),
                   truth_tuned_ekf(system, record, prior, settled), system, record, notes=weights_notes(output),
                   commands=[f"uiest {' '.join(analyse_args)}", f"uiest {' '.join(estimate_args)}"])  # fmt: skip
    if others:
        out = folder / f"{kind}_others"
        other_args = ["estimate", model, "--data", str(data), *(a for k in others for a in ("--estimator", k)),
                      "--out", str(out)]  # fmt: skip
        output = run_cli(other_args)
        result.commands.append(f"uiest {' '.join(other_args)}")
        result.notes.update({f"{k} (--estimator)": v for k, v in weights_notes(output).items()})
        for estimator in others:
            result.extra[estimator] = estimates(out, estimator, system)
    return result


def jump_window(case: Case) -> slice:
    """The samples from the jump (the first change of w, at ``case.jump_at``) over :data:`JUMP_WINDOW`."""
    return slice(case.jump_at, case.jump_at + JUMP_WINDOW)


def sampling_zero_named(analysis: dict) -> bool:
    """The JSON analysis names a zero created by sampling (an invariant zero, or a channel's where several outputs
    make the invariant one inexact)."""
    zeros = analysis["zeros"]
    invariant = any(zero.get("from_sampling") for zero in zeros["reference"])
    channels = any(zero.get("from_sampling") for channel in zeros["channels"] for zero in channel["zeros"])
    return invariant or channels
