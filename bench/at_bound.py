"""Estimates at X's sides: too-narrow domains and a physical side, per estimator and window backend.

Run: ``python bench/at_bound.py``. Simulates each model on a wide X and estimates with a narrow one (and the wide
one), then a tank whose level decays to the physical side 0 between inflow pulses. Prints per run: steps with each
state at a side of X (``EstimationResult.at_bound_steps``), failures, IPOPT fallbacks, the RMSE per state, the
largest distance of a flagged estimate from its side and the smallest of an unflagged one within 1e-3 (both over
X's width), windows at a side, ``on_boundary`` steps, and whether a ``BoundWarning`` was raised (DEVELOPING.md,
"Step health", quotes the figures).
"""

from __future__ import annotations

import warnings

import numpy as np

from uiest import BoundWarning, simulate
from uiest.estimators import EKF, UISE, UISEWeights
from uiest.models import closed_form, linear

K = 400


def _linear(x_bounds):
    # y = x1; x2 is seen only through x1's history
    A = np.array([[0.8, 0.0], [0.5, 0.6]])
    return linear.linear_system(A, [[1.0], [0.0]], [[1.0, 0.0]], x_bounds=x_bounds, v_bounds=(-0.01, 0.01))


CASES = {
    # name: (model, wide X, narrow X, u, w)
    "linear, x2 in +-1": (_linear, ((-50, -50), (50, 50)), ((-50, -1), (50, 1)), None,
                          lambda k: 2.0 * np.sin(0.05 * k)),
    "closed-form, x1 in +-1": (lambda xb: closed_form.system(x_bounds=xb), ((-50, -50), (50, 50)),
                               ((-1, -50), (1, 50)), lambda k: 1.2 * np.sin(0.03 * k), lambda k: 0.5 * np.sin(0.1 * k)),
    "closed-form, x2 in +-1": (lambda xb: closed_form.system(x_bounds=xb), ((-50, -50), (50, 50)),
                               ((-50, -1), (50, 1)), lambda k: 1.2 * np.sin(0.03 * k), lambda k: 0.5 * np.sin(0.1 * k)),
}  # fmt: skip


def _row(label: str, result, truth, X) -> str:
    distance = np.minimum(np.abs(result.x_hat - X.lower), np.abs(X.upper - result.x_hat)) / X.width
    flagged = distance[result.at_bound]
    near = distance[(distance < 1e-3) & ~result.at_bound]
    rmse = np.sqrt(np.mean(result.error(truth.x) ** 2, axis=0))
    return (
        f"  {label:22s} at side {result.at_bound_steps.tolist()!s:12s} failed {result.failures:3d} "
        f"fallbacks {result.fallbacks:3d} rmse {np.array2string(rmse, precision=3):18s} "
        f"flagged max {flagged.max() if flagged.size else float('nan'):8.2g} "
        f"unflagged<1e-3 min {near.min() if near.size else float('nan'):8.2g} "
        f"windows {int(result.window_at_bound.sum()):3d} on_boundary {int(result.on_boundary.sum()):3d}"
    )


def _run(estimator, u, y):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", BoundWarning)
        result = estimator.run(u, y)
    return result, any(issubclass(c.category, BoundWarning) for c in caught)


def main() -> None:
    k = np.arange(K)
    rng = np.random.default_rng(0)
    for name, (make, wide, narrow, u_law, w_law) in CASES.items():
        u = None if u_law is None else u_law(k)[:, None]
        truth = simulate(make(wide), [0.0, 0.0], K, u=u, w=w_law(k)[:, None], v=rng.uniform(-0.01, 0.01, (K + 1, 1)))
        print(f"{name}: true state ranges {np.round(truth.x.min(axis=0), 2)} .. {np.round(truth.x.max(axis=0), 2)}")
        for width, bounds in (("wide", wide), ("narrow", narrow)):
            system = make(bounds)
            builds = {
                "UISE gn": lambda s: UISE(s, weights=UISEWeights.from_scales(s, 0.6), N=10, x0_prior=[0.0, 0.0]),
                "UISE ipopt": lambda s: UISE(s, weights=UISEWeights.from_scales(s, 0.6), N=10, x0_prior=[0.0, 0.0],
                                             solver="ipopt"),
                "EKF": lambda s: EKF(s, w_variance=0.1, x0_prior=[0.0, 0.0]),
            }  # fmt: skip
            for label, build in builds.items():
                result, warned = _run(build(system), u, truth.y)
                print(_row(f"{width} {label}", result, truth, system.x.bounds) + f" warned {warned}")
    tank = linear.linear_system([[0.8]], [[1.0]], [[1.0]], x_bounds=(0.0, 10.0), v_bounds=(-0.05, 0.05))
    w = np.zeros((K, 1))
    w[::50] = 5.0
    truth = simulate(tank, [0.0], K, w=w, v=np.random.default_rng(0).uniform(-0.05, 0.05, (K + 1, 1)))
    print(f"tank, X = [0, 10]: truth within 1e-3 of 0 in {int((truth.x[:, 0] < 1e-3).sum())} of {K + 1} steps")
    for label, estimator in (("UISE", UISE(tank, weights=UISEWeights.from_scales(tank, 0.6), N=10, x0_prior=[0.0])),
                             ("EKF", EKF(tank, w_variance=0.1, x0_prior=[0.0]))):  # fmt: skip
        result, warned = _run(estimator, None, truth.y)
        print(_row(label, result, truth, tank.x.bounds) + f" warned {warned}")


if __name__ == "__main__":
    main()
