"""A damped pendulum driven by an unknown torque; only the angle is measured.

``dx/dt = (rate, -g/l sin(angle) - c rate + torque)``, sampled every 0.05 s by ``System.from_ode``
(RK4, the torque held over each sample). The torque has relative degree 2 to the angle, so the
sampled model has a zero near -1 that sampling created: ``uiest analyse examples/pendulum.py``
names it and what it hides.
"""

import numpy as np

from uiest import System
from uiest.models import SimulationSetup
from uiest.noise import UniformNoise

GRAVITY_OVER_LENGTH, DAMPING = 9.81, 0.2  # 1/s^2 (a 1 m pendulum), 1/s


def rhs(x, u, w):
    """dx/dt of (angle, rate): gravity, damping and the unknown torque (per unit inertia)."""
    return [x[1], -GRAVITY_OVER_LENGTH * np.sin(x[0]) - DAMPING * x[1] + w[0]]


system = System.from_ode(
    rhs,
    lambda x, v: [x[0] + v[0]],
    nx=2,
    nw=1,
    nv=1,
    dt=0.05,
    x_bounds=((-1.5, -6.0), (1.5, 6.0)),
    v_bounds=(-1e-3, 1e-3),
    x_names=("angle", "rate"),
    x_units=("rad", "rad/s"),
    w_names=("torque",),
    w_units=("rad/s^2",),
    y_names=("angle_measured",),
    y_units=("rad",),
    name="pendulum",
)


def torque(k: int, x: np.ndarray) -> np.ndarray:
    """Steps of 2 rad/s^2 every 5 s on a slow oscillation."""
    t = k * system.dt
    return np.array([2.0 * ((t // 5.0) % 2) + np.sin(0.5 * t)])


def setup() -> SimulationSetup:
    """400 samples (20 s) from rest at 0.3 rad, +-1e-3 rad angle noise."""
    return SimulationSetup(x0=np.array([0.3, 0.0]), steps=400, u=None, w=torque, noise=UniformNoise.symmetric(1e-3))
