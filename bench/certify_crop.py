"""Time the three certificates of the crop model (issue 3 target: all three under 30 s).

Run: ``python bench/certify_crop.py``. Prints, per certificate, whether it holds, the discount,
the condition number of P, the minimal horizon and the wall-clock time (bisection, cutting plane
and the eigenvalue re-check included; the sampled verification is timed separately).
"""

from __future__ import annotations

import time

from uiest.detectability import certify_delta_ioss, certify_strong_detectability
from uiest.models import crop_growth


def main() -> None:
    system = crop_growth.system()
    reduction = crop_growth.reduction()
    jobs = {
        "strong detectability": lambda: certify_strong_detectability(system),
        "reduced-order e-IOSS": reduction.certify,
        "delta-IOSS (P full)": lambda: certify_delta_ioss(system),
        "delta-IOSS (P identity)": lambda: certify_delta_ioss(system, structure="identity"),
    }
    total = 0.0
    print(
        f"{'certificate':26s} {'holds':>5s} {'mu':>10s} {'cond(P)':>9s} {'min N':>8s} {'solve s':>8s} {'verify s':>8s}"
    )
    for name, job in jobs.items():
        start = time.perf_counter()
        cert = job()
        solve = time.perf_counter() - start
        start = time.perf_counter()
        cert.verify(20_000)
        verify = time.perf_counter() - start
        total += solve
        mu = getattr(cert, "mu", getattr(cert, "eta", float("nan")))
        cond = getattr(cert, "condition", getattr(cert, "c_x", float("nan")))
        horizon = cert.min_horizon() if cert.certified else "-"
        print(f"{name:26s} {cert.certified!s:>5s} {mu:10.6f} {cond:9.3g} {horizon!s:>8s} {solve:8.2f} {verify:8.2f}")
        if not cert.certified:
            print(f"  reason: {cert.reason}")
    print(f"total certification time: {total:.1f} s (target < 30 s)")


if __name__ == "__main__":
    main()
