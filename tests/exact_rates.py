"""Rates with a bound on cond(P) computed without LMIs, for the certificates' known-answer tests."""

import numpy as np
import scipy.linalg
import scipy.optimize


def kernel_rate(vertices, G, kappa):
    """The smallest rate with cond(P) <= kappa for a 2-state storage whose output sees one direction (free weights).

    Independent of the LMI solve: in the basis (k, m) of ker G_z and its complement, with ``A_i k = alpha_i k +
    beta_i m``, the condition is ``max_i |A_i k|_P^2 / |k|_P^2 < mu``; with ``P = [[1, b], [b, b^2 + d]]`` that is
    ``(alpha_i + beta_i b)^2 + beta_i^2 d``, smallest for the least d of the bound, ``d = lambda_max(P)^2 / kappa``.
    """
    k = scipy.linalg.null_space(G[:, :2])[:, 0]
    m = scipy.linalg.orth(G[:, :2].T)[:, 0]
    alpha = np.array([k @ J[:, :2] @ k for J in vertices])
    beta = np.array([m @ J[:, :2] @ k for J in vertices])

    def worst(b):
        d = 0.0
        for _ in range(60):  # d = lambda_max^2 / kappa, a fixed point
            top = 0.5 * (1 + b * b + d + np.sqrt((1 - b * b - d) ** 2 + 4 * b * b))
            d = top**2 / kappa
        return float(np.max((alpha + beta * b) ** 2 + beta**2 * d))

    reach = np.log10(0.5 * np.sqrt(kappa))  # beyond |b| = sqrt(kappa) / 2 no d meets the bound (no fixed point)
    grid = np.sort(np.concatenate([-np.logspace(-2, reach, 1801), np.logspace(-2, reach, 1801)]))
    i = int(np.clip(np.argmin([worst(b) for b in grid]), 1, len(grid) - 2))
    found = scipy.optimize.minimize_scalar(worst, bounds=(grid[i - 1], grid[i + 1]), method="bounded",
                                           options={"xatol": 1e-12 * abs(grid[i])})  # fmt: skip
    return min(found.fun, worst(grid[i]))


def contraction_rate(F, kappa):
    """``min |P^1/2 F P^-1/2|^2`` over ``P = R(theta) diag(1, e) R(theta)^T``, ``1 <= e <= kappa`` (2 x 2 F).

    Nelder-Mead from 40 starts: the smallest rate of ``|F dz|_P^2 <= mu |dz|_P^2`` with cond(P) <= kappa.
    """

    def norm2(x):
        theta, log_e = x[0], np.clip(x[1], 0.0, np.log(kappa))
        R = np.array([[np.cos(theta), -np.sin(theta)], [np.sin(theta), np.cos(theta)]])
        root = R @ np.diag([1.0, np.exp(0.5 * log_e)]) @ R.T
        return np.linalg.norm(root @ F @ np.linalg.inv(root), 2) ** 2

    starts = np.random.default_rng(0).uniform([0.0, 0.0], [np.pi, np.log(kappa)], (40, 2))
    return min(scipy.optimize.minimize(norm2, x0, method="Nelder-Mead", options={"xatol": 1e-10, "fatol": 1e-12}).fun
               for x0 in starts)  # fmt: skip
