r"""The moving-window weighted nonlinear least-squares problem shared by every optimisation estimator.

The problem is posed on a :class:`~uiest.window.model.WindowModel` (``x+ = f(x, u, w, v, d)``,
``y = h(x, v, d)``, optional node constraints); a :class:`~uiest.system.System` is wrapped by
:meth:`WindowModel.from_system` (``f(x, u, w)``, ``h(x, v)``). Below, "system" means the model.

A window of ``L`` transitions covers the times ``s .. s+L`` (node ``i`` is time ``s+i``). Its
decision variables, stacked stage by stage as ``[x_0, v_0, w_0, x_1, v_1, w_1, ..., x_L, v_L]``
(``v_i`` only at measured nodes), are in **scaled coordinates**

::

    x_i = c_x + S_x x~_i,   w_i = c_w + S_w w~_i,   v_i = c_v + S_v v~_i,

with ``S = diag(signal.scale)`` and ``c`` the centre of the signal's domain (:func:`working_center`;
for w the centre of the range the problem is given, else ``system.nominal_w``). Multiple
shooting: the dynamics are equality constraints

::

    g_i = (f(x_i, u_i, w_i, v_i, d_i) - x_{i+1}) / s_x = 0,        i = 0 .. L-1,

(``v_i`` is node i's noise estimate, used only when f depends on v; ``d_i`` node i's data),

so the state box X is a simple bound on every node. The cost is ``J = |r|^2`` with the
residual vector

::

    r = [ Wp^{1/2} (x_0 - prior) / s_x ;
          for each measured node m:  Wy_m^{1/2} (mask_m * (y_m - h(x_m, v_m)) / s_y) ;
                                     Wv_m^{1/2} (v_m - v_bar_m) / s_v ;
          for each transition i:     Ww_i^{1/2} (w_i - w_bar_i) / s_w      (only if Ww given) ]

where the weights ``W`` are given in original units and converted to scaled ones
(``W~ = S W S``); ``M^{1/2}`` is the symmetric square root. ``mask`` (0/1 per output channel)
drops missing measurements. Outputs constrained to a box Y with finite sides add
``(h(x_m, v_m) - c_y) / s_y`` to g with bounds; node constraints ``c(x_m, v_m, d_m)`` of the
model add ``(c - c_c) / s_c`` at measured nodes (components with a finite side only).

Everything that changes from one step to the next, and the weights, are parameters ``p``:
``[prior (nx), u (L, nu), y (M, ny), mask (M, ny), v_bar (M, nv), w_bar (L, nw), data (L+1, nd),
weights]`` (row-major; ``weights`` holds the scaled square roots ``(S W S)^{1/2}`` of each block,
see :meth:`WindowProblem.weight_vector`), so the problem is built once per window length and
re-solved, and new weights (another rate, another certificate) need no rebuild. A Gauss-Newton backend needs
only :attr:`WindowProblem.residual_function`, :attr:`WindowProblem.constraint_function` and
the bounds; IPOPT uses :meth:`WindowProblem.nlp`.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike, NDArray

from uiest.box import Box, FloatArray
from uiest.checks import all_finite
from uiest.errors import DataError, OptionError
from uiest.system import System
from uiest.window.model import WindowModel

__all__ = ["WIDE", "WindowProblem", "WindowTrajectory", "WindowWeights", "sqrt_psd", "working_center"]


def sqrt_psd(matrix: ArrayLike, name: str) -> FloatArray:
    """Symmetric square root of a symmetric positive semidefinite matrix, or of each of a stack of them.

    Parameters
    ----------
    matrix : array_like, shape (n, n) or (m, n, n)
        Symmetric, eigenvalues >= -1e-10 * largest (tiny negative ones are set to zero); a stack is
        taken matrix by matrix, in one vectorised pass.
    name : str
        Argument name used in error messages (``name[i]`` for the ``i``-th matrix of a stack).

    Returns
    -------
    ndarray, the shape of ``matrix``
        ``M`` with ``M = M^T`` and ``M @ M = matrix`` (for each matrix of a stack).

    """
    arr = np.asarray(matrix, dtype=float)
    if arr.ndim not in (2, 3) or arr.shape[-1] != arr.shape[-2]:
        raise OptionError(f"{name}: expected a square matrix (or a stack of them), got shape {arr.shape}")
    if arr.size == 0:
        return arr.copy()
    stack = arr.reshape(-1, *arr.shape[-2:])

    def first(bad: np.ndarray) -> str:
        return name if arr.ndim == 2 else f"{name}[{int(np.argmax(bad))}]"

    finite = np.isfinite(stack).all(axis=(1, 2))
    if not finite.all():
        raise OptionError(f"{first(~finite)}: expected finite entries")
    transposed = stack.transpose(0, 2, 1)
    scale = np.maximum(1.0, np.abs(stack).max(axis=(1, 2)))
    # np.allclose(M, M^T, rtol=1e-8, atol=1e-12 * scale), matrix by matrix
    symmetric = (np.abs(stack - transposed) <= 1e-12 * scale[:, None, None] + 1e-8 * np.abs(transposed)).all(
        axis=(1, 2)
    )
    if not symmetric.all():
        raise OptionError(f"{first(~symmetric)}: expected a symmetric matrix")
    eigval, eigvec = np.linalg.eigh(0.5 * (stack + transposed))
    smallest = eigval.min(axis=1)
    negative = smallest < -1e-10 * np.maximum(1e-300, np.abs(eigval).max(axis=1))
    if negative.any():
        raise OptionError(
            f"{first(negative)}: expected a positive semidefinite matrix, smallest eigenvalue "
            f"{smallest[np.argmax(negative)]:.3g}"
        )
    root: FloatArray = (eigvec * np.sqrt(np.clip(eigval, 0.0, None))[:, None, :]) @ eigvec.transpose(0, 2, 1)
    return root.reshape(arr.shape)


LARGEST_WEIGHT = 1e6
"""The NLP's cost is scaled so that no squared weight root exceeds this (see :meth:`WindowProblem.objective_scale`)."""


WIDE = 1e6
"""A box wider than this many scales is not centred on its midpoint (see :func:`working_center`)."""


def working_center(box: Box, scale: FloatArray) -> FloatArray:
    """The origin of the scaled coordinates: the box's centre, or the point of the box nearest 0.

    The latter where the box is wider than ``WIDE`` scales (a domain meant as "unbounded"), so that
    values of the scale's magnitude are not resolved against a centre of the width's magnitude.
    """
    wide = ~(box.width <= WIDE * scale)
    return np.where(wide, np.clip(0.0, box.lower, box.upper), box.center)


@dataclass(frozen=True, eq=False)
class WindowWeights:
    """Weights of one window's residuals, in original units.

    Attributes
    ----------
    prior : ndarray (nx, nx)
        Weight of ``|x_0 - prior|^2``.
    y : ndarray (M, ny, ny)
        Output weight at each measured node (M = number of measured nodes).
    v : ndarray (M, nv, nv)
        Noise weight ``|v - v_bar|^2`` at each measured node.
    w : ndarray (L, nw, nw) or None
        Unknown-input weight ``|w - w_bar|^2`` per transition; None: w is not penalised.

    """

    prior: FloatArray
    y: FloatArray
    v: FloatArray
    w: FloatArray | None = None


@dataclass(frozen=True)
class WindowTrajectory:
    """A window's variables in original units: ``x (L+1, nx)``, ``w (L, nw)``, ``v (M, nv)``."""

    x: FloatArray
    w: FloatArray
    v: FloatArray


IntArray = NDArray[np.int_]


def _index_layout(L: int, nodes: IntArray, nx: int, nv: int, nw: int) -> tuple[IntArray, IntArray, IntArray, int]:
    """The decision vector's layout, stage-wise ``[x_i, v_i (if measured), w_i (if i < L)]``.

    Returns the indices of ``x`` (L+1, nx), ``w`` (L, nw) and ``v`` (M, nv, one row per measured node) and the
    number of variables.
    """
    M = nodes.size
    x_index = np.empty((L + 1, nx), dtype=int)
    w_index = np.empty((L, nw), dtype=int)
    v_index = np.empty((M, nv), dtype=int)
    pos, m = 0, 0
    for i in range(L + 1):
        x_index[i] = np.arange(pos, pos + nx)
        pos += nx
        if m < M and nodes[m] == i:
            v_index[m] = np.arange(pos, pos + nv)
            pos += nv
            m += 1
        if i < L:
            w_index[i] = np.arange(pos, pos + nw)
            pos += nw
    return x_index, w_index, v_index, pos


class WindowProblem:
    """One window's weighted nonlinear least-squares problem, built once with data as parameters.

    Parameters
    ----------
    system : System or WindowModel
        The model (a System is wrapped by :meth:`WindowModel.from_system`).
    length : int
        Number of transitions L >= 0 (the window has L+1 state nodes).
    measured : sequence of int
        Node indices (0..L) that carry a measurement; increasing.
    weights : WindowWeights, optional
        Default residual weights (original units; shapes must match ``measured`` and ``length``),
        used when :meth:`parameters` is given none.
    weighted_w : bool, optional
        Whether the unknown input has a residual ``|w - w_bar|`` (default: whether ``weights.w``
        is given).
    x_box : Box, optional
        Bound on every state node (default: the model's ``x_bounds``).
    v_box : Box, optional
        Bound on every noise estimate (default: the model's ``v_bounds``).
    w_box : Box, optional
        Bound on every unknown-input estimate (default: unbounded; the standard MHE passes
        ``system.w_range``).
    output_constraints : bool
        Constrain ``h(x_m, v_m)`` to ``system.y.bounds`` at measured nodes when Y has a finite side.
    node_constraints : bool
        Impose the model's node constraints (if it has any) at measured nodes.

    Attributes
    ----------
    model : WindowModel
    system : System or None
        The System the problem was built from (None for other window models).

    """

    def __init__(
        self,
        system: System | WindowModel,
        length: int,
        measured: ArrayLike,
        weights: WindowWeights | None = None,
        *,
        weighted_w: bool | None = None,
        x_box: Box | None = None,
        v_box: Box | None = None,
        w_box: Box | None = None,
        output_constraints: bool = True,
        node_constraints: bool = True,
    ) -> None:
        if isinstance(length, bool) or not isinstance(length, int | np.integer) or length < 0:
            raise OptionError(f"length: expected a non-negative integer, got {length!r}")
        if isinstance(system, System):
            self.system: System | None = system
            self.model = WindowModel.from_system(system)
        elif isinstance(system, WindowModel):
            self.system, self.model = None, system
        else:
            raise OptionError(f"system: expected a System or a WindowModel, got {type(system).__name__}")
        model = self.model
        self.length = L = int(length)
        nodes = np.asarray(measured, dtype=int).reshape(-1)
        if nodes.size and (nodes.min() < 0 or nodes.max() > L or np.any(np.diff(nodes) <= 0)):
            raise OptionError(f"measured: expected increasing node indices in 0..{L}, got {nodes.tolist()}")
        self.measured = nodes
        self.measured_row = np.full(L + 1, -1, dtype=int)
        """Node ``i``'s row of ``v`` (M, nv), -1 where node ``i`` is not measured; shape (L+1,)."""
        self.measured_row[nodes] = np.arange(nodes.size)
        self.n_meas = M = int(nodes.size)
        nx, nw, nv, ny = model.nx, model.nw, model.nv, model.ny
        self.f_uses_v = model.f_uses_v
        missing = sorted(set(range(L)) - set(nodes.tolist()))
        if self.f_uses_v and missing:
            raise OptionError(
                f"measured: the dynamics depend on the noise, so every node 0..{L - 1} needs a noise estimate; "
                f"nodes {missing} are not measured"
            )
        self.x_box = model.x_bounds if x_box is None else x_box
        self.v_box = model.v_bounds if v_box is None else v_box
        self.w_box = Box.unbounded(nw) if w_box is None else w_box
        for label, box, n in (("x_box", self.x_box, nx), ("v_box", self.v_box, nv), ("w_box", self.w_box, nw)):
            if box.size != n:
                raise OptionError(f"{label}: expected dimension {n}, got {box.size}")
        self.weighted_w = bool(weights is not None and weights.w is not None) if weighted_w is None else weighted_w

        # scaling: z = c + s * z~
        self.x_center, self.x_scale = working_center(self.x_box, model.x_scale), model.x_scale
        self.v_center, self.v_scale = working_center(self.v_box, model.v_scale), model.v_scale
        self.w_center = (
            working_center(self.w_box, model.w_scale) if self.w_box != Box.unbounded(nw) else model.nominal_w
        )
        self.w_scale = model.w_scale
        self.y_center, self.y_scale = working_center(model.y_bounds, model.y_scale), model.y_scale

        self.x_index, self.w_index, self.v_index, self.n_var = _index_layout(L, nodes, nx, nv, nw)
        # x, w, v flattened in this order: their positions in z, centres and scales (pack, unpack)
        self._flat_index = np.concatenate((self.x_index.ravel(), self.w_index.ravel(), self.v_index.ravel()))
        self._flat_center = np.concatenate((np.tile(self.x_center, L + 1), np.tile(self.w_center, L),
                                            np.tile(self.v_center, M)))  # fmt: skip
        self._flat_scale = np.concatenate(
            (np.tile(self.x_scale, L + 1), np.tile(self.w_scale, L), np.tile(self.v_scale, M))
        )
        self._flat_ends = ((L + 1) * nx, (L + 1) * nx + L * nw)
        y_lo, y_hi = model.y_bounds.lower, model.y_bounds.upper
        self.has_output_constraints = bool(
            output_constraints and M > 0 and (np.isfinite(y_lo).any() or np.isfinite(y_hi).any())
        )
        if node_constraints and model.node_bounds is not None and M > 0:
            finite = np.isfinite(model.node_bounds.lower) | np.isfinite(model.node_bounds.upper)
            self.node_rows = np.flatnonzero(finite)
        else:
            self.node_rows = np.zeros(0, dtype=int)
        self.n_dyn = L * nx
        self.n_out_con = M * ny if self.has_output_constraints else 0
        self.n_node_con = M * self.node_rows.size
        self.n_con = self.n_dyn + self.n_out_con + self.n_node_con
        self.parameter_slices = self._parameter_layout()
        self.n_par = max((part.stop for part in self.parameter_slices.values()), default=0)
        self._build()
        self.default_weights = None if weights is None else self.weight_vector(weights)

    def _parameter_layout(self) -> dict[str, slice]:
        """Where each part of the parameter vector ``p`` sits: prior, u, y, mask, v_bar, w_bar, data, weights."""
        model, L, M = self.model, self.length, self.n_meas
        nx, nu, nw, nv, ny, nd = model.nx, model.nu, model.nw, model.nv, model.ny, model.nd
        sizes = {
            "prior": nx,
            "u": L * nu,
            "y": M * ny,
            "mask": M * ny,
            "v_bar": M * nv,
            "w_bar": L * nw,
            "data": (L + 1) * nd,
            "weights": nx * nx + M * (ny * ny + nv * nv) + (L * nw * nw if self.weighted_w else 0),
        }
        slices: dict[str, slice] = {}
        start = 0
        for key, size in sizes.items():
            slices[key] = slice(start, start + size)
            start += size
        return slices

    # ------------------------------------------------------------------ construction
    def weight_vector(self, weights: WindowWeights) -> FloatArray:
        """The weights' part of ``p``: scaled symmetric square roots ``(S W S)^{1/2}``, block by block.

        Raises OptionError for wrong shapes or weights that are not symmetric positive semidefinite.
        """
        s = self.model
        L, M = self.length, self.n_meas
        blocks: list[tuple[str, ArrayLike, tuple[int, ...], FloatArray]] = [
            ("prior", weights.prior, (s.nx, s.nx), self.x_scale),
            ("y", weights.y, (M, s.ny, s.ny), self.y_scale),
            ("v", weights.v, (M, s.nv, s.nv), self.v_scale),
        ]
        if self.weighted_w:
            if weights.w is None:
                raise OptionError("weights.w: this problem penalises w, expected weights of shape (L, nw, nw)")
            blocks.append(("w", weights.w, (L, s.nw, s.nw), self.w_scale))
        parts = []
        for label, value, shape, scale in blocks:
            arr = np.asarray(value, dtype=float)
            if arr.shape != shape:
                raise OptionError(f"weights.{label}: expected shape {shape}, got {arr.shape}")
            parts.append(sqrt_psd(np.outer(scale, scale) * arr, f"weights.{label}").ravel())
        return np.concatenate(parts) if parts else np.zeros(0)

    def _build(self) -> None:
        s = self.model
        nx, nu, nw, nv, ny, nd = s.nx, s.nu, s.nw, s.nv, s.ny, s.nd
        L, M = self.length, self.n_meas
        z = ca.SX.sym("z", self.n_var)
        p = ca.SX.sym("p", self.n_par)

        def take(index: np.ndarray) -> ca.SX:
            return z[[int(i) for i in index]] if index.size else ca.SX(0, 1)

        def par(key: str, row: int, width: int) -> ca.SX:
            start = self.parameter_slices[key].start + row * width
            return p[start : start + width] if width else ca.SX(0, 1)

        # centres and scales as DMs once (a DM built per stage costs more than the stage's expressions)
        x_center, x_scale = ca.DM(self.x_center), ca.DM(self.x_scale)
        w_center, w_scale = ca.DM(self.w_center), ca.DM(self.w_scale)
        v_center, v_scale = ca.DM(self.v_center), ca.DM(self.v_scale)
        y_center, y_scale = ca.DM(self.y_center), ca.DM(self.y_scale)
        xs = [x_center + x_scale * take(self.x_index[i]) for i in range(L + 1)]
        ws = [w_center + w_scale * take(self.w_index[i]) for i in range(L)]
        vs = [v_center + v_scale * take(self.v_index[m]) for m in range(M)]
        ds = [par("data", i, nd) for i in range(L + 1)]
        node_of = {int(node): m for m, node in enumerate(self.measured)}
        offset = [self.parameter_slices["weights"].start]

        def root(n: int) -> ca.SX:
            """The next (n, n) weight root of the parameter vector (symmetric: row or column order alike)."""
            start = offset[0]
            offset[0] += n * n
            return ca.reshape(p[start : start + n * n], n, n) if n else ca.SX(0, 0)

        residuals = [ca.mtimes(root(nx), (xs[0] - par("prior", 0, nx)) / x_scale)]
        outputs = []
        roots_y = [root(ny) for _ in range(M)]
        roots_v = [root(nv) for _ in range(M)]
        for m, node in enumerate(self.measured):
            y_hat = s.h(xs[int(node)], vs[m], ds[int(node)])
            outputs.append(y_hat)
            diff = par("mask", m, ny) * (par("y", m, ny) - y_hat) / y_scale
            residuals.append(ca.mtimes(roots_y[m], diff))
            residuals.append(ca.mtimes(roots_v[m], (vs[m] - par("v_bar", m, nv)) / v_scale))
        if self.weighted_w:
            for i in range(L):
                residuals.append(ca.mtimes(root(nw), (ws[i] - par("w_bar", i, nw)) / w_scale))
        r = ca.vertcat(*residuals)
        dynamics = [
            (s.f(xs[i], par("u", i, nu), ws[i], vs[node_of[i]] if i in node_of else v_center, ds[i]) - xs[i + 1])
            / x_scale
            for i in range(L)
        ]
        constraints = list(dynamics)
        if self.has_output_constraints:
            constraints += [(y_hat - y_center) / y_scale for y_hat in outputs]
        rows = [int(r) for r in self.node_rows]
        if rows:
            assert s.node_constraint is not None and s.node_bounds is not None and s.node_scale is not None
            c_center = ca.DM(working_center(s.node_bounds, s.node_scale)[rows])
            c_scale = ca.DM(s.node_scale[rows])
            for m, node in enumerate(self.measured):
                c = s.node_constraint(xs[int(node)], vs[m], ds[int(node)])[rows]
                constraints.append((c - c_center) / c_scale)
        g = ca.vertcat(*constraints) if constraints else ca.SX(0, 1)
        self.z, self.p, self.r, self.g = z, p, r, g
        self.n_res = int(r.numel())

        lbx = np.empty(self.n_var)
        ubx = np.empty(self.n_var)
        for index, box, center, scale in (
            (self.x_index, self.x_box, self.x_center, self.x_scale),
            (self.w_index, self.w_box, self.w_center, self.w_scale),
            (self.v_index, self.v_box, self.v_center, self.v_scale),
        ):
            if index.size:
                lbx[index] = (box.lower - center) / scale
                ubx[index] = (box.upper - center) / scale
        self.lbx, self.ubx = lbx, ubx
        lbg = np.zeros(self.n_con)
        ubg = np.zeros(self.n_con)
        if self.has_output_constraints:
            lo = (s.y_bounds.lower - self.y_center) / self.y_scale
            hi = (s.y_bounds.upper - self.y_center) / self.y_scale
            lbg[self.n_dyn : self.n_dyn + self.n_out_con] = np.tile(lo, M)
            ubg[self.n_dyn : self.n_dyn + self.n_out_con] = np.tile(hi, M)
        if rows:
            assert s.node_bounds is not None and s.node_scale is not None
            center, scale = working_center(s.node_bounds, s.node_scale)[rows], s.node_scale[rows]
            start = self.n_dyn + self.n_out_con
            lbg[start:] = np.tile((s.node_bounds.lower[rows] - center) / scale, M)
            ubg[start:] = np.tile((s.node_bounds.upper[rows] - center) / scale, M)
        self.lbg, self.ubg = lbg, ubg

    @cached_property
    def residual_function(self) -> ca.Function:
        """CasADi Function ``(z (n_var,), p (n_par,)) -> r (n_res,)``; the cost is ``|r|^2``."""
        return ca.Function("window_residual", [self.z, self.p], [self.r], ["z", "p"], ["r"])

    @cached_property
    def constraint_function(self) -> ca.Function:
        """CasADi Function ``(z, p) -> g (n_con,)`` with ``lbg <= g <= ubg`` (dynamics: ``g = 0``)."""
        return ca.Function("window_constraints", [self.z, self.p], [self.g], ["z", "p"], ["g"])

    @cached_property
    def cost_function(self) -> ca.Function:
        """CasADi Function ``(z, p) -> J = |r|^2``."""
        return ca.Function("window_cost", [self.z, self.p], [ca.sumsqr(self.r)], ["z", "p"], ["J"])

    @cached_property
    def gauss_newton_function(self) -> ca.Function:
        """CasADi Function ``(z, p) -> (r, dr/dz, g, dg/dz)``, dense outputs (for Gauss-Newton steps)."""
        return ca.Function(
            "window_gauss_newton",
            [self.z, self.p],
            [self.r, ca.densify(ca.jacobian(self.r, self.z)), self.g, ca.densify(ca.jacobian(self.g, self.z))],
            ["z", "p"],
            ["r", "J", "g", "G"],
        )

    def nlp(self) -> dict[str, ca.SX]:
        """The NLP ``{x: z, p: p, f: c(p) |r|^2, g: g}`` for ``casadi.nlpsol``, ``c`` from :meth:`objective_scale`."""
        return {"x": self.z, "p": self.p, "f": self._objective_scale(self.p) * ca.sumsqr(self.r), "g": self.g}

    def objective_scale(self, p: FloatArray) -> float:
        """The factor ``c = min(1, LARGEST_WEIGHT / w_max)`` on the NLP's cost (w_max: largest squared weight root).

        The minimiser does not change. IPOPT's step computation breaks down when the weights span
        ~1e12 (a certificate's output weight against a unit prior); with the largest weight brought to
        ``LARGEST_WEIGHT`` it does not. Its stopping test (``tol`` on the scaled problem) is then ``1/c``
        times looser in the original units, so :class:`~uiest.window.solvers.IpoptSolver` polishes its
        solution when ``c < POLISH_BELOW`` (design notes: window solvers).
        """
        roots = np.asarray(p, dtype=float)[self.parameter_slices["weights"]]
        largest = float(np.abs(roots).max(initial=0.0)) ** 2
        return LARGEST_WEIGHT / largest if largest > LARGEST_WEIGHT else 1.0

    def _objective_scale(self, p: ca.SX) -> ca.SX:
        """:meth:`objective_scale` as a CasADi expression of the parameters."""
        roots = p[self.parameter_slices["weights"]]
        if roots.numel() == 0:
            return ca.SX(1.0)
        largest = ca.mmax(ca.fabs(roots)) ** 2
        return LARGEST_WEIGHT / ca.fmax(largest, LARGEST_WEIGHT)

    # ------------------------------------------------------------------ data in and out
    def parameters(
        self,
        prior: ArrayLike,
        u: ArrayLike,
        y: ArrayLike,
        v_bar: ArrayLike | None = None,
        w_bar: ArrayLike | None = None,
        data: ArrayLike | None = None,
        weights: WindowWeights | FloatArray | None = None,
    ) -> FloatArray:
        """Pack a window's data and weights into the parameter vector ``p``.

        Parameters
        ----------
        prior : array_like (nx,)
            Prior of the window's first state.
        u : array_like (L, nu)
            Known inputs of the window's transitions.
        y : array_like (M, ny)
            Measurements at the measured nodes; NaN entries are missing (masked out).
        v_bar : array_like (M, nv), optional
            Noise priors (default: zeros).
        w_bar : array_like (L, nw), optional
            Unknown-input priors (default: ``system.nominal_w``); used only if w is weighted.
        data : array_like (L+1, nd), optional
            Node data of the model (required when ``nd > 0``).
        weights : WindowWeights or ndarray, optional
            The weights, or their part of ``p`` from :meth:`weight_vector` (cache it: it is the
            costly part); default: the weights the problem was built with.

        """
        s = self.model
        L, M = self.length, self.n_meas
        parts = self._data_parts(prior, u, y, data)
        parts["v_bar"] = np.zeros(M * s.nv) if v_bar is None else np.asarray(v_bar, dtype=float).reshape(M * s.nv)
        parts["w_bar"] = (
            np.broadcast_to(s.nominal_w, (L, s.nw)).ravel()
            if w_bar is None
            else np.asarray(w_bar, dtype=float).reshape(L * s.nw)
        )
        parts["weights"] = self._weights_part(weights)
        return self._filled(np.empty(self.n_par), parts)

    def with_data(
        self, base: FloatArray, prior: ArrayLike, u: ArrayLike, y: ArrayLike, data: ArrayLike | None = None
    ) -> FloatArray:
        """A copy of ``base`` (a vector from :meth:`parameters`) with another window's data in it.

        The same vector as :meth:`parameters` with these data and ``base``'s priors of v and w and weights: for a
        caller whose priors and weights stay the same from window to window. The data as in :meth:`parameters`.
        """
        return self._filled(np.array(base, dtype=float), self._data_parts(prior, u, y, data))

    def _data_parts(
        self, prior: ArrayLike, u: ArrayLike, y: ArrayLike, data: ArrayLike | None
    ) -> dict[str, FloatArray]:
        """The window's data as the flat parts of ``p``: prior, u, y (0 where missing), mask, data."""
        s = self.model
        L, M = self.length, self.n_meas
        if data is None and s.nd:
            raise DataError(f"data: the model takes node data, expected shape ({L + 1}, {s.nd}), got None")
        y_arr = np.asarray(y, dtype=float).reshape(M * s.ny)
        mask = np.isfinite(y_arr)
        return {
            "prior": np.asarray(prior, dtype=float).reshape(s.nx),
            "u": np.asarray(u, dtype=float).reshape(L * s.nu),
            "y": np.where(mask, y_arr, 0.0),
            "mask": mask.astype(float),
            "data": np.zeros(0) if data is None else np.asarray(data, dtype=float).reshape((L + 1) * s.nd),
        }

    def _filled(self, p: FloatArray, parts: dict[str, FloatArray]) -> FloatArray:
        """``p`` with ``parts`` written at their slices; DataError naming a part that is not finite."""
        for key, value in parts.items():
            p[self.parameter_slices[key]] = value
        if not all_finite(p):
            key = next((key for key, value in parts.items() if not np.isfinite(value).all()), "base")
            shown = np.asarray(parts[key]).tolist() if key in parts else "a parameter vector that is not finite"
            raise DataError(f"{key}: expected finite window data, got {shown}")
        return p

    def _weights_part(self, weights: WindowWeights | FloatArray | None) -> FloatArray:
        if weights is None:
            if self.default_weights is None:
                raise OptionError("weights: this problem was built without weights; pass them to parameters()")
            return self.default_weights
        if isinstance(weights, WindowWeights):
            return self.weight_vector(weights)
        vector = np.asarray(weights, dtype=float).reshape(-1)
        expected = self.parameter_slices["weights"].stop - self.parameter_slices["weights"].start
        if vector.size != expected:
            raise OptionError(f"weights: expected a weight vector of {expected} values, got {vector.size}")
        return vector

    def pack(self, trajectory: WindowTrajectory) -> FloatArray:
        """Scaled decision vector ``(value - centre) / scale`` from a trajectory in original units."""
        model, L, M = self.model, self.length, self.n_meas
        parts = [np.asarray(trajectory.x, dtype=float).reshape((L + 1) * model.nx)]
        if L:
            parts.append(np.asarray(trajectory.w, dtype=float).reshape(L * model.nw))
        if M:
            parts.append(np.asarray(trajectory.v, dtype=float).reshape(M * model.nv))
        z = np.empty(self.n_var)
        z[self._flat_index] = (np.concatenate(parts) - self._flat_center) / self._flat_scale
        return z

    def unpack(self, z: ArrayLike) -> WindowTrajectory:
        """Trajectory in original units (``centre + scale * z``) from a scaled decision vector."""
        model, L = self.model, self.length
        vec = np.asarray(z, dtype=float).reshape(self.n_var)
        values = self._flat_center + self._flat_scale * vec[self._flat_index]
        x_end, w_end = self._flat_ends
        return WindowTrajectory(
            x=values[:x_end].reshape(L + 1, model.nx),
            w=values[x_end:w_end].reshape(L, model.nw),
            v=values[w_end:].reshape(self.n_meas, model.nv),
        )

    def __repr__(self) -> str:
        return (
            f"WindowProblem(model={self.model.name!r}, length={self.length}, measured={self.n_meas}, "
            f"n_var={self.n_var}, n_con={self.n_con}, n_res={self.n_res})"
        )
