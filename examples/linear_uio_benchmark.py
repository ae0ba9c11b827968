"""A linear unknown-input-observer benchmark: the classical UIO beside the designed UISE and an EKF.

The system has 3 states, one unknown input and two outputs (no invariant zeros; noise
|v| <= 0.05). The unknown input is a step to 5 at k = 50 and then a ramp: bounded by nothing a
filter could be tuned to.
The Chen-Patton-Zhang UIO and the UISE ignore it exactly (their errors do not depend on w); the
EKF, tuned on a separate record with a smooth random-walk input, lags behind each change.
Run ``python examples/linear_uio_benchmark.py`` to write ``examples/figures/linear_uio_benchmark.png``.
"""

from pathlib import Path

import numpy as np

from uiest import simulate
from uiest.estimators import EKF, UISE, LinearUIO
from uiest.models import linear
from uiest.noise import UniformNoise
from uiest.plotting import save_figure


def build():
    """x+ = A x + B w, y = C x + v with X = +-50 (a safety box; scales 10)."""
    A = np.array([[0.8, 0.3, 0.0], [-0.2, 0.7, 0.4], [0.1, -0.3, 0.6]])
    B, C = np.array([[1.0], [0.0], [0.5]]), np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    return linear.linear_system(A, B, C, x_bounds=(-50, 50), v_bounds=(-0.05, 0.05), x_scale=10.0, name="benchmark")


def unknown_input(steps: int) -> np.ndarray:
    """A step to 5 at k = 50, then a ramp of 0.05 per sample from k = 100; shape (steps, 1)."""
    k = np.arange(steps)
    return (5.0 * (k >= 50) + 0.05 * np.clip(k - 100, 0, None))[:, None]


def run(out: Path, steps: int = 200, seed: int = 0) -> dict[str, float]:
    """Simulate, estimate with the three, write ``linear_uio_benchmark.png``; return the state RMS errors."""
    import matplotlib.pyplot as plt

    system = build()
    noise = UniformNoise.symmetric(0.05)
    x0 = np.array([0.5, -0.5, 0.25])
    record = simulate(system, x0, steps, w=unknown_input(steps), v=noise, seed=seed)
    rng = np.random.default_rng(seed + 1)
    training = simulate(system, x0, steps, w=np.cumsum(0.05 * rng.standard_normal(steps))[:, None], v=noise,
                        seed=seed + 1)  # fmt: skip
    estimators = {
        "linear UIO": LinearUIO(system, x0_prior=np.zeros(3)),
        "UISE (designed)": UISE.design(system, x0_prior=np.zeros(3), trials=1, steps=60),
        "EKF (tuned)": EKF.tuned(system, training, x0_prior=np.zeros(3)),
    }
    results = {label: est.run(None, record.y) for label, est in estimators.items()}
    fig, axes = plt.subplots(2, 1, figsize=(7.5, 4.6), sharex=True)
    k = np.arange(steps + 1)
    axes[0].plot(k[:-1], record.w[:, 0], color="k", lw=1.3, label="true w")
    for j, (label, result) in enumerate(results.items()):
        axes[0].plot(k[:-1], result.w_hat[:, 0], color=f"C{j}", lw=0.9, ls="--", label=label)
        error = np.linalg.norm(result.error(record.x), axis=1)
        axes[1].semilogy(k, error + 1e-16, color=f"C{j}", lw=0.9, label=label)
    axes[0].set_ylabel("unknown input w")
    axes[1].set_ylabel("|x - x_hat|")
    axes[1].set_xlabel("sample k")
    for ax in axes:
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    save_figure(fig, Path(out) / "linear_uio_benchmark.png")
    settled = slice(20, steps + 1)
    return {label: float(np.sqrt(np.mean(r.error(record.x)[settled] ** 2))) for label, r in results.items()}


if __name__ == "__main__":
    print(run(Path(__file__).parent / "figures"))
