"""Linear systems ``x+ = A x + B_u u + B w``, ``y = C x + v`` and examples with chosen invariant zeros."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike

from uiest.box import FloatArray
from uiest.checks import check_int, check_seed, real_array
from uiest.errors import ModelError
from uiest.system import System

__all__ = ["example", "linear_system", "with_invariant_zeros"]


def _matrix(value: ArrayLike, name: str, rows: int | None = None, cols: int | None = None) -> FloatArray:
    arr = real_array(value, name, "a real matrix", error=ModelError)
    if arr.ndim == 1 and rows is not None and cols == 1:
        arr = arr.reshape(-1, 1)
    if arr.ndim != 2 or (rows is not None and arr.shape[0] != rows) or (cols is not None and arr.shape[1] != cols):
        raise ModelError(f"{name}: expected a matrix of shape ({rows or 'any'}, {cols or 'any'}), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ModelError(f"{name}: expected finite entries")
    return arr


def linear_system(
    A: ArrayLike,
    B: ArrayLike,
    C: ArrayLike,
    *,
    B_u: ArrayLike | None = None,
    name: str = "linear",
    **spec: Any,
) -> System:
    """The LTI system ``x+ = A x + B_u u + B w``, ``y = C x + v`` as a :class:`System`.

    Parameters
    ----------
    A : array_like, shape (nx, nx)
    B : array_like, shape (nx, nw)
        Unknown-input matrix.
    C : array_like, shape (ny, nx)
        Output matrix; the noise enters every output additively (nv = ny).
    B_u : array_like, shape (nx, nu), optional
        Known-input matrix (nu = 0 when omitted).
    **spec
        Bounds, names, units, scales, dt as in :meth:`System.from_functions`.

    """
    A_ = _matrix(A, "A")
    nx = A_.shape[0]
    if A_.shape != (nx, nx):
        raise ModelError(f"A: expected a square matrix, got shape {A_.shape}")
    B_ = _matrix(B, "B", nx, None if np.ndim(B) == 2 else 1)
    C_ = _matrix(C, "C", None, nx)
    Bu = np.zeros((nx, 0)) if B_u is None else _matrix(B_u, "B_u", nx, None if np.ndim(B_u) == 2 else 1)
    x, u, w, v = (
        ca.SX.sym("x", nx),
        ca.SX.sym("u", Bu.shape[1]),
        ca.SX.sym("w", B_.shape[1]),
        ca.SX.sym("v", C_.shape[0]),
    )
    x_next = ca.mtimes(ca.DM(A_), x) + ca.mtimes(ca.DM(Bu), u) + ca.mtimes(ca.DM(B_), w)
    y = ca.mtimes(ca.DM(C_), x) + v
    return System.from_expressions(x, u, w, v, x_next, y, name=name, **spec)


def _real_block(zeros: Sequence[complex]) -> FloatArray:
    """A real block-diagonal matrix whose eigenvalues are ``zeros`` (complex ones in conjugate pairs)."""
    blocks: list[FloatArray] = []
    pending = [complex(z) for z in zeros]
    while pending:
        z = pending.pop(0)
        if abs(z.imag) < 1e-14:
            blocks.append(np.array([[z.real]]))
            continue
        try:
            pending.remove(z.conjugate())
        except ValueError as exc:
            raise ModelError(f"zeros: complex zero {z} needs its conjugate in the list") from exc
        blocks.append(np.array([[z.real, z.imag], [-z.imag, z.real]]))
    size = sum(b.shape[0] for b in blocks)
    out = np.zeros((size, size))
    i = 0
    for b in blocks:
        out[i : i + b.shape[0], i : i + b.shape[0]] = b
        i += b.shape[0]
    return out


def with_invariant_zeros(
    zeros: Sequence[complex],
    *,
    nw: int = 1,
    extra_outputs: int = 0,
    seed: int = 0,
    name: str = "linear-zeros",
    **spec: Any,
) -> tuple[System, FloatArray, FloatArray, FloatArray]:
    """A strongly-structured LTI system whose invariant zeros are exactly ``zeros``.

    Construction: ``nw`` measured states ``x_m`` driven by the unknown input and ``len(zeros)``
    hidden states ``x_h`` with ``x_h+ = Z x_h + K x_m`` (Z real with eigenvalues ``zeros``).
    With ``y = x_m`` the unknown input can mask ``x_h`` from the output only through ``x_m``,
    so the Rosenbrock pencil loses rank exactly at the eigenvalues of Z and rank(CB) = rank(B).
    ``extra_outputs`` adds outputs that are random combinations of ``x_m`` (a non-square C with
    the same zeros). A random orthogonal change of coordinates hides the structure.

    Returns
    -------
    system, A, B, C
        The System and its matrices (A (n, n), B (n, nw), C (ny, n)).

    """
    nw = check_int(nw, "nw", low=1, error=ModelError)
    extra_outputs = check_int(extra_outputs, "extra_outputs", error=ModelError)
    rng = np.random.default_rng(check_seed(seed))
    Z = _real_block(zeros) if len(zeros) else np.zeros((0, 0))
    nh = Z.shape[0]
    n = nw + nh
    A = np.zeros((n, n))
    A[:nw, :nw] = 0.5 * rng.standard_normal((nw, nw))
    A[:nw, nw:] = rng.standard_normal((nw, nh))
    A[nw:, :nw] = rng.standard_normal((nh, nw))
    A[nw:, nw:] = Z
    B = np.vstack([np.eye(nw), np.zeros((nh, nw))])
    C = np.hstack([np.eye(nw), np.zeros((nw, nh))])
    if extra_outputs:
        C = np.vstack([C, rng.standard_normal((extra_outputs, nw)) @ C])
    Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    A_t, B_t, C_t = Q @ A @ Q.T, Q @ B, C @ Q.T
    return linear_system(A_t, B_t, C_t, name=name, **spec), A_t, B_t, C_t


def example() -> System:
    """The registered ``linear-example``: 3 states, 1 unknown input, 1 output, zeros {0.5, 0.2}.

    Strongly detectable (rank(CB) = rank(B), all invariant zeros inside the unit disk); the
    smallest certifiable discount is ``mu = 0.25``.
    """
    system, *_ = with_invariant_zeros(
        [0.5, 0.2], nw=1, seed=1, name="linear-example", x_bounds=(-10.0, 10.0), v_bounds=(-1e-3, 1e-3)
    )
    return system
