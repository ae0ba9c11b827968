"""A four-state model with two known inputs, one unknown input into the measured x1, and three outputs.

x4 is not measured and contracts; x3 is measured together with a tenth of x4. Used where a design's certified
weights cap the window below its ``min_horizon()`` (the smooth-input MHE) and where an output the unknown input
reaches goes missing (the two-stage UISE).
"""

import casadi as ca

from uiest import System


def system() -> System:
    def f(x, u, w):
        return [
            0.9 * x[0] + 0.2 * ca.sin(x[1]) + 0.1 * u[0] + w[0],
            0.7 * x[1] + 0.1 * x[0] + 0.1 * u[1],
            0.6 * x[2] + 0.2 * ca.tanh(x[3]) + 0.05 * u[0] * u[1],
            (0.4 + 0.2 * ca.tanh(x[1])) * x[3] + 0.1 * x[2],
        ]

    return System.from_callables(f, lambda x, v: [x[0] + v[0], x[1] + v[1], x[2] + 0.1 * x[3] + v[2]], nx=4, nu=2,
                                 nw=1, nv=3, x_bounds=(-10.0, 10.0), u_bounds=(-1.0, 1.0),
                                 v_bounds=(-1e-3, 1e-3))  # fmt: skip
