r"""What a window problem needs from a model: :class:`WindowModel`.

A window model is

    x+ = f(x, u, w, v, d),    y = h(x, v, d),    c(x, v, d) in C   (optional node constraints)

with the known input ``u`` (per transition), the unknown input ``w`` (per transition), the
measurement noise ``v`` (per measured node), and node data ``d`` (per node, a parameter like
``u``) -- plus domains and nominal scales. Two kinds exist:

- :meth:`WindowModel.from_system`: a full :class:`~uiest.system.System` (``f(x, u, w)``,
  ``h(x, v)``; no node data, no node constraints). Every full-order estimator uses it.
- :meth:`WindowModel.from_reduced`: the reduced-order model of the two-stage UISE:
  ``x = z_sharp``, no ``w``, ``d = gamma`` (the measurement entering Eq. (21) of Guo et al.), f depends on
  ``v`` and the node constraint ``T^-1(psi(gamma, z_sharp, v), z_sharp) in X`` of Eq. (30).

When ``f`` depends on ``v``, transition ``i`` uses the noise estimate of node ``i``, so every
node ``0 .. L-1`` of a window must carry one (be "measured").
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import TYPE_CHECKING

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike

from uiest.box import Box, FloatArray
from uiest.errors import ModelError
from uiest.system import System
from uiest.window.buffered import BufferedFunction

if TYPE_CHECKING:
    from uiest.reduction import ReducedModel

__all__ = ["WindowModel", "box_scale"]


def _scale(values: ArrayLike, n: int, name: str) -> FloatArray:
    arr = np.array(values, dtype=float).reshape(-1)
    if arr.shape != (n,) or not np.all(np.isfinite(arr) & (arr > 0)):
        raise ModelError(f"{name}: expected {n} positive finite scales, got {arr.tolist()}")
    arr.setflags(write=False)
    return arr


def box_scale(box: Box) -> FloatArray:
    """Nominal magnitudes from a box: the width where finite and positive, else 1."""
    width = box.width
    return np.where(np.isfinite(width) & (width > 0), width, 1.0)


@dataclass(frozen=True, eq=False)
class WindowModel:
    """The model of a window problem (see the module docstring).

    Attributes
    ----------
    f : casadi.Function
        ``(x (nx,), u (nu,), w (nw,), v (nv,), d (nd,)) -> x+ (nx,)``.
    h : casadi.Function
        ``(x, v, d) -> y (ny,)``.
    x_bounds, v_bounds, y_bounds : Box
        Default bounds of the state nodes and noise estimates; output box (constrained where finite).
    x_scale, w_scale, v_scale, y_scale : ndarray
        Nominal magnitudes (the problem's variables are ``(z - centre) / scale``).
    nominal_w : ndarray (nw,)
        Centre of the unknown-input variables when they are unbounded (their prior by default).
    node_constraint : casadi.Function or None
        ``(x, v, d) -> c (nc,)``, imposed at measured nodes as ``c in node_bounds``.
    node_bounds : Box or None
        Bounds of c (components with two infinite sides are dropped).
    node_scale : ndarray or None
        Nominal magnitudes of c.
    name : str

    """

    f: ca.Function
    h: ca.Function
    x_bounds: Box
    v_bounds: Box
    y_bounds: Box
    x_scale: FloatArray
    w_scale: FloatArray
    v_scale: FloatArray
    y_scale: FloatArray
    nominal_w: FloatArray
    node_constraint: ca.Function | None = None
    node_bounds: Box | None = None
    node_scale: FloatArray | None = None
    name: str = "model"

    def __post_init__(self) -> None:
        if not isinstance(self.f, ca.Function) or self.f.n_in() != 5 or self.f.n_out() != 1:
            raise ModelError(f"f: expected a casadi.Function (x, u, w, v, d) -> x+, got {self.f!r}")
        if not isinstance(self.h, ca.Function) or self.h.n_in() != 3 or self.h.n_out() != 1:
            raise ModelError(f"h: expected a casadi.Function (x, v, d) -> y, got {self.h!r}")
        nx, nv, nd = self.nx, self.nv, self.nd
        if self.f.numel_out(0) != nx or self.f.numel_in(3) != nv or self.f.numel_in(4) != nd:
            raise ModelError(
                f"f, h: disagreeing sizes, f inputs {[self.f.numel_in(i) for i in range(5)]} -> "
                f"{self.f.numel_out(0)}, h inputs {[self.h.numel_in(i) for i in range(3)]}"
            )
        for label, box, n in (("x_bounds", self.x_bounds, nx), ("v_bounds", self.v_bounds, nv),
                              ("y_bounds", self.y_bounds, self.ny)):  # fmt: skip
            if box.size != n:
                raise ModelError(f"{label}: expected dimension {n}, got {box.size}")
        for label, n in (("x_scale", nx), ("w_scale", self.nw), ("v_scale", nv), ("y_scale", self.ny)):
            object.__setattr__(self, label, _scale(getattr(self, label), n, label))
        nominal = np.array(self.nominal_w, dtype=float).reshape(-1)
        if nominal.shape != (self.nw,):
            raise ModelError(f"nominal_w: expected shape ({self.nw},), got {nominal.shape}")
        object.__setattr__(self, "nominal_w", nominal)
        if self.node_constraint is not None:
            c = self.node_constraint
            if (
                c.n_in() != 3
                or [c.numel_in(i) for i in range(3)] != [nx, nv, nd]
                or self.node_bounds is None
                or self.node_bounds.size != c.numel_out(0)
            ):
                raise ModelError("node_constraint: expected (x, v, d) -> c with node_bounds of c's size")
            given = self.node_scale if self.node_scale is not None else box_scale(self.node_bounds)
            object.__setattr__(self, "node_scale", _scale(given, c.numel_out(0), "node_scale"))

    # ------------------------------------------------------------------ sizes
    @cached_property
    def nx(self) -> int:
        """State dimension."""
        return int(self.f.numel_in(0))

    @cached_property
    def nu(self) -> int:
        """Known-input dimension."""
        return int(self.f.numel_in(1))

    @cached_property
    def nw(self) -> int:
        """Unknown-input dimension."""
        return int(self.f.numel_in(2))

    @cached_property
    def nv(self) -> int:
        """Noise dimension."""
        return int(self.f.numel_in(3))

    @cached_property
    def nd(self) -> int:
        """Node-data dimension."""
        return int(self.f.numel_in(4))

    @cached_property
    def ny(self) -> int:
        """Output dimension."""
        return int(self.h.numel_out(0))

    @property
    def nc(self) -> int:
        """Number of node constraints (0 without)."""
        return 0 if self.node_constraint is None else int(self.node_constraint.numel_out(0))

    @property
    def f_uses_v(self) -> bool:
        """Whether the dynamics depend on the noise (then every transition's node needs a noise estimate)."""
        syms = [ca.SX.sym(f"a{i}", self.f.numel_in(i)) for i in range(5)]
        return bool(self.nv) and bool(ca.depends_on(self.f(*syms), syms[3]))

    # ------------------------------------------------------------------ numerics
    def step(self, x: FloatArray, u: FloatArray, w: FloatArray, v: FloatArray, d: FloatArray) -> FloatArray:
        """``f`` at one point, as a 1-D array (a new one)."""
        return self._f_buffered(x, u, w, v, d)[0].copy()

    @cached_property
    def _f_buffered(self) -> BufferedFunction:
        """``f`` through CasADi's buffer interface (a plain call builds DMs, which costs more than evaluating ``f``)."""
        return BufferedFunction(self.f)

    @classmethod
    def from_system(cls, system: System) -> WindowModel:
        """The window model of a full :class:`System`: ``f(x, u, w)``, ``h(x, v)``, no data, no node constraints."""
        x, u, w, v = (ca.SX.sym(s, n) for s, n in (("x", system.nx), ("u", system.nu), ("w", system.nw),
                                                   ("v", system.nv)))  # fmt: skip
        d = ca.SX.sym("d", 0)
        return cls(
            f=ca.Function("f", [x, u, w, v, d], [system.f(x, u, w)], ["x", "u", "w", "v", "d"], ["x_next"]),
            h=ca.Function("h", [x, v, d], [system.h(x, v)], ["x", "v", "d"], ["y"]),
            x_bounds=system.x.bounds,
            v_bounds=system.v.bounds,
            y_bounds=system.y.bounds,
            x_scale=system.x.scale,
            w_scale=system.w.scale,
            v_scale=system.v.scale,
            y_scale=system.y.scale,
            nominal_w=system.nominal_w,
            name=system.name,
        )

    @classmethod
    def from_reduced(cls, reduced: ReducedModel, *, state_constraints: bool = True) -> WindowModel:
        """Eq. (21) as a :class:`~uiest.window.WindowModel`: state ``z_sharp``, node data ``gamma``, no w.

        With ``state_constraints`` the node constraint ``T^-1(psi(gamma, z, v), z) in X`` of Eq. (30).
        """
        s = reduced.system
        n = reduced.n_sharp
        z, u, w, v, d = (ca.SX.sym(name, size) for name, size in (("z", n), ("u", s.nu), ("w", 0), ("v", s.nv),
                                                                  ("gamma", s.ny)))  # fmt: skip
        f = ca.Function(
            "f_sharp", [z, u, w, v, d], [reduced.f_sharp(z, d, u, v)], ["x", "u", "w", "v", "d"], ["x_next"]
        )
        h = ca.Function("h_sharp", [z, v, d], [reduced.h_sharp(z, d, v)], ["x", "v", "d"], ["y"])
        x_box = s.x.bounds
        has_x_side = bool(np.isfinite(x_box.lower).any() or np.isfinite(x_box.upper).any())
        node = None
        if state_constraints and has_x_side:
            x = reduced.T_inv(ca.vertcat(reduced.psi(d, z, v), z))
            node = ca.Function("x_of_node", [z, v, d], [x], ["x", "v", "d"], ["c"])
        return cls(
            f=f,
            h=h,
            x_bounds=reduced.z_bounds,
            v_bounds=s.v.bounds,
            y_bounds=s.y.bounds,
            x_scale=reduced.z_scale,
            w_scale=np.ones(0),
            v_scale=s.v.scale,
            y_scale=s.y.scale,
            nominal_w=np.zeros(0),
            node_constraint=node,
            node_bounds=x_box if node is not None else None,
            node_scale=s.x.scale if node is not None else None,
            name=f"{s.name} (reduced)",
        )
