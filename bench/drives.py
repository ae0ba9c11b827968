"""Test drives of `uiest analyse` and the default `uiest estimate` on three mechanical and two process models.

Run: ``PYTHONPATH=src python bench/drives.py [--out out/drives] [--only pendulum,cart] [--seed 0]``. The models, the
records and the scores are ``tests/drives.py``'s (its docstring): per model a record with a smooth unknown input and
one where it jumps by 5 times the smooth input's amplitude, both from scipy's solve_ivp; per record ``uiest analyse``
and ``uiest estimate`` without ``--estimator`` through the CLI, and ``--estimator smooth --estimator ekf --estimator
uise``; the EKF tuned on the record's own truth. Prints, per record:

- what ``uiest analyse`` names (a zero created by sampling, invariant or of one channel; the near-zero on |z| = 1; the
  strong-detectability certificate and the UISE guarantee's verdict) and what it recommends;
- the state RMSE after the first 20 % of the samples, each state divided by its scale and then their quadratic
  mean, of the default estimate and of the truth-tuned EKF, their ratio (the acceptance: at most 1.5) and the
  largest ratio of one state's RMSEs;
- over the 40 samples after the jump: the smooth-input MHE, the truth-tuned EKF, the EKF fitted to the data, the
  UISE, and the ratio smooth / truth-tuned EKF (the acceptance: below 1);

then every per-state figure and the commands. README (Which estimator for my model?) and DEVELOPING.md quote it.
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from drives import CASES, JUMP_WINDOW, Drive, drive, jump_window, overall

OTHERS = ("smooth", "ekf", "uise")


def analysis_names(analysis: dict) -> str:
    """What the analysis names: a sampling zero (invariant or a channel's), the near-zero, the certificate."""
    parts = []
    zeros = analysis["zeros"]
    invariant = [z for z in zeros["reference"] if z.get("from_sampling")]
    if invariant:
        parts.append(f"sampling zero {invariant[0]['real']:.4g}")
    else:
        channel = [(c, z) for c in zeros["channels"] for z in c["zeros"] if z.get("from_sampling") and z["real"] > -2]
        if channel:
            c, z = channel[0]
            exact = "no invariant zero" if not zeros["reference"] else "invariant zeros not from sampling"
            parts.append(f"{exact}; {c['input']} -> {c['output']}: sampling zero {z['real']:.4g}")
    circle = analysis["near_zeros"]["unit_circle"]
    if circle is not None:
        parts.append(f"near-zero {circle['sigma']:.2g} at z = {circle['z'][0]:.3g}")
    strong = analysis["strong"]
    if strong["certified"]:
        parts.append(f"certified mu {strong['mu']:.3g} (window {strong['min_horizon']}), "
                     f"UISE {strong['guarantee']['verdict']}")  # fmt: skip
    else:
        parts.append(f"strong: {strong['status']}")
    return "; ".join(parts)


def settled_row(d: Drive) -> str:
    default, ekf = overall(d.rmse(d.default)), overall(d.rmse(d.ekf_truth.x_hat))
    per_state = d.rmse(d.default) / d.rmse(d.ekf_truth.x_hat)
    worst = int(np.argmax(per_state))
    return (f"| {d.case} | {d.record} | {analysis_names(d.analysis)} | {d.recommended} | {default:.3g} | "
            f"{ekf:.3g} (q = {d.ekf_truth.factor:.3g}) | {default / ekf:.2f} | "
            f"{per_state[worst]:.2f} ({d.system.x.names[worst]}) |")  # fmt: skip


def jump_row(d: Drive, window: slice) -> str:
    smooth, ekf = overall(d.rmse(d.extra["smooth"], window)), overall(d.rmse(d.ekf_truth.x_hat, window))
    fitted, uise = overall(d.rmse(d.extra["ekf"], window)), overall(d.rmse(d.extra["uise"], window))
    return f"| {d.case} | {smooth:.3g} | {ekf:.3g} | {fitted:.3g} | {uise:.3g} | {smooth / ekf:.2f} |"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("out/drives"))
    parser.add_argument("--only", default=",".join(CASES))
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    warnings.simplefilter("ignore", UserWarning)
    start = time.process_time()
    drives: list[tuple[Drive, slice]] = []
    for name in args.only.split(","):
        case = CASES[name]
        for kind in ("smooth", "jump"):
            folder = args.out / f"seed{args.seed}" / name.replace(" ", "_")
            d = drive(case, kind, folder, seed=args.seed, others=OTHERS if kind == "jump" else ("uise",))
            drives.append((d, jump_window(case)))
            print(f"{name}, {kind}: done ({time.process_time() - start:.0f} s CPU)", file=sys.stderr, flush=True)
    print("state RMSE after the first 20 % of the samples (each state over its scale, quadratic mean over states)\n")
    print("| model | record | `uiest analyse` names | recommended | default `uiest estimate` | EKF tuned on the truth "
          "| ratio | largest ratio of a state |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|")
    for d, _ in drives:
        print(settled_row(d))
    print(f"\nover the {JUMP_WINDOW} samples after the jump (same scaling)\n")
    print("| model | smooth-input MHE | EKF tuned on the truth | EKF fitted to the data | UISE "
          "| smooth / EKF on truth |")  # fmt: skip
    print("|---|---|---|---|---|---|")
    for d, window in drives:
        if d.record == "jump":
            print(jump_row(d, window))
    print("\nper state (scaled RMSE after 20 %; after the jump), and the weights each estimator was given")
    for d, window in drives:
        names = d.system.x.names
        print(f"\n{d.case}, {d.record}: states {list(names)}")
        rows = {f"default ({d.recommended})": d.default, "EKF on truth": d.ekf_truth.x_hat, **d.extra}
        for label, x_hat in rows.items():
            settled = np.array2string(d.rmse(x_hat), precision=3)
            jump = np.array2string(d.rmse(x_hat, window), precision=3)
            after = f"   after the jump {jump}" if d.record == "jump" else ""
            print(f"  {label:22s} {settled}{after}")
        for label, note in d.notes.items():
            print(f"  weights, {label}: {note}")
        for command in d.commands:
            print(f"  $ {command}")
    print(f"\n{time.process_time() - start:.0f} s CPU")


if __name__ == "__main__":
    main()
