"""Two masses on springs (a spring-damper chain), both positions measured, an unknown force on mass 1.

``q1, q2`` in m, ``p1, p2`` their velocities in m/s: mass 1 (1 kg) hangs on a spring of 1 N/m to the wall and on a
stiff spring of 50 N/m to mass 2 (0.5 kg), which hangs on 1 N/m to the other wall; viscous damping 0.2 N s/m on each.
Sampled every 0.04 s by ``System.from_ode`` (RK4). The force has relative degree 2 to q1 (4 to q2): the channel
force -> q1 has a zero near -1 that sampling created; with q2 measured too the two-output model has no exact zero,
but a near-zero remains.
"""

import numpy as np

from uiest import System
from uiest.models import SimulationSetup
from uiest.noise import UniformNoise

M1, M2 = 1.0, 0.5  # kg
K_WALL, K_COUPLING, DAMPING = 1.0, 50.0, 0.2  # N/m, N/m, N s/m
NOISE = 1e-3  # m


def rhs(x, u, w):
    """dx/dt of (q1, q2, p1, p2); the unknown force w acts on mass 1."""
    q1, q2, p1, p2 = x[0], x[1], x[2], x[3]
    return [
        p1,
        p2,
        (-K_WALL * q1 - K_COUPLING * (q1 - q2) - DAMPING * p1 + w[0]) / M1,
        (-K_WALL * q2 + K_COUPLING * (q1 - q2) - DAMPING * p2) / M2,
    ]


system = System.from_ode(
    rhs, lambda x, v: [x[0] + v[0], x[1] + v[1]], nx=4, nw=1, nv=2, dt=0.04,
    x_bounds=((-4.0, -4.0, -5.0, -5.0), (4.0, 4.0, 5.0, 5.0)), v_bounds=(-NOISE, NOISE),
    x_names=("q1", "q2", "p1", "p2"), x_units=("m", "m", "m/s", "m/s"), w_names=("force",), w_units=("N",),
    w_scale=0.5, y_names=("q1_measured", "q2_measured"), y_units=("m", "m"), name="two masses",
)  # fmt: skip


def force(k: int, x: np.ndarray) -> np.ndarray:
    """A slow oscillating force of 0.5 N."""
    return np.array([0.5 * np.sin(0.8 * k * system.dt)])


def setup() -> SimulationSetup:
    """400 samples (16 s) from rest, +-1e-3 m position noise."""
    return SimulationSetup(x0=np.zeros(4), steps=400, u=None, w=force, noise=UniformNoise.symmetric([NOISE, NOISE]))
