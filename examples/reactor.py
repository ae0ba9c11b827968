"""A continuous stirred-tank reactor whose coolant actuator drifts: the fault is the unknown input.

Dimensionless CSTR with one exothermic reaction A -> B: concentration c_A and temperature T,
coolant duty u (known), and an actuator fault w that adds to the heat balance (unknown, drifting
and unbounded in principle). Only the temperature is measured. The model is continuous-time;
``System.from_ode`` samples it every 0.05 time units (RK4 for the drift, the fault through its
exact per-sample integral, so it keeps a constant direction and the model certifies).

Use it with ``uiest estimate examples/reactor.py --data examples/data/reactor.csv``.
"""

import numpy as np

from uiest import Box, System
from uiest.models import SimulationSetup
from uiest.noise import UniformNoise

K0, ENERGY, HEAT = 50.0, 5.0, 0.5  # rate constant, activation energy, heat of reaction (dimensionless)


def rhs(x, u, w):
    """dx/dt of (c_A, T): feed, reaction and cooling; the fault w adds to the heat balance."""
    rate = K0 * x[0] * np.exp(-ENERGY / x[1])
    return [1.0 - x[0] - rate, 2.0 - 2.0 * x[1] + HEAT * rate + u[0] + w[0]]


system = System.from_ode(
    rhs,
    lambda x, v: [x[1] + v[0]],
    nx=2,
    nu=1,
    nw=1,
    nv=1,
    dt=0.05,
    x_bounds=Box(lower=(0.0, 0.8), upper=(1.0, 2.5)),
    u_bounds=(-0.5, 0.5),
    v_bounds=(-2e-3, 2e-3),
    x_names=("c_A", "T"),
    x_units=("-", "-"),
    u_names=("coolant",),
    w_names=("fault",),
    y_names=("T_measured",),
    y_units=("-",),
    time_unit="-",
    name="reactor",
)


def fault(k: int, x: np.ndarray) -> np.ndarray:
    """The actuator drifts from t = 5 on, towards -0.25, with a slow oscillation."""
    t = k * system.dt
    drift = -0.25 * (1.0 - np.exp(-max(t - 5.0, 0.0) / 4.0))
    return np.array([drift + 0.05 * np.sin(0.8 * t)])


def setup() -> SimulationSetup:
    """400 samples (20 time units) from the steady state, a stepped duty, +-2e-3 sensor noise."""
    noise = UniformNoise.symmetric(2e-3)
    return SimulationSetup(x0=np.array([0.6696, 1.0826]), steps=400, u=duty, w=fault, noise=noise)


def duty(k: int, x: np.ndarray) -> np.ndarray:
    """The known input: 0 and 0.2 in turn, every 100 samples."""
    return np.array([0.0 if (k // 100) % 2 == 0 else 0.2])


def study():
    """Ten runs from initial states around the steady state: the UISE beside the practitioner's filters.

    ``uiest reproduce examples/reactor.py`` runs it (``--quick``: two runs).
    """
    from uiest.experiments import EstimatorSpec, Scenario

    return Scenario(
        name="reactor",
        model=__file__,
        steps=400,
        runs=10,
        x0_lower=(0.6, 1.0),
        x0_upper=(0.7, 1.1),
        prior=(0.65, 1.05),
        settle=40,
        focus_state=0,
        estimators=(
            EstimatorSpec("UISE", "uise", N=10, mu=0.8, output_weight=1.0),
            EstimatorSpec("UISE (certified)", "uise", N=0, mu=0.9, weights="certificate"),  # mu_min is 0.897
            EstimatorSpec("standard MHE", "standard-mhe", N=10, mu=0.8, output_weight=1.0),
            EstimatorSpec("EKF (tuned)", "ekf"),
            EstimatorSpec("UKF (tuned)", "ukf"),
        ),
    )


if __name__ == "__main__":  # writes examples/data/reactor.csv: the measurements (and, for checking, the truth)
    from pathlib import Path

    from uiest import simulate

    config = setup()
    record = simulate(system, config.x0, config.steps, u=config.u, w=config.w, v=config.noise, seed=7)
    columns = ["t", *system.u.names, *system.y.names, *system.x.names, *system.w.names]
    path = Path(__file__).parent / "data" / "reactor.csv"
    record.to_pandas()[columns].to_csv(path, float_format="%.8g")
    print(f"wrote {path}")
