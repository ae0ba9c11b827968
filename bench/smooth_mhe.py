"""The smooth-input MHE against the UISE, the EKF and the standard MHE on models whose unknown input is smooth.

Run: ``python bench/smooth_mhe.py``. Sampled mechanical models with a sampling zero (a pendulum with an unknown torque,
a cart on a spring, an exactly sampled double integrator, two masses on springs with both positions measured) and a
process model (the reactor example, its fault as the unknown input); data from scipy's solve_ivp with w held over each
sample (the reactor from its own model), noise uniform. Per model and record (smooth w; a step of the unknown input
halfway): the RMSE of every state after 20 samples (smooth) or over the 40 samples after the jump, for

- the UISE (``UISE.design`` where a certified window of at most 60 exists, else explicit weights mu 0.8, N 20),
- the EKF with the smooth-input MHE's increment variance, and the EKF whose variance is best on the record (from the
  truth: the grid 1e-4 .. 10 w.scale^2),
- ``SmoothInputMHE.design`` with that variance,

and the thread CPU per sample (``EstimationResult.cpu_time``, mean over the steps after the first) of the smooth-input
MHE, of the standard MHE on the same model (its delta-IOSS certificate over W, the same N) and of the EKF.
docs/performance.md quotes the figures.
"""

from __future__ import annotations

import time
import warnings

import numpy as np
from scipy.integrate import solve_ivp

from uiest import CertificationError, System, simulate
from uiest.detectability import certify_delta_ioss
from uiest.estimators import EKF, UISE, SmoothInputMHE, StandardMHE, UISEWeights
from uiest.models import load

K = 300
GRID = (1e-4, 1e-3, 1e-2, 1e-1, 1.0, 10.0)


def pendulum() -> tuple[System, object]:
    def rhs(x, u, w):
        return [x[1], -9.81 * np.sin(x[0]) - 0.5 * x[1] + w[0]]

    system = System.from_ode(rhs, lambda x, v: [x[0] + v[0]], nx=2, nw=1, nv=1, dt=0.05,
                             x_bounds=((-3.0, -8.0), (3.0, 8.0)), v_bounds=(-1e-3, 1e-3), name="pendulum")  # fmt: skip
    return system, rhs


def cart() -> tuple[System, object]:
    def rhs(x, u, w):
        return [x[1], -4.0 * x[0] - 0.4 * x[1] + w[0]]

    system = System.from_ode(rhs, lambda x, v: [x[0] + v[0]], nx=2, nw=1, nv=1, dt=0.05,
                             x_bounds=((-10.0, -10.0), (10.0, 10.0)), v_bounds=(-1e-3, 1e-3), name="cart")  # fmt: skip
    return system, rhs


def double_integrator() -> tuple[System, object]:
    def rhs(x, u, w):
        return [x[1], w[0]]

    system = System.from_ode(rhs, lambda x, v: [x[0] + v[0]], nx=2, nw=1, nv=1, dt=0.05,
                             x_bounds=((-10.0, -10.0), (10.0, 10.0)), v_bounds=(-1e-3, 1e-3),
                             name="double integrator")  # fmt: skip
    return system, rhs


def two_masses() -> tuple[System, object]:
    def rhs(x, u, w):
        q1, q2, p1, p2 = x
        return [p1, p2, -4.0 * q1 - 4.0 * (q1 - q2) - 0.2 * p1 + w[0], -4.0 * (q2 - q1) - 0.2 * p2]

    system = System.from_ode(rhs, lambda x, v: [x[0] + v[0], x[1] + v[1]], nx=4, nw=1, nv=2, dt=0.04,
                             x_bounds=((-5.0, -5.0, -20.0, -20.0), (5.0, 5.0, 20.0, 20.0)),
                             v_bounds=(-1e-3, 1e-3), name="two masses")  # fmt: skip
    return system, rhs


def record(system: System, rhs, x0, w, seed=0):
    """solve_ivp with w held over each sample; the outputs with noise uniform in V."""
    x = np.zeros((len(w) + 1, system.nx))
    x[0] = x0
    u = np.zeros(0)
    for k, wk in enumerate(w):
        x[k + 1] = solve_ivp(lambda t, z, wk=wk: np.asarray(rhs(z, u, wk), dtype=float), (0.0, system.dt), x[k],
                             rtol=1e-11, atol=1e-11).y[:, -1]  # fmt: skip
    V = system.v.bounds
    v = np.random.default_rng(seed).uniform(V.lower, V.upper, (len(x), system.nv))
    return x, system.output(x, v)


def uise(system: System, x0) -> tuple[object, str]:
    try:
        return UISE.design(system, x0_prior=x0, max_horizon=60), "certified"
    except CertificationError as exc:
        return UISE(system, weights=UISEWeights.from_scales(system, 0.8), N=20, x0_prior=x0), f"explicit ({exc})"[:60]


def rms(e) -> np.ndarray:
    return np.sqrt(np.mean(np.square(e), axis=0))


def compare(name: str, system: System, x, y, x0, u, variance: float, window: slice, w_bounds) -> None:
    variance = variance * system.w.scale[0] ** 2
    runs = {}
    estimator, how = uise(system, x0)
    runs[f"UISE ({how})"] = estimator.run(u, y)
    runs[f"EKF (q={variance:g})"] = ekf = EKF(system, w_variance=variance, x0_prior=x0).run(u, y)
    grid = {q: EKF(system, w_variance=q * system.w.scale[0] ** 2, x0_prior=x0).run(u, y) for q in GRID}
    best = min(grid, key=lambda q: float(np.sum(rms((grid[q].x_hat[window] - x[window]) / system.x.scale))))
    runs[f"EKF best (q={best:g})"] = grid[best]
    smooth = SmoothInputMHE.design(system, dw_variance=variance, w_bounds=w_bounds, x0_prior=x0)
    runs[f"smooth MHE (N={smooth.N}, {'certified' if smooth.certificate else 'explicit'})"] = result = smooth.run(u, y)
    print(f"\n{name}: state RMSE {list(system.x.names)}; guarantee: {result.guarantee}")
    for label, r in runs.items():
        print(f"  {label:58s} {np.array2string(rms(r.x_hat[window] - x[window]), precision=4)}  failed {r.failures}")
    standard = StandardMHE(system, certificate=certify_delta_ioss(system, w_bounds=w_bounds), N=smooth.N, x0_prior=x0)
    other = standard.run(u, y)
    print(f"  CPU per sample: smooth MHE {1e3 * result.cpu_time[1:].mean():.2f} ms, standard MHE (N={standard.N}) "
          f"{1e3 * other.cpu_time[1:].mean():.2f} ms, EKF {1e3 * ekf.cpu_time[1:].mean():.3f} ms")  # fmt: skip


def main() -> None:
    warnings.simplefilter("ignore", UserWarning)
    steps = np.arange(K)
    for make, x0, amplitude, jump in ((pendulum, [0.5, 0.0], 2.0, 6.0), (cart, [0.0, 0.0], 1.0, 6.0),
                                      (double_integrator, [0.0, -1.25], 1.0, None),
                                      (two_masses, [0.1, 0.0, 0.0, 0.0], 1.0, 3.0)):  # fmt: skip
        system, rhs = make()
        dt = system.dt
        smooth_w = (amplitude * np.sin(0.8 * dt * steps))[:, None]
        x, y = record(system, rhs, x0, smooth_w)
        compare(f"{system.name}, w = {amplitude} sin(0.8 t)", system, x, y, np.asarray(x0, float), None, 0.01,
                slice(20, None), (-20.0, 20.0))  # fmt: skip
        if jump is not None:
            w = (0.5 * np.sin(0.8 * dt * steps) + jump * (steps >= K // 2))[:, None]
            x, y = record(system, rhs, x0, w)
            compare(f"{system.name}, w = 0.5 sin(0.8 t) + {jump} after k = {K // 2}", system, x, y,
                    np.asarray(x0, float), None, 0.01, slice(K // 2, K // 2 + 40), (-20.0, 20.0))  # fmt: skip
    entry = load("examples/reactor.py")
    system, setup = entry.build(), entry.setup()

    def step(k, x):
        return np.array([-0.4 * (k >= 200)])

    for label, fault in (("the example's drifting fault", setup.w), ("a fault stepping to -0.4 at k = 200", step)):
        traj = simulate(system, setup.x0, setup.steps, u=setup.u, w=fault, v=setup.noise, seed=0)
        window = slice(20, None) if label.startswith("the") else slice(200, 240)
        compare(f"reactor, {label}", system, traj.x, traj.y, setup.x0, traj.u, 1e-4, window, (-1.0, 1.0))


if __name__ == "__main__":
    start = time.process_time()
    main()
    print(f"\n{time.process_time() - start:.0f} s CPU")
