"""Time every certificate of the crop model and of systems with known answers (issue 15 target: < 2 s each).

Run: ``python bench/certify.py``. Prints, per certificate: status, smallest and design rate, the
condition number of P, the minimal horizon, the largest per-step noise gain (strong detectability,
in state units), the cover, the CPU time of the certificate (``time.thread_time``: the solvers run
in this thread) and its wall-clock time, the part of that CPU time the adversarial search took and
its worst ratio, and the sampled verification (1e5 pairs, timed apart).
The machine's load average is printed first: wall-clock times on a shared machine swing.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable

import numpy as np

from uiest import Box, System
from uiest.detectability import (
    Certificate,
    certify_delta_ioss,
    certify_reduced_model,
    certify_strong_detectability,
    linear_strong_detectability,
)
from uiest.models import closed_form, crop_growth, linear
from uiest.reduction import reduce_quasi_state_affine


def henon() -> System:
    """The Henon map carrying a message w in x1, x1 measured."""
    return System.from_callables(
        lambda x, u, w: [1.0 - 1.4 * x[0] ** 2 + x[1] + w[0], 0.3 * x[0]],
        lambda x, v: [x[0] + v[0]],
        nx=2, nw=1, nv=1, x_bounds=((-1.5, -0.5), (1.5, 0.5)), v_bounds=(-1e-3, 1e-3), name="henon",
    )  # fmt: skip


def cstr() -> System:
    """A dimensionless CSTR with an actuator fault w on the temperature, T measured, sampled every 0.05."""

    def rhs(x, u, w):  # type: ignore[no-untyped-def]
        rate = 50.0 * x[0] * np.exp(-5.0 / x[1])
        return [1.0 - x[0] - rate, 2.0 - 2.0 * x[1] + 0.5 * rate + w[0]]

    return System.from_ode(rhs, lambda x, v: [x[1] + v[0]], nx=2, nw=1, nv=1, dt=0.05,
                           x_bounds=Box(lower=(0.0, 0.8), upper=(1.0, 2.5)), v_bounds=(-1e-3, 1e-3),
                           name="cstr")  # fmt: skip


def pendulum() -> System:
    """A damped pendulum with an unknown torque, the angle measured, sampled every 0.05 s."""
    return System.from_ode(
        lambda x, u, w: [x[1], -9.81 * np.sin(x[0]) - 0.5 * x[1] + w[0]],
        lambda x, v: [x[0] + v[0]],
        nx=2, nw=1, nv=1, dt=0.05, x_bounds=((-3.0, -8.0), (3.0, 8.0)), v_bounds=(-1e-3, 1e-3), name="pendulum",
    )  # fmt: skip


def chen_patton() -> System:
    """Chen and Patton's 3-state UIO example sampled by zero-order hold (dt = 0.1), X = +-1e9 with unit scales."""
    import scipy.linalg

    A = np.array([[-1.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, -1.0, -1.0]])
    E, C = np.array([[-1.0], [0.0], [0.0]]), np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    M = scipy.linalg.expm(np.block([[A, E], [np.zeros((1, 4))]]) * 0.1)
    return linear.linear_system(M[:3, :3], M[:3, 3:], C, x_bounds=(-1e9, 1e9), v_bounds=(-1e-2, 1e-2), x_scale=1.0,
                                name="chen-patton")  # fmt: skip


def jobs() -> dict[str, Callable[[], Certificate]]:
    crop = crop_growth.system()
    theta = crop_growth.jacobian_parameters()
    wide = closed_form.system(x_bounds=((-3.0, -60.0), (3.0, 60.0)))
    cases: dict[str, Callable[[], Certificate]] = {
        "crop strong (parameter box)": lambda: certify_strong_detectability(crop, parameters=theta),
        "crop strong, mu=0.48 (parameter box)": lambda: certify_strong_detectability(crop, 0.48, parameters=theta),
        "crop strong (exact by entries)": lambda: certify_strong_detectability(crop),
        "crop strong (sampled cover)": lambda: certify_strong_detectability(crop, cover="sampled"),
        "crop reduced e-IOSS": lambda: certify_reduced_model(crop_growth.reduction()),
        "crop delta-IOSS (P full)": lambda: certify_delta_ioss(crop),
        "crop reduced e-IOSS, cond(P) <= 1e12": lambda: certify_reduced_model(
            crop_growth.reduction(), max_condition=1e12
        ),
        "chen-patton reduced e-IOSS, X = +-1e9": lambda: certify_reduced_model(
            reduce_quasi_state_affine(chen_patton())
        ),
        "closed-form +-3/+-60 (exact by entries)": lambda: certify_strong_detectability(wide),
        "closed-form +-3/+-60 (parameters)": lambda: certify_strong_detectability(
            wide, parameters=closed_form.jacobian_parameters()
        ),
        "henon": lambda: certify_strong_detectability(henon()),
        "cstr (from_ode)": lambda: certify_strong_detectability(cstr()),
        "pendulum (from_ode)": lambda: certify_strong_detectability(pendulum()),
    }
    for zeros in ([0.5, 0.2], [0.3 + 0.4j, 0.3 - 0.4j, -0.7], [0.95, 0.1]):
        system, A, B, C = linear.with_invariant_zeros(zeros, seed=3, x_bounds=(-10.0, 10.0), v_bounds=(-1e-3, 1e-3))
        label = f"linear zeros {np.round(np.abs(zeros), 3).tolist()}"
        cases[f"{label}: strong"] = lambda system=system: certify_strong_detectability(system)
        cases[f"{label}: Hautus + LMI"] = lambda A=A, B=B, C=C: linear_strong_detectability(A, B, C)
    return cases


def main() -> None:
    print(f"load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores")
    columns = (("status", 10), ("rate_min", 9), ("rate", 9), ("cond(P)", 9), ("min N", 6), ("noise gain", 10),
               ("cover", 16), ("cpu s", 6), ("wall s", 6), ("search", 8), ("srch s", 6), ("verify", 8),
               ("ver. s", 6))  # fmt: skip
    print(f"{'certificate':42s} " + " ".join(f"{name:>{width}s}" for name, width in columns))
    slowest = 0.0
    for name, job in jobs().items():
        wall, cpu = time.perf_counter(), time.thread_time()
        cert = job()
        cpu, wall = time.thread_time() - cpu, time.perf_counter() - wall
        slowest = max(slowest, cpu)
        start = time.perf_counter()
        check = cert.verify(100_000)
        verify_s = time.perf_counter() - start
        ok = cert.certified
        gain = getattr(cert, "noise_gain", None)
        cover = getattr(getattr(cert, "cover", None), "kind", cert.coverage.split(" (")[0].split(":")[0])
        found = cert.falsification
        search = (found.worst_ratio, found.seconds) if found is not None else (float("nan"), float("nan"))
        print(
            f"{name:42s} {cert.status[:10]:>10s} {cert.rate_min:9.4g} {cert.rate:9.4g} "
            f"{cert.condition if ok else float('nan'):9.3g} {cert.min_horizon() if ok else '-'!s:>6s} "
            f"{float(np.max(gain)) if gain is not None and ok else float('nan'):10.3g} {cover[:16]:>16s} "
            f"{cpu:6.2f} {wall:6.2f} {search[0]:8.4f} {search[1]:6.2f} {check.worst_ratio:8.4f} {verify_s:6.2f}"
        )
    print(f"slowest certificate: {slowest:.2f} s CPU (target < 2 s for nx <= 4)")


if __name__ == "__main__":
    main()
