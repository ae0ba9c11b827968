"""The discount eta of ``uiest estimate``'s data-tuned window estimators: the design's against eta -> 1.

Run: ``PYTHONPATH=src python bench/data_prior_eta.py [--seeds 5] [--only chemostat,crop-growth]``. Where a model has
no informative certificate, ``uiest estimate`` builds the smooth-input MHE with the window prior ``0.5 inv(C)``, C the
random-walk EKF's settled covariance of (x, w) on the record, and the window that starts at time s with ``0.5
inv(C_s)``, C_s that EKF's covariance of (x[s], w[s]) (:func:`uiest.tuning.arrival_covariances`), at the
design's eta (``FALLBACK_ETA`` or the certificate's), and the standard MHE with Gaussian weights whose prior is the
white-input EKF's settled covariance (:func:`uiest.tuning.fit_standard_mhe`) at ``FALLBACK_RATE``. The cost weighs the
prior by ``eta^N`` and stage j by ``eta^(j-1)``; at eta = 1 it is the window's negative log-posterior.

Per model, seed (the record's noise) and prior of x[0] (``exact``: the simulation's x0; ``wrong``: moved a quarter of
X's width towards X's centre, or two scales where X is unbounded), both routes are built as ``uiest estimate`` builds
them (the variance fitted to the record, no true states) and run at the design's eta, 0.95, 0.99 and 1 - 1e-9, beside
the EKF ``uiest estimate`` fits (its smooth-input MHE takes the eta of the smallest prediction error among the design's
and :data:`~uiest.tuning.SMOOTH_DISCOUNTS` above it: the line ``smooth by prediction``). Printed: the state RMSE (each
state divided by its scale, root mean square over the states) over the whole record and over its last third, the mean
over the seeds, IPOPT fallbacks and failed steps summed over the seeds, the CPU of the runs, and the one-step prediction
error (no truth: the RMS over the record's second half of ``y[k+1] - h(f(x_hat[k], u[k], w))`` in output scales, w the
newest estimate of the input, :func:`uiest.tuning.prediction_error`) with, per route, the RMSE of the eta whose
prediction error is the smallest on each record (``by prediction``; the standard MHE's over all four, which ``uiest
estimate`` does not do).

Models: the gallery's closed-form, crop-growth and linear-example, examples/reactor.py and examples/pendulum.py, a
cart on a spring sampled at 10 ms (position measured, unknown force) and a chemostat with Monod growth over a wide
domain (biomass up to 1e4 mg/L unmeasured, substrate measured, an unknown feed disturbance).
"""

from __future__ import annotations

import argparse
import time
import warnings
from collections import defaultdict
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from uiest import Box, System, models, simulate
from uiest.estimate import DEFAULT_HORIZON, DEFAULT_MAX_HORIZON, FALLBACK_RATE, build_estimator
from uiest.estimators import EKF, SmoothInputMHE, StandardMHE, smooth_mhe
from uiest.input_model import InputModel
from uiest.models import SimulationSetup
from uiest.noise import UniformNoise
from uiest.run_data import check_run_data
from uiest.tuning import SMOOTH_DISCOUNTS, arrival_covariances, fit_standard_mhe, prediction_error, preferred_discount

ONE = 1.0 - 1e-9
ROOT = Path(__file__).resolve().parents[1]


def chemostat() -> System:
    mu, ks, yld, sf = 0.4, 200.0, 0.5, 5000.0  # 1/h, mg/L, -, mg/L

    def rhs(x, u, w):
        growth = mu * x[1] / (ks + x[1]) * x[0]
        return [growth - u[0] * x[0], u[0] * (sf - x[1]) - growth / yld + w[0]]

    return System.from_ode(rhs, lambda x, v: [x[1] + v[0]], nx=2, nu=1, nw=1, nv=1, dt=0.25, substeps=8,
                           x_bounds=Box(lower=(0.0, 0.0), upper=(1.0e4, 500.0)), u_bounds=(0.05, 0.2),
                           v_bounds=(-2.0, 2.0), w_range=(-300.0, 300.0), name="chemostat")  # fmt: skip


def chemostat_setup() -> SimulationSetup:
    def dilution(k, x):
        return np.array([0.1 if (k // 80) % 2 == 0 else 0.15])

    def feed(k, x):
        return np.array([-100.0 * (k * 0.25 > 10) + 30.0 * np.sin(0.3 * k * 0.25)])

    return SimulationSetup(x0=np.array([2400.0, 70.0]), steps=300, u=dilution, w=feed,
                           noise=UniformNoise.symmetric(2.0))  # fmt: skip


def cart() -> System:
    def rhs(x, u, w):
        return [x[1], (-8.0 * x[0] - 1.0 * x[1] + w[0]) / 2.0]

    return System.from_ode(rhs, lambda x, v: [x[0] + v[0]], nx=2, nw=1, nv=1, dt=0.01,
                           x_bounds=((-1.0, -5.0), (1.0, 5.0)), v_bounds=(-1e-4, 1e-4), name="cart")  # fmt: skip


def cart_setup() -> SimulationSetup:
    def force(k, x):
        return np.array([2.0 * np.sin(1.5 * k * 0.01) + 3.0 * (k * 0.01 > 2.0)])

    return SimulationSetup(x0=np.array([0.1, 0.0]), steps=400, u=None, w=force, noise=UniformNoise.symmetric(1e-4))


def entries() -> dict[str, models.ModelEntry]:
    found = {name: models.get(name) for name in ("closed-form", "crop-growth", "linear-example")}
    for name in ("reactor", "pendulum"):
        found[name] = models.load(ROOT / "examples" / f"{name}.py")
    for name, build, setup in (("chemostat", chemostat, chemostat_setup), ("cart", cart, cart_setup)):
        found[name] = models.register(f"bench-{name}", build, setup=setup, replace=True)
    return found


def wrong_prior(system: System, x0: np.ndarray) -> np.ndarray:
    """x0 moved a quarter of X's width towards X's centre (two scales where X is unbounded), kept in X."""
    bounds = system.x.bounds
    shift = np.where(np.isfinite(bounds.width), 0.25 * bounds.width, 2.0 * system.x.scale)
    sign = np.where(np.isfinite(bounds.center) & (bounds.center < x0), -1.0, 1.0)
    return np.clip(x0 + sign * shift, bounds.lower, bounds.upper)


def runs(entry: models.ModelEntry, seed: int, prior: str) -> dict[str, dict[str, Any]]:
    """Each route's scores on one record."""
    system, setup = entry.build(), entry.simulation()
    record = simulate(system, setup.x0, setup.steps, u=setup.u, w=setup.w, v=setup.noise, seed=seed)
    x0 = np.asarray(setup.x0, dtype=float)
    x0 = wrong_prior(system, x0) if prior == "wrong" else x0
    u = record.u if system.nu else None
    u_checked, y = check_run_data(system, u, record.y)
    last = slice(record.steps - record.steps // 3, None)

    def score(estimator: Any) -> dict[str, Any]:
        start = time.process_time()
        result = estimator.run(u, y, x0_prior=x0)
        cpu = time.process_time() - start
        error = (result.x_hat - record.x) / system.x.scale
        return {"rmse": float(np.sqrt(np.mean(error**2))), "last": float(np.sqrt(np.mean(error[last] ** 2))),
                "fallbacks": result.fallbacks, "failures": result.failures, "cpu": cpu,
                "predicted": prediction_error(system, result.x_hat, result.w_hat, u_checked, y)}  # fmt: skip

    out = {"ekf": score(build_estimator("ekf", entry, system, x0, record=record)[0])}
    fitted = EKF.fit(system, u, y, x0_prior=x0, input_models=InputModel.RANDOM_WALK, prior_factors=[1.0])
    assert fitted.likelihood is not None
    variance = fitted.likelihood.chosen * system.w.scale**2
    window = min(smooth_mhe.DEFAULT_HORIZON, DEFAULT_MAX_HORIZON)
    design = SmoothInputMHE.design(system, dw_variance=variance, x0_prior=x0, N=window,
                                   max_horizon=DEFAULT_MAX_HORIZON)  # fmt: skip
    settled, starts = arrival_covariances(EKF(system, w_variance=variance, x0_prior=x0), u_checked, y, with_input=True)
    standard = fit_standard_mhe(system, u, y, x0_prior=x0, N=DEFAULT_HORIZON, eta=FALLBACK_RATE)
    for label, eta in (("design", None), ("0.95", 0.95), ("0.99", 0.99), ("1", ONE)):
        weights = replace(design.weights, eta=design.weights.eta if eta is None else max(eta, design.weights.eta),
                          P=0.5 * np.linalg.inv(settled))  # fmt: skip
        out[f"smooth {label}"] = score(SmoothInputMHE(system, weights=weights, dw_variance=variance,
                                                      dw_bound=design.dw_bound, N=design.N, x0_prior=x0,
                                                      arrival_P=0.5 * np.linalg.inv(starts)))  # fmt: skip
        weights = replace(standard.weights, eta=FALLBACK_RATE if eta is None else eta)
        out[f"mhe {label}"] = score(StandardMHE(system, weights=weights, N=DEFAULT_HORIZON, x0_prior=x0))
    library = ["smooth design"] + [f"smooth {eta:g}" for eta in SMOOTH_DISCOUNTS]  # the set uiest estimate tries
    errors = {float(design.weights.eta if label == "smooth design" else label.split()[1]): out[label]["predicted"]
              for label in library}  # fmt: skip
    chosen = preferred_discount(errors, design.weights.eta)
    out["smooth by prediction"] = out["smooth design" if chosen == design.weights.eta else f"smooth {chosen:g}"]
    out["mhe by prediction"] = min(
        (r for label, r in out.items() if label.startswith("mhe")), key=lambda r: r["predicted"]
    )
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--only", default="", help="comma-separated model names")
    args = parser.parse_args()
    warnings.simplefilter("ignore")
    chosen = {name: entry for name, entry in entries().items() if not args.only or name in args.only.split(",")}
    for prior in ("exact", "wrong"):
        print(f"\nprior {prior}: scaled RMSE whole | last third, mean over {args.seeds} seeds [fallbacks/failures]")
        for name, entry in chosen.items():
            scores: dict[str, list[dict[str, Any]]] = defaultdict(list)
            for seed in range(args.seeds):
                for route, result in runs(entry, seed, prior).items():
                    scores[route].append(result)
            print(f"  {name}")
            for route, results in scores.items():
                rmse, tail = np.mean([r["rmse"] for r in results]), np.mean([r["last"] for r in results])
                fallbacks, failures = sum(r["fallbacks"] for r in results), sum(r["failures"] for r in results)
                cpu, error = sum(r["cpu"] for r in results), np.mean([r["predicted"] for r in results])
                print(
                    f"    {route:20s} {rmse:9.3g} | {tail:9.3g}  [{fallbacks}/{failures}]  CPU {cpu:6.1f} s  "
                    f"prediction {error:.3g}"
                )


if __name__ == "__main__":
    main()
