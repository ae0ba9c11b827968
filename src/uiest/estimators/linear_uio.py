r"""The classical full-order unknown input observer for LTI systems (Chen, Patton, Zhang 1996).

For ``x+ = A x + B_u u + B w (+ f_0)``, ``y = C x + D v (+ h_0)`` (offsets allowed; see
``shared/notes/references.md`` section 3)::

    H = B (C B)^+,   T = I - H C,   F = T A - K1 C  (Schur stable),   K = K1 + F H
    z[k+1] = F z[k] + T (B_u u[k] + f_0) + K y'[k],     x_hat[k] = z[k] + H y'[k]
    y'[k]  = y[k] - h_0 - D v_bar,                        z[0] = T x_bar_0

so that ``e[k+1] = F e[k]`` for ``e = T x - z`` whatever w (noise-free): ``T B = 0`` needs the matching
condition ``rank(C B) = rank(B)`` (checked; :class:`~uiest.errors.ModelError` otherwise), and a
Schur stable F needs every invariant zero strictly inside the unit disk (they are eigenvalues of
F for every gain). With noise, ``e[k+1] = F e[k] - K D (v[k] - v_bar)`` and
``x_hat[k] - x[k] = -e[k] + H D (v[k] - v_bar)`` (``e[0] = T (x[0] - x_bar_0)``), so noise-free the error
decays like ``F^k``; :attr:`LinearUIO.guarantee` bounds it for noise in V.

Index convention::

    x_hat[k]   = z[k] + H y'[k]                       (current measurement used)
    w_hat[k-1] = B^+ (x_hat[k] - A x_hat[k-1] - B_u u[k-1] - f_0)   (least squares, minimum norm)

The gain K1: the DARE of the dual pair ``((T A)^T, C^T)`` with Q = R = I (default), pole
placement (``poles=``) or given (``gain=``). Missing channels of ``y[k]`` are replaced by the
predicted output ``C x_pred + h_0 + D v_bar`` with ``x_pred = A x_hat[k-1] + B_u u[k-1] + B w_hat + f_0``
(the last unknown-input estimate): the observer cannot be exact across such a step.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from uiest.box import FloatArray, as_vector
from uiest.checks import real_array
from uiest.detectability import lmi
from uiest.detectability.linear import LinearStrongDetectability, linear_strong_detectability, observer_gain
from uiest.errors import DataError, ModelError, OptionError
from uiest.estimators.base import StreamingEstimator, collect_run
from uiest.estimators.bounds import impulse_bound
from uiest.guarantee import Guarantee
from uiest.health import Outcome, at_bound
from uiest.models.linear import linear_system
from uiest.results import EstimationResult, StepEstimate
from uiest.run_data import check_run_data, check_u_prev, check_y
from uiest.system import System
from uiest.theory import LINEAR_STRONG_DETECTABILITY

__all__ = ["LinearUIO"]


class LinearUIO(StreamingEstimator):
    r"""Chen-Patton-Zhang unknown input observer (see the module docstring).

    Parameters
    ----------
    system : System
        A linear (affine) system: constant Jacobians of f and h (checked); its matrices come from
        ``system.linearize``. See :meth:`from_matrices` to start from matrices.
    poles : sequence of complex, optional
        The nx eigenvalues of F, placed by scipy's ``place_poles`` on ``((T A)^T, C^T)``. The
        invariant zeros are eigenvalues of F for every gain, so they must be among the poles.
    gain : array_like (nx, ny), optional
        K1 given (F = T A - K1 C must be Schur stable).
    x0_prior : array_like (nx,), optional
        Prior of x[0] (or give it to :meth:`reset` / :meth:`run`).
    v_prior : array_like (nv,), optional
        Noise prior ``v_bar`` (default 0).
    rtol : float
        Rank tolerance of the matching test (:func:`~uiest.detectability.linear_strong_detectability`).

    Attributes
    ----------
    A, B_u, B, C, D : ndarray
        The system's matrices (B: unknown input, D: noise).
    H, T, F, K1, K : ndarray
        The observer's matrices.
    detectability : LinearStrongDetectability
        The Hautus test of ``(A, B, C)`` (matching, invariant zeros).

    """

    estimator_name = "LinearUIO"
    theorem = f"linear UIO error dynamics (Chen-Patton-Zhang), with {LINEAR_STRONG_DETECTABILITY}"
    N = None

    def __init__(
        self,
        system: System,
        *,
        poles: Sequence[complex] | None = None,
        gain: ArrayLike | None = None,
        x0_prior: ArrayLike | None = None,
        v_prior: ArrayLike | None = None,
        rtol: float = 1e-9,
    ) -> None:
        if not isinstance(system, System):
            raise OptionError(f"system: expected a uiest.System, got {type(system).__name__}")
        jac = system.jacobian_function
        names = ("A", "B_u", "B", "C", "D")
        varying = [name for i, name in enumerate(names) if not lmi.is_constant(jac, i, [0, 1, 2, 3])]
        if varying:
            raise ModelError(
                f"system: expected a linear (affine) system with constant Jacobians, but {varying} vary with x, u, w "
                "or v; the linear UIO needs x+ = A x + B_u u + B w, y = C x + D v"
            )
        self.system = system
        nx, nu, nw, nv = system.nx, system.nu, system.nw, system.nv
        lin = system.linearize(np.zeros(nx), np.zeros(nu), np.zeros(nw), np.zeros(nv))
        self.A, self.B_u, self.B, self.C, self.D = (np.asarray(m, dtype=float) for m in (lin.A, lin.B_u, lin.B_w,
                                                                                        lin.C, lin.D_v))  # fmt: skip
        self.f0 = system.step(np.zeros(nx), np.zeros(nu), np.zeros(nw))
        self.h0 = system.output(np.zeros(nx), np.zeros(nv))
        self.detectability: LinearStrongDetectability = linear_strong_detectability(self.A, self.B, self.C, rtol=rtol)
        det = self.detectability
        if not det.matching:
            raise ModelError(f"system: no unknown input observer exists: {det.reason}")
        if not det.strongly_detectable:
            raise ModelError(f"system: no stable unknown input observer exists: {det.reason}")
        CB = self.C @ self.B
        self.H = self.B @ np.linalg.pinv(CB, rcond=rtol) if self.B.size else np.zeros((nx, system.ny))
        self.T = np.eye(nx) - self.H @ self.C
        E = self.T @ self.A
        if poles is not None and gain is not None:
            raise OptionError("poles, gain: give at most one of them")
        if gain is not None:
            K1 = real_array(gain, "gain", f"a matrix of shape ({nx}, {system.ny})", error=OptionError)
            if K1.shape != (nx, system.ny):
                raise OptionError(f"gain: expected shape ({nx}, {system.ny}), got {K1.shape}")
            if not np.all(np.isfinite(K1)):
                raise OptionError(f"gain: expected finite entries, got {K1.tolist()}")
        elif poles is not None:
            try:
                wanted = np.asarray(poles, dtype=complex).reshape(-1)
            except (TypeError, ValueError):
                raise OptionError(f"poles: expected {nx} numbers, got {poles!r}") from None
            if not np.all(np.isfinite(wanted)):
                raise OptionError(f"poles: expected finite numbers, got {np.round(wanted, 6).tolist()}")
            if wanted.size != nx:
                raise OptionError(f"poles: expected {nx} poles, got {wanted.size}")
            gaps = [np.min(np.abs(wanted - z), initial=np.inf) / (1 + abs(z)) for z in det.invariant_zeros]
            absent = [z for z, gap in zip(det.invariant_zeros, gaps, strict=True) if gap > 1e-6]
            if absent:
                raise OptionError(
                    f"poles: the invariant zeros {np.round(absent, 6).tolist()} are eigenvalues of F for every gain; "
                    f"include them among the poles, got {np.round(wanted, 6).tolist()}"
                )
            try:
                import scipy.signal  # imported when used: it takes most of `import uiest.estimators`

                K1 = scipy.signal.place_poles(E.T, self.C.T, wanted).gain_matrix.T
            except ValueError as exc:
                raise OptionError(f"poles: pole placement on (T A, C) failed: {exc}") from exc
        else:
            try:
                K1 = observer_gain(E, self.C)
            except (np.linalg.LinAlgError, ValueError) as exc:
                raise ModelError(f"system: the Riccati equation for the observer gain of (T A, C) failed ({exc}); "
                                 "give poles= or gain=") from exc  # fmt: skip
        self.K1 = np.asarray(K1, dtype=float)
        self.F = E - self.K1 @ self.C
        self.spectral_radius = float(np.max(np.abs(np.linalg.eigvals(self.F)), initial=0.0))
        if not self.spectral_radius < 1.0:
            source = "poles" if poles is not None else "gain"
            raise OptionError(
                f"{source}: F = T A - K1 C has spectral radius {self.spectral_radius:.6g} >= 1; "
                "expected a Schur stable F"
            )
        self.K = self.K1 + self.F @ self.H
        self.v_prior = np.zeros(nv) if v_prior is None else as_vector(v_prior, nv, "v_prior")
        if not system.v.bounds.contains(self.v_prior):
            raise DataError(f"v_prior: expected a point in V = {system.v.bounds}, got {self.v_prior.tolist()}")
        self._x0_prior: FloatArray | None = None
        self._clear()
        if x0_prior is not None:
            self.reset(x0_prior)

    @classmethod
    def from_matrices(
        cls,
        A: ArrayLike,
        B: ArrayLike,
        C: ArrayLike,
        *,
        B_u: ArrayLike | None = None,
        system_options: dict[str, Any] | None = None,
        **options: Any,
    ) -> LinearUIO:
        """The observer of ``x+ = A x + B_u u + B w``, ``y = C x + v``.

        ``system_options`` go to :func:`uiest.models.linear.linear_system` (bounds, names, dt);
        further keywords to the constructor.
        """
        return cls(linear_system(A, B, C, B_u=B_u, **(system_options or {})), **options)

    # ------------------------------------------------------------------ state
    def _clear(self) -> None:
        self._k = 0
        self._z: FloatArray | None = None
        self._y_last: FloatArray | None = None
        self._x_last: FloatArray | None = None
        self._w_last: FloatArray | None = None

    # ------------------------------------------------------------------ steps
    def _offset_output(self, y: FloatArray, u_prev: FloatArray) -> FloatArray:
        """``y' = y - h_0 - D v_bar`` with missing channels predicted (module docstring)."""
        missing = np.isnan(y)
        if missing.any():
            if self._x_last is None:
                x_pred = self._x0_prior
            else:
                w = self._w_last if self._w_last is not None else self.system.nominal_w
                x_pred = self.A @ self._x_last + self.B_u @ u_prev + self.B @ w + self.f0
            y = np.where(missing, self.C @ x_pred + self.h0 + self.D @ self.v_prior, y)
        return y - self.h0 - self.D @ self.v_prior

    def step(self, u_prev: ArrayLike | None, y: ArrayLike) -> StepEstimate:
        """Process ``u[k-1]`` and ``y[k]``; return the estimate of ``x[k]`` (``UPDATED``; ``PROPAGATED`` if no y)."""
        if self._x0_prior is None:
            raise OptionError("x0_prior: required; pass it to the constructor or call reset(x0_prior) first")
        start = time.perf_counter()
        k = self._k
        u_vec = check_u_prev(self.system, u_prev, k)
        y_vec = check_y(self.system, y)
        y_eff = self._offset_output(y_vec, u_vec)
        if k == 0:
            z = self.T @ self._x0_prior
        else:
            assert self._z is not None and self._y_last is not None
            z = self.F @ self._z + self.T @ (self.B_u @ u_vec + self.f0) + self.K @ self._y_last
        x_hat = z + self.H @ y_eff
        w_hat, w_index = None, None
        if k > 0 and self._x_last is not None:
            rhs = x_hat - self.A @ self._x_last - self.B_u @ u_vec - self.f0
            w_hat, w_index = np.linalg.lstsq(self.B, rhs, rcond=None)[0], k - 1
        self._z, self._y_last, self._x_last = z, y_eff, x_hat
        if w_hat is not None:
            self._w_last = w_hat
        self._k = k + 1
        return StepEstimate(
            k=k,
            x_hat=x_hat,
            w_hat=w_hat,
            w_index=w_index,
            outcome=Outcome.PROPAGATED if np.isnan(y_vec).all() else Outcome.UPDATED,
            iterations=0,
            solve_time=time.perf_counter() - start,
            cost=0.0,
            window=0,
            missing=np.isnan(y_vec),
            at_bound=at_bound(self.system.x.bounds, x_hat, self.system.x.scale),
        )

    def run(self, u: ArrayLike | None, y: ArrayLike, *, x0_prior: ArrayLike | None = None) -> EstimationResult:
        """Estimate ``x[0..K]`` from ``u (K, nu)`` and ``y (K+1, ny)``, starting from a reset."""
        u_arr, y_arr = check_run_data(self.system, u, y)
        self.reset(x0_prior)
        return collect_run(self, u_arr, y_arr)

    # ------------------------------------------------------------------ guarantee
    @property
    def guarantee(self) -> Guarantee:
        """:data:`~uiest.estimators.bounds.SETTLED` (1.1) times the exact worst case of ``x_hat - x`` over noise in V.

        (e+ = F e; module docstring.)

        ``x_hat[k] - x[k] = -F^k T (x[0] - x_bar_0) + sum_{j<k} F^{k-1-j} K D dv[j] + H D dv[k]``
        with ``dv = v - v_bar`` in ``V - v_bar``, whatever w: the impulse response summed with each
        noise sample at the side of V that makes it largest
        (:func:`~uiest.estimators.bounds.impulse_bound`).
        """
        V = self.system.v.bounds
        width = self.system.x.bounds.width
        with np.errstate(invalid="ignore"):
            transient = np.where(self.T == 0.0, 0.0, self.T * width[None, :])  # e[0] = T (x[0] - x_bar_0)
        bound, settling = impulse_bound(self.F, self.H @ self.D, self.K @ self.D, transient, V.lower - self.v_prior,
                                        V.upper - self.v_prior)  # fmt: skip
        zeros = np.round(self.detectability.invariant_zeros, 6).tolist()
        assumes = (
            f"e+ = F e with spectral radius {self.spectral_radius:.4g} < 1 (invariant zeros {zeros} are eigenvalues of "
            f"F); noise in V around v_prior {np.round(self.v_prior, 12).tolist()}, every output measured; any "
            "unknown input"
        )
        return self._holds(self.theorem, bound, settling, assumes)

    def __repr__(self) -> str:
        return (
            f"LinearUIO(system={self.system.name!r}, spectral_radius={self.spectral_radius:.4g}, "
            f"guarantee={str(self.guarantee)!r})"
        )
