"""A two-state model file the tests copy and edit: x1 integrates the unknown input, x2 decays at GAIN (0.5).

x1+ = x1 + w, x2+ = GAIN x2 + 0.1 x1, y = x1 + v; X = [-10, 10]^2. With GAIN = 0.5 the default simulation
stays inside X; edited to 1.5, x2 leaves X within 20 steps.
"""

import numpy as np

from uiest import System
from uiest.models import SimulationSetup

GAIN = 0.5

system = System.from_callables(
    lambda x, u, w: [x[0] + w[0], GAIN * x[1] + 0.1 * x[0]], lambda x, v: [x[0] + v[0]], nx=2, nw=1, nv=1,
    x_bounds=((-10.0, -10.0), (10.0, 10.0)), v_bounds=(-1e-3, 1e-3), name="gain",
)  # fmt: skip


def setup() -> SimulationSetup:
    """20 steps from (0, 1) with a constant unknown input 0.1, noise-free."""
    return SimulationSetup(x0=np.array([0.0, 1.0]), steps=20, u=None, w=np.array([0.1]), noise=None)
