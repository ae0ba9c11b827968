"""Johansson's quadruple tank (IEEE Trans. Control Syst. Technol. 8(3), 2000), pump 1's flow with an unknown fault.

Levels h1..h4 in cm (tanks 1, 2 below, 3, 4 above), pump voltages v1, v2 in V (known), and an unknown additive
fault w on pump 1's voltage (its flow splits between tanks 1 and 4 as the pump's does). The lower levels are
measured: y = (h1, h2) in cm. Parameters of the paper's minimum-phase setting P-: A1 = A3 = 28 cm^2,
A2 = A4 = 32 cm^2, a1 = a3 = 0.071 cm^2, a2 = a4 = 0.057 cm^2, k1 = 3.33, k2 = 3.35 cm^3/(V s),
gamma1 = 0.70, gamma2 = 0.60, g = 981 cm/s^2; its operating point h = (12.4, 12.7, 1.8, 1.4) cm at v = (3, 3) V.
Sampled every 3 s by ``System.from_ode``. X: each level between 1 cm (below it the outflow's sqrt is too steep to
certify) and the tank's height, 20 cm.
"""

import numpy as np

from uiest import System
from uiest.models import SimulationSetup
from uiest.noise import UniformNoise

AREA = (28.0, 32.0, 28.0, 32.0)  # cm^2
OUTLET = (0.071, 0.057, 0.071, 0.057)  # cm^2
PUMP = (3.33, 3.35)  # cm^3 / (V s)
SPLIT = (0.70, 0.60)
G = 981.0  # cm / s^2
OPERATING_POINT = np.array([12.4, 12.7, 1.8, 1.4])


def rhs(h, v, w):
    """dh/dt: outflows a_i sqrt(2 g h_i), the pumps' flows split by gamma; w adds to pump 1's voltage."""
    out = [OUTLET[i] * np.sqrt(2.0 * G * h[i]) for i in range(4)]
    q1, q2 = PUMP[0] * (v[0] + w[0]), PUMP[1] * v[1]
    return [
        (-out[0] + out[2] + SPLIT[0] * q1) / AREA[0],
        (-out[1] + out[3] + SPLIT[1] * q2) / AREA[1],
        (-out[2] + (1.0 - SPLIT[1]) * q2) / AREA[2],
        (-out[3] + (1.0 - SPLIT[0]) * q1) / AREA[3],
    ]


system = System.from_ode(
    rhs,
    lambda h, v: [h[0] + v[0], h[1] + v[1]],
    nx=4,
    nu=2,
    nw=1,
    nv=2,
    dt=3.0,
    x_bounds=(1.0, 20.0),
    u_bounds=(0.0, 6.0),
    v_bounds=(-0.05, 0.05),
    x_names=("h1", "h2", "h3", "h4"),
    x_units=("cm",) * 4,
    u_names=("v1", "v2"),
    u_units=("V", "V"),
    w_names=("pump1_fault",),
    w_units=("V",),
    y_names=("h1_measured", "h2_measured"),
    y_units=("cm", "cm"),
    name="quadruple-tank",
)


def fault(k: int, x: np.ndarray) -> np.ndarray:
    """Pump 1 runs 0.5 V above its command from t = 300 s on."""
    return np.array([0.5 if k * system.dt >= 300.0 else 0.0])


def setup() -> SimulationSetup:
    """200 samples (600 s) from the operating point at v = (3, 3) V, level noise +-0.05 cm."""
    return SimulationSetup(x0=OPERATING_POINT, steps=200, u=np.full((200, 2), 3.0), w=fault,
                           noise=UniformNoise.symmetric([0.05, 0.05]))  # fmt: skip
