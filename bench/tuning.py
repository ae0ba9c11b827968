"""Tuning from the data alone against tuning on the truth: the EKF, UKF and standard MHE on three models.

For each model and record: the estimator fitted by the prediction-error method (``EKF.fit``, ``UKF.fit``: the
input model, its variance and the prior's factor; ``uiest.tuning.fit_standard_mhe``: the disturbance variance; no
true states), the same estimator (EKF, UKF: a random walk with the default prior) at the best variance of the default
grid scored on the record's true states, and (EKF, UKF) ``tuned()`` on a separate record with its states. Prints
the state RMSE of each (after the first tenth of the record, each state divided by its scale; per state in its
units), the ratios fit / truth-best and fit / tuned(), the choices and the likelihood profile's shape, then a table
of the ratios' ranges over the records. Then, on the linear model whose
unknown input is a Gaussian random walk of known variance, where the random walk's likelihood maximum lies against
that variance, how often the profile's 95 % interval holds it and how often the fit chooses the random walk.

Models: the CSTR of examples/reactor.py (its setup(): a drifting, smooth fault), a linear 3-state system with a
random-walk input and Gaussian noise (the input enters the unmeasured x3: relative degree 2, no UISE), a damped
pendulum sampled by System.from_ode (angle measured, a smooth torque).

    PYTHONPATH=src python bench/tuning.py [--records 3] [--coverage 20] [--only reactor,linear,pendulum]
"""

from __future__ import annotations

import argparse
import time
import warnings
from collections.abc import Callable
from pathlib import Path

import numpy as np

from uiest import System, simulate
from uiest.estimators import EKF, UKF, StandardMHE
from uiest.input_model import InputModel
from uiest.likelihood import DEFAULT_GRID
from uiest.models import linear, load
from uiest.noise import UniformNoise
from uiest.results import Trajectory
from uiest.tuning import fit_standard_mhe, likelihood_weights

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
MHE_N, MHE_ETA = 20, 0.8
A = np.array([[0.8, 0.3, 0.0], [-0.2, 0.7, 0.4], [0.1, -0.3, 0.6]])
B, C, B_U = np.array([[0.0], [0.0], [1.0]]), np.array([[1.0, 0, 0], [0, 1.0, 0]]), np.array([[0.0], [1.0], [0.0]])
LINEAR_STEP, LINEAR_NOISE = 0.05, 0.02  # the random walk's step and the noise's standard deviations


class Case:
    """A model, a record maker (seed -> record) and the filters' keywords."""

    def __init__(self, name: str, system: System, record: Callable[[int], Trajectory], x0: np.ndarray,
                 **keywords: object) -> None:  # fmt: skip
        self.name, self.system, self.record, self.x0, self.keywords = name, system, record, x0, keywords


def reactor() -> Case:
    entry = load(EXAMPLES / "reactor.py")
    system, setup = entry.build(), entry.simulation()

    def record(seed: int) -> Trajectory:
        return simulate(system, setup.x0, setup.steps, u=setup.u, w=setup.w, v=setup.noise, seed=seed)

    return Case("reactor", system, record, np.asarray(setup.x0, dtype=float))


def linear_random_walk() -> Case:
    system = linear.linear_system(A, B, C, B_u=B_U, x_bounds=(-50, 50), v_bounds=(-0.1, 0.1), u_bounds=(-2, 2),
                                  x_scale=10.0)  # fmt: skip

    def record(seed: int) -> Trajectory:
        rng = np.random.default_rng(seed)
        K = 400
        u = rng.uniform(-1, 1, (K, 1))
        w = np.cumsum(LINEAR_STEP * rng.standard_normal(K))[:, None]
        return simulate(system, [1.0, -1.0, 2.0], K, u=u, w=w, v=LINEAR_NOISE * rng.standard_normal((K + 1, 2)))

    return Case("linear", system, record, np.zeros(3), v_covariance=LINEAR_NOISE**2)


def pendulum() -> Case:
    system = System.from_ode(
        lambda x, u, w: [x[1], -9.81 * np.sin(x[0]) - 0.2 * x[1] + w[0]],
        lambda x, v: [x[0] + v[0]],
        nx=2, nw=1, nv=1, dt=0.05, x_bounds=((-10.0, -20.0), (10.0, 20.0)), v_bounds=(-1e-2, 1e-2),
        x_scale=(1.0, 3.0), w_scale=2.0, name="pendulum",
    )  # fmt: skip

    def record(seed: int) -> Trajectory:
        phase = np.random.default_rng(seed).uniform(0, 2 * np.pi, 2)

        def torque(k: int, x: np.ndarray) -> np.ndarray:
            t = 0.05 * k
            return np.array([2.0 * np.sin(0.4 * t + phase[0]) + np.sin(1.1 * t + phase[1])])

        return simulate(system, [0.5, 0.0], 400, w=torque, v=UniformNoise.symmetric(1e-2), seed=seed)

    return Case("pendulum", system, record, np.zeros(2))


CASES = {"reactor": reactor, "linear": linear_random_walk, "pendulum": pendulum}


def scaled_rmse(system: System, result, truth: Trajectory) -> float:
    settle = len(truth.y) // 10
    return float(np.sqrt(np.mean((result.error(truth.x)[settle:] / system.x.scale) ** 2)))


def per_state(result, truth: Trajectory) -> str:
    settle = len(truth.y) // 10
    return " ".join(f"{e:.3g}" for e in np.sqrt(np.mean(result.error(truth.x)[settle:] ** 2, axis=0)))


def mhe_at(case: Case, factor: float, u, y) -> StandardMHE:
    """The standard MHE of fit_standard_mhe's construction at a given variance factor."""
    s = case.system
    weights = likelihood_weights(s, u, y, x0_prior=case.x0, eta=MHE_ETA, w_variance=factor * s.w.scale**2,
                                 v_covariance=case.keywords.get("v_covariance"))  # fmt: skip
    return StandardMHE(s, weights=weights, N=MHE_N, x0_prior=case.x0)


def compare(case: Case, seed: int, table: dict[tuple[str, str], list[float]]) -> None:
    s, truth = case.system, case.record(seed)
    u = truth.u if s.nu else None
    training = case.record(seed + 1000)
    for cls in (EKF, UKF):
        start = time.process_time()
        fitted = cls.fit(s, u, truth.y, x0_prior=case.x0, **case.keywords)
        cpu = time.process_time() - start
        fit = fitted.filter_fit.best
        fit_result = fitted.run(u, truth.y)
        fit_rmse = scaled_rmse(s, fit_result, truth)
        grid = [scaled_rmse(s, cls(s, w_variance=q * s.w.scale**2, x0_prior=case.x0, **case.keywords).run(u, truth.y),
                            truth) for q in DEFAULT_GRID]  # fmt: skip
        best = int(np.argmin(grid))
        tuned = cls.tuned(s, training, x0_prior=case.x0, **case.keywords)
        tuned_rmse = scaled_rmse(s, tuned.run(u, truth.y), truth)
        best_result = cls(s, w_variance=DEFAULT_GRID[best] * s.w.scale**2, x0_prior=case.x0, **case.keywords)
        maxima = ", ".join(f"{m.input_model.value} {m.maximum:.1f}" for m in fitted.filter_fit.fits)
        print(f"{case.name:9s} {seed:4d} {cls.__name__:4s} fit {fit_rmse:.3g} ({fit.input_model.value}, q "
              f"{fit.variance.chosen:.3g} {fit.variance.shape.value}, prior factor {fit.prior_factor:.2g}; "
              f"log-likelihood {maxima}; {cpu:.1f} s CPU) | truth-best random walk {grid[best]:.3g} (q "
              f"{DEFAULT_GRID[best]:.3g}) | tuned() {tuned_rmse:.3g} (q {tuned.tuning.chosen:.3g}) | ratio fit/best "
              f"{fit_rmse / grid[best]:.2f}, fit/tuned() {fit_rmse / tuned_rmse:.2f} | per state fit "
              f"{per_state(fit_result, truth)}, best {per_state(best_result.run(u, truth.y), truth)}")  # fmt: skip
        table.setdefault((case.name, f"{cls.__name__} fit / best"), []).append(fit_rmse / grid[best])
        table.setdefault((case.name, f"{cls.__name__} fit / tuned()"), []).append(fit_rmse / tuned_rmse)
    start = time.process_time()
    mhe = fit_standard_mhe(s, u, truth.y, x0_prior=case.x0, N=MHE_N, eta=MHE_ETA,
                           v_covariance=case.keywords.get("v_covariance"))  # fmt: skip
    cpu = time.process_time() - start
    fit_rmse = scaled_rmse(s, mhe.run(u, truth.y), truth)
    grid = [scaled_rmse(s, mhe_at(case, q, u, truth.y).run(u, truth.y), truth) for q in DEFAULT_GRID]
    best = int(np.argmin(grid))
    print(f"{case.name:9s} {seed:4d} MHE  fit {fit_rmse:.3g} (q {mhe.likelihood.chosen:.3g}, "
          f"{mhe.likelihood.shape.value}, {cpu:.1f} s CPU) | truth-best {grid[best]:.3g} (q {DEFAULT_GRID[best]:.3g})"
          f" | ratio fit/best {fit_rmse / grid[best]:.2f}")  # fmt: skip
    table.setdefault((case.name, "standard MHE fit / best"), []).append(fit_rmse / grid[best])


def print_table(table: dict[tuple[str, str], list[float]]) -> None:
    """The ratios' ranges over the records: one row per model, one column per estimator and reference."""
    models = list(dict.fromkeys(name for name, _ in table))
    columns = list(dict.fromkeys(column for _, column in table))
    print("\n| model | " + " | ".join(columns) + " |")
    print("|---" * (len(columns) + 1) + "|")
    for name in models:
        cells = []
        for column in columns:
            values = table.get((name, column), [])
            lo, hi = (min(values), max(values)) if values else (np.nan, np.nan)
            cells.append(f"{lo:.2f}" if f"{lo:.2f}" == f"{hi:.2f}" else f"{lo:.2f}-{hi:.2f}")
        print(f"| {name} | " + " | ".join(cells) + " |")


def coverage(records: int) -> None:
    """The linear random walk: the chosen variance against the true one, and the 95 % interval's coverage."""
    case = linear_random_walk()
    s = case.system
    true_factor = LINEAR_STEP**2 / float(s.w.scale[0]) ** 2
    ratios, covered, widths, chosen = [], 0, [], 0
    for seed in range(records):
        truth = case.record(10_000 + seed)
        found = EKF.fit(s, truth.u, truth.y, x0_prior=case.x0, **case.keywords).filter_fit
        chosen += found.best.input_model is InputModel.RANDOM_WALK
        profile = next(fit.variance for fit in found.fits if fit.input_model is InputModel.RANDOM_WALK)
        lo, hi = profile.interval
        ratios.append(profile.chosen / true_factor)
        covered += lo <= true_factor <= hi
        widths.append(hi / lo)
    ratios_arr = np.array(ratios)
    print(
        f"linear random walk, K = 400, {records} records: chosen / true variance median "
        f"{np.median(ratios_arr):.3g}, range {ratios_arr.min():.3g} .. {ratios_arr.max():.3g}; the 95 % interval "
        f"holds the true variance in {covered} of {records} (its width hi/lo median {np.median(widths):.3g}); the "
        f"random walk chosen over the integrated random walk in {chosen} of {records}"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--records", type=int, default=3, help="records per model")
    parser.add_argument("--coverage", type=int, default=20, help="records of the known-variance check (0: none)")
    parser.add_argument("--only", default=",".join(CASES), help="models, comma separated")
    args = parser.parse_args()
    warnings.simplefilter("ignore")
    table: dict[tuple[str, str], list[float]] = {}
    for name in args.only.split(","):
        case = CASES[name]()
        for seed in range(args.records):
            compare(case, 7 + seed, table)
    print_table(table)
    if args.coverage:
        coverage(args.coverage)


if __name__ == "__main__":
    main()
