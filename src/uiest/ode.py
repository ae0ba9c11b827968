r"""Discretisation of continuous-time models ``dx/dt = F(x, u, w)`` for :meth:`System.from_ode`.

The known input u and the unknown input w are held constant over each sample (zero-order
hold). Two ways to treat w:

- ``input_channel="integral"`` (default when F is affine in w with a constant matrix G,
  ``F = F0(x, u) + G w``): the drift is integrated by RK4 at the nominal input ``w0`` and the
  unknown input enters through its per-sample integral

      x+ = RK4(F0 + G w0, x, u, dt) + Gamma (w - w0),   Gamma = int_0^dt exp(A_ref s) ds G,

  with ``A_ref = dF/dx`` at the reference point (the centre of X and U). Gamma is constant, so
  the unknown input keeps a constant direction, as the strong-detectability certificate needs.
  Per sample, this differs from the exact zero-order-hold flow by about
  ``dt^2 / 2 |(dF/dx(x) - A_ref) G (w - w0)|`` plus the RK4 error ``O(dt^5)``, terms of order
  ``dt^3 |w - w0|`` and ``dt^3 |w - w0|^2 |d^2F/dx^2|``: the model error grows with the unknown
  input's size and with how far the state is from the reference point.
- ``input_channel="rk4"``: w is held inside the RK4 stages (the accurate zero-order-hold step);
  the input's direction then depends on the state, which the certificate reports as such.

The integrator (``method``) takes ``substeps`` equal steps per sample (at most ``MAX_SUBSTEPS``):

- ``"rk4"``: the classical explicit Runge-Kutta method (order 4);
- ``"collocation"``: Radau IIA collocation with two stages (order 3, L-stable: for stiff models,
  where RK4 needs a step below ``2.8 / |fastest eigenvalue|``). Its implicit stage equations are
  solved by ``NEWTON_ITERATIONS`` Newton iterations from zero stage derivatives, unrolled into the
  expression (so the step stays a CasADi SX expression with exact derivatives); one iteration is
  exact for a linear model, and a stiff nonlinear model needs substeps small enough to converge.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from uiest.box import Box
from uiest.checks import check_int
from uiest.errors import ModelError, OptionError

__all__ = ["ContinuousModel", "collocation_unconverged", "discretise", "input_integral", "rk4_instability"]

INPUT_CHANNELS = ("integral", "rk4")
METHODS = ("rk4", "collocation")
NEWTON_ITERATIONS = 6
"""Newton iterations per collocation step, from zero stage derivatives (the stage points at x): exact
for a linear model after one; for a stiff nonlinear model the step must be small enough that six
converge (the residual is not checked inside the expression; :func:`collocation_unconverged` checks it over X
when the model is built)."""
RADAU_A = np.array([[5.0 / 12.0, -1.0 / 12.0], [3.0 / 4.0, 1.0 / 4.0]])
RADAU_B = np.array([3.0 / 4.0, 1.0 / 4.0])
MAX_SUBSTEPS = 1000
"""Most RK4 substeps per sample: the steps are unrolled into the model's expression graph."""


@dataclass(frozen=True, eq=False)
class ContinuousModel:
    """The continuous-time model a :class:`~uiest.system.System` was sampled from (:meth:`System.from_ode`).

    Attributes
    ----------
    rhs : casadi.Function
        ``(x (nx,), u (nu,), w (nw,)) -> dx/dt (nx,)``.
    method : str
        The integrator (:data:`METHODS`).
    substeps : int
        Integrator steps per sample.
    input_channel : str
        How w enters the sampled model (:data:`INPUT_CHANNELS`).

    """

    rhs: ca.Function
    method: str
    substeps: int
    input_channel: str


def rk4_step(rhs: ca.Function, x: ca.SX, u: ca.SX, w: ca.SX | ca.DM, dt: float, substeps: int) -> ca.SX:
    """``substeps`` classical Runge-Kutta steps of ``dx/dt = rhs(x, u, w)`` over ``dt``."""
    h = dt / substeps
    for _ in range(substeps):
        k1 = rhs(x, u, w)
        k2 = rhs(x + 0.5 * h * k1, u, w)
        k3 = rhs(x + 0.5 * h * k2, u, w)
        k4 = rhs(x + h * k3, u, w)
        x = x + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    return x


def radau_step(rhs: ca.Function, x: ca.SX, u: ca.SX, w: ca.SX | ca.DM, dt: float, substeps: int) -> ca.SX:
    """``substeps`` two-stage Radau IIA steps of ``dx/dt = rhs(x, u, w)`` over ``dt`` (module docstring)."""
    h, n = dt / substeps, x.numel()
    symbols = [u] + ([w] if isinstance(w, ca.SX) else [])
    newton, _ = _radau_newton(rhs, n, h, u, w, symbols)
    for _ in range(substeps):
        guess = ca.SX.zeros(n * RADAU_A.shape[0])
        for _ in range(NEWTON_ITERATIONS):
            guess = newton(guess, x, *symbols)
        x = x + h * sum(RADAU_B[j] * guess[j * n : (j + 1) * n] for j in range(RADAU_A.shape[0]))
    return x


def _radau_newton(
    rhs: ca.Function, n: int, h: float, u: ca.SX, w: ca.SX | ca.DM, symbols: list[ca.SX]
) -> tuple[ca.Function, ca.Function]:
    """One Newton iteration on a Radau IIA step's stage equations, and their residual, as Functions.

    Both take ``(k (n stages,), x0 (n,), *symbols)``: the stacked stage derivatives, the step's start, then the
    symbols ``u`` and ``w`` are among. The residual is ``k - rhs(stage points)``.
    """
    stages = RADAU_A.shape[0]
    k, x0 = ca.SX.sym("k", n * stages), ca.SX.sym("x0", n)
    points = [x0 + h * sum(RADAU_A[i, j] * k[j * n : (j + 1) * n] for j in range(stages)) for i in range(stages)]
    residual = k - ca.vertcat(*[rhs(p, u, w) for p in points])
    newton = ca.Function("newton", [k, x0, *symbols], [k - ca.solve(ca.jacobian(residual, k), residual)])
    return newton, ca.Function("stage_residual", [k, x0, *symbols], [residual])


COLLOCATION_RTOL = 1e-6
"""The stage equations' residual after the Newton iterations times the step (``h |residual|``, a measure of how far
the step is from solving them, in the state's units), relative to the state's width in X, above which
:func:`collocation_unconverged` reports a point."""


def collocation_unconverged(rhs: ca.Function, box: Box, u_ref: np.ndarray, w_ref: np.ndarray, h: float) -> str | None:
    """Where one collocation step of length ``h`` leaves its stage equations unsolved in ``box``, or None.

    At the points of :func:`_probe_jacobians` (u at ``u_ref``, w at ``w_ref``), the residual ``r = k - F(stage
    points)`` after the :data:`NEWTON_ITERATIONS` Newton iterations: a point is reported where ``h |r_i|`` (state i,
    either stage) exceeds :data:`COLLOCATION_RTOL` times state i's width in ``box`` (``1 + |x_i|`` where the width is
    not finite); NaN counts as unsolved.
    """
    points, _ = _probe_jacobians(rhs, box, u_ref, w_ref)
    if not len(points):
        return None
    n, stages, m = box.size, RADAU_A.shape[0], len(points)
    x0, u, w = ca.SX.sym("x0", n), ca.SX.sym("u", u_ref.size), ca.SX.sym("w", w_ref.size)
    newton, left = _radau_newton(rhs, n, h, u, w, [u, w])
    guess = ca.SX.zeros(n * stages)
    for _ in range(NEWTON_ITERATIONS):
        guess = newton(guess, x0, u, w)
    unsolved = ca.Function("unsolved", [x0, u, w], [left(guess, x0, u, w)]).map(m)
    with np.errstate(over="ignore", invalid="ignore"):
        r = np.asarray(unsolved(points.T, np.tile(u_ref, (m, 1)).T, np.tile(w_ref, (m, 1)).T), dtype=float)
        error = h * np.abs(r.reshape(stages, n, m)).max(axis=0)  # (n, m): each state's step error
        width = np.where(np.isfinite(box.width) & (box.width > 0), box.width, 0.0)[:, None]
        relative = (error / np.where(width > 0, width, 1.0 + np.abs(points.T))).max(axis=0)
    relative = np.where(np.isfinite(relative), relative, np.inf)
    worst = int(np.argmax(relative))
    if relative[worst] <= COLLOCATION_RTOL:
        return None
    size = f"{relative[worst]:.2g} of X's width" if np.isfinite(relative[worst]) else "not finite"
    where = [float(f"{value:.6g}") for value in points[worst]]
    return (
        f"collocation's {NEWTON_ITERATIONS} Newton iterations leave its stage equations unsolved at x = {where} "
        f"(their residual times the step {size}, step {h:.4g}): the sampled model is wrong there; more substeps"
    )


RK4_REAL_LIMIT = 2.785
"""RK4's stability region meets the negative real axis at about -2.785."""
GROWTH_ROUNDING = 1e-9
"""Amplification above 1 by less than this is rounding (a purely imaginary or zero eigenvalue sits on the edge)."""


def rk4_instability(rhs: ca.Function, box: Box, u_ref: np.ndarray, w_ref: np.ndarray, h: float) -> str | None:
    """Why RK4 with step ``h`` grows where the ODE decays somewhere in ``box``, or None.

    At the points of :func:`_probe_jacobians`, the Jacobian's eigenvalues ``lambda`` with
    ``Re lambda <= 0`` are checked against RK4's amplification
    ``|1 + z + z^2/2 + z^3/6 + z^4/24| <= 1``, ``z = h lambda`` (to ``GROWTH_ROUNDING``).
    """
    points, J = _probe_jacobians(rhs, box, u_ref, w_ref)
    if not len(points):
        return None
    lam = np.linalg.eigvals(J)
    z = h * lam
    bad = rk4_grows(lam, h)
    if not bad.any():
        return None
    i, j = np.unravel_index(np.argmax(np.where(bad, np.abs(z), -np.inf)), z.shape)
    return (f"RK4 with step {h:.4g} grows where the ODE decays: at x = {np.round(points[i], 6).tolist()} the "
            f"eigenvalue {lam[i, j]:.4g} gives h lambda = {z[i, j]:.3g} (RK4 needs |h lambda| below about "
            f"{RK4_REAL_LIMIT} on the real axis); more substeps or method='collocation'")  # fmt: skip


def rk4_grows(lam: np.ndarray, h: float) -> np.ndarray:
    """Which eigenvalues ``lam`` (any shape) of a decaying mode (``Re lambda <= 0``) RK4 with step ``h`` amplifies.

    RK4's amplification ``|1 + z + z^2/2 + z^3/6 + z^4/24|``, ``z = h lambda``, above 1 by more than
    :data:`GROWTH_ROUNDING`.
    """
    z = h * np.asarray(lam)
    growth = np.abs(1 + z + z**2 / 2 + z**3 / 6 + z**4 / 24)
    result: np.ndarray = (np.real(lam) <= 0) & (growth > 1 + GROWTH_ROUNDING)
    return result


def _probe_jacobians(rhs: ca.Function, box: Box, u_ref: np.ndarray, w_ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Points of ``box`` (m, n) and the drift's state Jacobians there (m, n, n), where finite.

    The box's corners (256 random ones beyond 8 states) and 256 uniform points (fixed seed), sides that are not
    finite held at the box's centre; points where the Jacobian is not finite (a square root at a side of X) are left
    out.
    """
    finite = np.isfinite(box.lower) & np.isfinite(box.upper)
    bounded = Box(np.where(finite, box.lower, box.center), np.where(finite, box.upper, box.center))
    rng = np.random.default_rng(0)
    n = box.size
    if n > 8:
        corners = np.where(rng.integers(0, 2, (256, n)).astype(bool), bounded.upper, bounded.lower)
    else:
        corners = bounded.corners()
    points = np.vstack([corners, bounded.sample(rng, 256)])
    x, u, w = ca.SX.sym("x", n), ca.SX.sym("u", u_ref.size), ca.SX.sym("w", w_ref.size)
    jac = ca.Function("state_jacobian", [x, u, w], [ca.jacobian(rhs(x, u, w), x)]).map(len(points))
    J = np.asarray(jac(points.T, np.tile(u_ref, (len(points), 1)).T, np.tile(w_ref, (len(points), 1)).T), dtype=float)
    J = J.reshape(n, len(points), n).transpose(1, 0, 2)
    keep = np.all(np.isfinite(J), axis=(1, 2))
    return points[keep], J[keep]


INPUT_SPREAD = 0.25
"""The per-sample input integral may differ from the one at X's centre by this fraction of it over X before
:meth:`System.from_ode <uiest.system.System.from_ode>` warns."""
INPUT_SPREAD_LIMIT = 1.0
"""Where the per-sample input integral differs from the one at X's centre by more than this fraction of it (more
than its own size: a constant direction then misstates even the size or sign of w's effect), ``System.from_ode``
puts w inside the integrator unless the constant direction is asked for."""


@dataclass(frozen=True)
class InputSpread:
    """How far the input channel ``"integral"`` (``Gamma`` fixed at X's centre) misstates w's effect in a box."""

    spread: float
    """The largest ``|Gamma(x) - Gamma| / |Gamma|`` over the points probed (inf where the integral overflows)."""
    text: str
    """The sentence that says where and by how much."""


def input_spread(rhs: ca.Function, box: Box, u_ref: np.ndarray, w_ref: np.ndarray, dt: float) -> InputSpread | None:
    """How far the input channel ``"integral"`` (``Gamma`` fixed at X's centre) misstates w's effect in ``box``.

    ``Gamma(x) = int_0^dt exp(A(x) s) ds G`` at the points of :func:`_probe_jacobians` against ``Gamma`` at the
    centre: None when ``|Gamma(x) - Gamma| <= INPUT_SPREAD |Gamma|`` (2-norms) at every point.
    """
    points, J = _probe_jacobians(rhs, box, u_ref, w_ref)
    n, nu, nw = (rhs.numel_in(i) for i in range(3))
    x, u, w = ca.SX.sym("x", n), ca.SX.sym("u", nu), ca.SX.sym("w", nw)
    jacobians = ca.Function("jacobians", [x, u, w], [ca.jacobian(rhs(x, u, w), x), ca.jacobian(rhs(x, u, w), w)])
    A_ref, G = (np.asarray(m, dtype=float) for m in jacobians(box.center, u_ref, w_ref))
    if not len(points) or not np.all(np.isfinite(A_ref)):
        return None
    reference = input_integral(A_ref, G, dt)
    size = max(float(np.linalg.norm(reference, 2)), 1e-300)

    def spread_at(A: np.ndarray) -> float:  # inf where the integral overflows (a runaway mode over the sample)
        with np.errstate(over="ignore", invalid="ignore"):
            difference = input_integral(A, G, dt) - reference
        return float(np.linalg.norm(difference, 2)) / size if np.all(np.isfinite(difference)) else np.inf

    spread = np.array([spread_at(A) for A in J])
    worst = int(np.argmax(spread))
    if spread[worst] <= INPUT_SPREAD:
        return None
    factor = f"{spread[worst]:.3g} times its size" if np.isfinite(spread[worst]) else "more than doubles can hold"
    where = np.round(points[worst], 6).tolist()
    text = (f"w's per-sample integral at x = {where} differs from the one at X's centre by {factor}: a constant "
            "direction, taken at the centre, misstates w's effect by that much away from it")  # fmt: skip
    return InputSpread(float(spread[worst]), text)


def input_integral(A_ref: np.ndarray, G: np.ndarray, dt: float) -> np.ndarray:
    """``int_0^dt exp(A_ref s) ds G`` (the top-right block of ``expm([[A, G], [0, 0]] dt)``)."""
    n, q = G.shape
    augmented = np.zeros((n + q, n + q))
    augmented[:n, :n], augmented[:n, n:] = A_ref, G
    import scipy.linalg  # imported when used: `import uiest` (which loads this module) stays light

    return scipy.linalg.expm(augmented * dt)[:n, n:]


def discretise(
    rhs: ca.Function,
    *,
    dt: float,
    substeps: int = 1,
    input_channel: str | None = None,
    method: str = "rk4",
    x_ref: np.ndarray,
    u_ref: np.ndarray,
    w_ref: np.ndarray,
) -> tuple[ca.Function, str]:
    """The sampled model ``f(x, u, w)`` of ``dx/dt = rhs(x, u, w)`` and the input channel used.

    ``input_channel`` None picks "integral" when rhs is affine in w with a constant matrix,
    else "rk4". Raises :class:`ModelError` when "integral" is asked for and rhs is not of that form.
    """
    if not (np.isfinite(dt) and dt > 0):
        raise ModelError(f"dt: expected a positive finite sampling time, got {dt!r}")
    substeps = check_int(substeps, "substeps", low=1, high=MAX_SUBSTEPS)
    if method not in METHODS:
        raise OptionError(f"method: expected one of {METHODS}, got {method!r}")
    step = rk4_step if method == "rk4" else radau_step
    if input_channel is not None and input_channel not in INPUT_CHANNELS:
        raise OptionError(f"input_channel: expected one of {INPUT_CHANNELS} or None, got {input_channel!r}")
    nx, nu, nw = (rhs.numel_in(i) for i in range(3))
    x, u, w = ca.SX.sym("x", nx), ca.SX.sym("u", nu), ca.SX.sym("w", nw)
    G_expr = ca.jacobian(rhs(x, u, w), w)
    constant = not any(ca.depends_on(G_expr, s) for s in (x, u, w) if s.numel())
    channel = input_channel or ("integral" if constant else "rk4")
    if channel == "rk4":
        x_next = step(rhs, x, u, w, dt, int(substeps))
    else:
        if not constant:
            raise ModelError(
                "input_channel='integral' needs dx/dt = F0(x, u) + G w with a constant G, but dF/dw varies; "
                "use input_channel='rk4' (the input's direction then varies with the state)"
            )
        G = np.asarray(ca.DM(ca.substitute(G_expr, ca.vertcat(x, u, w), ca.DM.zeros(nx + nu + nw))), dtype=float)
        A_ref = np.asarray(
            ca.Function("A", [x, u, w], [ca.jacobian(rhs(x, u, w), x)])(x_ref, u_ref, w_ref), dtype=float
        )
        Gamma = input_integral(A_ref, G, dt)
        w0 = ca.DM(np.asarray(w_ref, dtype=float))
        x_next = step(rhs, x, u, w0, dt, int(substeps)) + ca.mtimes(ca.DM(Gamma), w - w0)
    return ca.Function("f", [x, u, w], [x_next], ["x", "u", "w"], ["x_next"]), channel
