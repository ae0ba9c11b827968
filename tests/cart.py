"""A cart on a rail with viscous friction, pushed by an unknown force; its position is measured.

``position`` in m, ``speed`` in m/s, the force per unit mass in m/s^2; friction 0.5 1/s. Sampled every 0.05 s by
``System.from_ode`` (RK4). Without a spring the cart is a damped double integrator: the force has relative degree 2
to the position, so the sampled model has a zero near -1 that sampling created.
"""

import numpy as np

from uiest import System
from uiest.models import SimulationSetup
from uiest.noise import UniformNoise

FRICTION = 0.5  # 1/s
NOISE = 1e-3  # m


def rhs(x, u, w):
    """dx/dt of (position, speed)."""
    return [x[1], -FRICTION * x[1] + w[0]]


system = System.from_ode(
    rhs, lambda x, v: [x[0] + v[0]], nx=2, nw=1, nv=1, dt=0.05,
    x_bounds=((-20.0, -10.0), (20.0, 10.0)), v_bounds=(-NOISE, NOISE), x_names=("position", "speed"),
    x_units=("m", "m/s"), w_names=("force",), w_units=("m/s^2",), y_names=("position_measured",), y_units=("m",),
    name="cart",
)  # fmt: skip


def force(k: int, x: np.ndarray) -> np.ndarray:
    """A back-and-forth push of 1 m/s^2."""
    return np.array([np.cos(0.8 * k * system.dt)])


def setup() -> SimulationSetup:
    """400 samples (20 s) from rest at the origin, +-1e-3 m position noise."""
    return SimulationSetup(x0=np.zeros(2), steps=400, u=None, w=force, noise=UniformNoise.symmetric(NOISE))
