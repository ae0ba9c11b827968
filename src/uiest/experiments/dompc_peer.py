r"""The standard-MHE window problem of :class:`~uiest.estimators.StandardMHE` posed in do-mpc (optional peer).

do-mpc (``pip install uiest[peers]``) is the tool a user would otherwise pick for an MHE in
Python. :func:`run_dompc_standard_mhe` builds the same full-length window problem as
``StandardMHE(system, weights=..., N=N, x0_prior=prior)`` with ``do_mpc.model.Model('discrete')``
and ``do_mpc.estimator.MHE``, runs it over a trajectory and reports its solve times and its
deviation from our IPOPT backend.

How the problem is mapped onto do-mpc's MHE template (do-mpc's window has nodes ``0..N``, stage
``j`` carries the process noise ``w_j`` with ``x_{j+1} = f(x_j, ...) + w_j`` and the
measurement ``y_meas[j] = h(x_{j+1}) + v_j``, imposed as an equality)::

    do-mpc state  xi = (x, x_prev, w_in, v_in)         (v_in: the noise of the previous node / s_v)
    xi+ = (f(x, u, w_in),  x,  w_bar + e_w,  e_v)    e_w, e_v: do-mpc's additive process noise
    y_meas[j] / s_y = h(x_prev_{j+1}, s_v v_in_{j+1}) / s_y + e_y,j = h(x_j, v_j) / s_y + e_y,j
    stage j:  eta^{N-j-1} (|s_y e_y,j|_R^2 + 2 |s_v e_v,j|_{Q_v}^2) + 2 eta^{N-j-2} |e_w,j|_{Q_w}^2
              (e_w,N-1 moves only the unused w_in_N: weight 2 Q_w)
    arrival:  2 eta^N |x_0 - prior|_P^2 + 2 eta^{N-1} |w_in_0 - w_bar|_{Q_w}^2
              + |x_prev_0 - x_0|_P^2 + |v_in_0|^2

so the measured nodes are ``0..N-1`` and the estimate is ``x_N`` (one-step-ahead, as ours);
``w_in_j`` is the unknown input of transition ``j`` (``w_in_0`` enters through the arrival cost
with the discount of transition 0, ``e_w,j = w_in_{j+1} - w_bar`` through stage ``j``), and
do-mpc's measurement noise ``e_y`` is our output residual ``(y - h(x, v)) / s_y``; the last two
arrival terms only pin the otherwise free ``x_prev_0`` and ``v_in_0`` (zero at the optimum). The known input u and
the per-stage discounts are do-mpc time-varying parameters; the prior is a fixed parameter set
at every step, so the arrival cost uses our prior rule (below). Bounds: X on ``x`` and
``x_prev`` at every node, ``system.w_range`` on ``w_in``, V on ``s_v v_in``.

Differences from our formulation (see also :data:`FORMULATION_DIFFERENCES`):

- measurement: do-mpc's template imposes ``y = h(x) + v`` as an equality with a penalised,
  unbounded v; ours has a bounded noise v inside h and penalises ``|h(x, v) - y|_R^2``. With
  the benchmark's weights R is *not* much larger than Q_v (``R / 2Q_v = 1e6 s_v^2 / (2 s_y^2)``
  ~ 2.5 for y^c), so using do-mpc's noise as our v with V as its bound gives a different optimum
  (design notes: stored study runs); our bounded v is therefore
  a state ``v_in`` driven by process noise, and do-mpc's measurement noise is our residual;
- measured nodes: do-mpc measures nodes ``1..N`` of its window (a filtering MHE that uses
  ``y[k]``); ours measures ``0..N-1`` (one-step-ahead); the lagged copy ``x_prev`` makes do-mpc's
  nodes ``1..N`` carry our nodes ``0..N-1``, at the price of 3 + nw + nv more states per node;
- prior: do-mpc's own ``make_step`` sets ``x_prev`` to node 1 of the previous window (the
  smoothed ``x_{k-N|k-1}``) with a constant ``P_x`` (no covariance update of the arrival cost);
  here the arrival cost ignores that and uses our filtering prior ``x_hat[k-N]``, passed as a parameter;
- start-up: do-mpc's window has a fixed length (it pads missing measurements by repeating the
  first one); ours grows ``N_k = min(N, k)``. do-mpc is run from ``k = N`` on (the first full
  window); the estimates for ``k < N`` (and so the priors of the windows ``N <= k < 2N``) are
  those of our ``StandardMHE(solver="ipopt")`` run;
- unknown input: do-mpc has no non-additive disturbance variable; it is the extra state ``w_in``
  driven by additive process noise, with its first value in the arrival cost (same optimum);
- scaling: do-mpc divides states by ``scaling['_x']`` (no centring) and does not scale noise
  variables; the noise is scaled here by hand (``v~ = v / s_v``, ``e``); ours centres and
  scales every variable;
- warm start: do-mpc restarts IPOPT from the previous window's solution unshifted (and passes
  the multipliers, which IPOPT ignores without ``warm_start_init_point``); ours shifts it by
  one step.
"""

from __future__ import annotations

import contextlib
import io
import warnings
from dataclasses import dataclass
from time import perf_counter, thread_time
from typing import Any

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike

from uiest.box import FloatArray
from uiest.estimators import MHEWeights
from uiest.system import System
from uiest.window.solvers import IPOPT_DEFAULTS

__all__ = ["DompcPeerResult", "run_dompc_standard_mhe"]

FORMULATION_DIFFERENCES = (
    "measurement: do-mpc's noise enters additively with y = h(x) + v as an equality; ours bounds v inside h and "
    "penalises |h(x, v) - y|_R^2: our v is a state v_in driven by process noise, do-mpc's noise is our residual",
    "measured nodes: do-mpc fits y at nodes 1..N (filtering); ours 0..N-1 (one-step-ahead): lagged state x_prev",
    "arrival-cost prior: do-mpc's make_step would use the previous window's node 1 with a constant P_x; "
    "replaced here by our prior x_hat[k-N] (a parameter)",
    "fixed horizon: do-mpc runs from k = N on; x_hat[k < N] are our StandardMHE(ipopt) estimates",
    "unknown input as an extra state w_in with additive process noise (w_in_0 in the arrival cost)",
    "scaling: do-mpc scales states without centring and leaves noise unscaled (scaled here by hand)",
    "warm start: previous solution unshifted (ours: shifted by one step)",
)
"""Where the do-mpc problem or its use differs from :class:`~uiest.estimators.StandardMHE`."""


@dataclass(frozen=True, kw_only=True)
class DompcPeerResult:
    """do-mpc run of the standard-MHE window problem.

    Attributes
    ----------
    x_hat : ndarray (K+1, nx)
        Estimates; rows ``k < N`` are the reference run's (do-mpc is run from ``k = N``).
    solve_time : ndarray (K+1,)
        Wall-clock seconds of ``MHE.make_step`` per sample (0 for ``k < N``).
    iterations : ndarray (K+1,)
        IPOPT iterations per sample (0 for ``k < N``).
    success : ndarray (K+1,) of bool
        IPOPT reported success (True for ``k < N``).
    median_ms, p95_ms, max_ms : float
        Wall time of ``make_step`` per sample after a warm-up of N samples (see Notes).
    median_cpu_ms, p95_cpu_ms, max_cpu_ms : float
        The same in CPU time of this thread (``time.thread_time``).
    max_dev_vs_ipopt : float
        ``max |x_hat - x_hat_ipopt| / system.x.scale`` over ``k >= N`` (closed loop: each run's
        priors are its own earlier estimates).
    failures : int
        Samples where IPOPT did not report success.

    Notes
    -----
    The timing statistics are taken over the samples after the N warm-up ones, i.e. over
    ``k >= N`` (the full windows), like the benchmark's ``solve_time[N:]``.

    """

    x_hat: FloatArray
    solve_time: FloatArray
    iterations: FloatArray
    success: np.ndarray
    median_ms: float
    p95_ms: float
    max_ms: float
    median_cpu_ms: float
    p95_cpu_ms: float
    max_cpu_ms: float
    max_dev_vs_ipopt: float
    failures: int


def build_dompc_mhe(
    system: System,
    weights: MHEWeights,
    N: int,
    *,
    w_prior: ArrayLike | None = None,
    ipopt_options: dict[str, Any] | None = None,
) -> tuple[Any, dict[str, Any]]:
    """The do-mpc MHE of the full-length standard-MHE window (see the module docstring).

    Parameters
    ----------
    system : System
        Model with a known range of w (``system.w_range``) and ``h`` additive in v.
    weights : MHEWeights
        The standard MHE's weights (``eta, P, Q_w, Q_v, R``; R is not used: do-mpc imposes
        the measurement equation).
    N : int
        Horizon (transitions of the window), >= 1.
    w_prior : array_like (nw,), optional
        ``w_bar`` (default ``system.nominal_w``, as StandardMHE).
    ipopt_options : dict, optional
        IPOPT options (default: our IPOPT backend's defaults, output silenced).

    Returns
    -------
    mhe : do_mpc.estimator.MHE
        Set up; feed it through the returned ``inputs``.
    inputs : dict
        Mutable data read by the MHE's parameter functions: ``"prior"`` (nx,), ``"u"`` (N, nu),
        ``"y"`` (N, ny) (set before every ``make_step``).

    """
    with warnings.catch_warnings():  # do-mpc warns about its optional features (ONNX, OPC UA, PyTorch) on import
        warnings.simplefilter("ignore")
        import do_mpc

    if system.w_range is None:
        raise ValueError("system: the standard MHE's do-mpc peer needs a known range of w (system.w_range)")
    w_bar = system.nominal_w if w_prior is None else np.asarray(w_prior, dtype=float).reshape(system.nw)
    model = _dompc_model(do_mpc, system, w_bar)
    mhe = do_mpc.estimator.MHE(model, p_est_list=[])
    opts = {"ipopt." + key: value for key, value in {**IPOPT_DEFAULTS, **(ipopt_options or {})}.items()}
    opts.update({"print_time": False, "ipopt.print_level": 0, "ipopt.sb": "yes"})
    mhe.settings.n_horizon = N
    mhe.settings.t_step = float(system.dt)
    mhe.settings.meas_from_data = False
    mhe.settings.nlpsol_opts = opts
    mhe.settings.store_full_solution = False
    _set_objective(mhe, model, system, weights, N, w_bar)
    _set_bounds(mhe, system)
    inputs = _attach_data(mhe, system, weights.eta, N)
    with contextlib.redirect_stdout(io.StringIO()), warnings.catch_warnings():
        warnings.simplefilter("ignore", FutureWarning)  # casadi's numpy-mode notice, raised inside do-mpc
        mhe.setup()
    return mhe, inputs


def _dompc_model(do_mpc: Any, system: System, w_bar: FloatArray) -> Any:
    """The do-mpc model of the window.

    States x, x_prev, w_in, v_in (scaled v of the previous node); time-varying u and discounts; the prior as a
    parameter; y measured from x_prev.
    """
    nx, nu, nw, nv = system.nx, system.nu, system.nw, system.nv
    s_v, s_y = system.v.scale, system.y.scale
    model = do_mpc.model.Model("discrete", "SX")
    x = model.set_variable("_x", "x", (nx, 1))
    x_prev = model.set_variable("_x", "x_prev", (nx, 1))
    w_in = model.set_variable("_x", "w_in", (nw, 1))
    v_in = model.set_variable("_x", "v_in", (nv, 1))  # scaled noise v / s_v of the previous node
    u = model.set_variable("_tvp", "u", (nu, 1))
    model.set_variable("_tvp", "discount_v", (1, 1))
    model.set_variable("_tvp", "discount_w", (1, 1))
    model.set_variable("_p", "prior", (nx, 1))
    model.set_rhs("x", system.f(x, u, w_in))
    model.set_rhs("x_prev", x)
    model.set_rhs("w_in", ca.SX(ca.DM(w_bar)), process_noise=True)  # w_in+ = w_bar + e_w
    model.set_rhs("v_in", ca.SX.zeros(nv), process_noise=True)  # v_in+ = e_v
    model.set_meas("y", system.h(x_prev, ca.DM(s_v) * v_in) / ca.DM(s_y), meas_noise=True)
    model.setup()
    return model


def _set_objective(mhe: Any, model: Any, system: System, weights: MHEWeights, N: int, w_bar: FloatArray) -> None:
    """The standard MHE's cost: discounted stage terms and the arrival cost on the first node (scaled units)."""
    s_v, s_y = system.v.scale, system.y.scale
    eta = weights.eta
    d_v, d_w, prior = model.tvp["discount_v"], model.tvp["discount_w"], model.p["prior"]
    R_scaled = np.outer(s_y, s_y) * weights.R  # weight of e_y = (y - h(x, v)) / s_y
    Q_v_scaled = np.outer(s_v, s_v) * weights.Q_v  # weight of v~ = v / s_v
    Q_w = weights.Q_w
    noise = mhe._w  # process noise: e_w = w_in_{j+1} - w_bar, e_v = v~_{j+1}
    e_w, e_v = noise["w_in_noise"], noise["v_in_noise"]
    e_y = mhe._v.cat
    stage = (
        d_v * ca.bilin(ca.DM(R_scaled), e_y, e_y)
        + 2.0 * d_v * ca.bilin(ca.DM(Q_v_scaled), e_v, e_v)
        + 2.0 * d_w * ca.bilin(ca.DM(Q_w), e_w, e_w)
    )
    x0 = mhe._x
    dx = x0["x"] - prior
    dw = x0["w_in"] - ca.DM(w_bar)
    dg = x0["x_prev"] - x0["x"]
    arrival = (
        2.0 * eta**N * ca.bilin(ca.DM(weights.P), dx, dx)
        + 2.0 * eta ** (N - 1) * ca.bilin(ca.DM(Q_w), dw, dw)
        + ca.bilin(ca.DM(weights.P), dg, dg)
        + ca.sumsqr(x0["v_in"])
    )
    mhe.set_objective(stage, arrival)


def _set_bounds(mhe: Any, system: System) -> None:
    """X on x and x_prev, the range of w on w_in, V (scaled) on v_in; the variables' scales."""
    assert system.w_range is not None  # checked by build_dompc_mhe
    s_v = system.v.scale
    x_lo, x_hi = system.x.bounds.lower, system.x.bounds.upper
    for name in ("x", "x_prev"):
        mhe.bounds["lower", "_x", name] = x_lo
        mhe.bounds["upper", "_x", name] = x_hi
    mhe.bounds["lower", "_x", "w_in"] = system.w_range.lower
    mhe.bounds["upper", "_x", "w_in"] = system.w_range.upper
    mhe.bounds["lower", "_x", "v_in"] = system.v.bounds.lower / s_v
    mhe.bounds["upper", "_x", "v_in"] = system.v.bounds.upper / s_v
    mhe.scaling["_x", "x"] = system.x.scale
    mhe.scaling["_x", "x_prev"] = system.x.scale
    mhe.scaling["_x", "w_in"] = system.w.scale


def _attach_data(mhe: Any, system: System, eta: float, N: int) -> dict[str, Any]:
    """Connect the MHE's time-varying parameters, parameters and measurements to a mutable dict, returned.

    Its entries: ``"prior"`` (nx,), ``"u"`` (N, nu), ``"y"`` (N, ny); the discounts are ``eta^(N-1-j)``.
    """
    s_y = system.y.scale
    inputs: dict[str, Any] = {
        "prior": np.zeros(system.nx),
        "u": np.zeros((N, system.nu)),
        "y": np.zeros((N, system.ny)),
    }
    discount_v = eta ** (N - np.arange(N) - 1.0)
    discount_w = np.append(eta ** (N - np.arange(N - 1) - 2.0), 1.0)

    tvp_template = mhe.get_tvp_template()

    def tvp_fun(t_now: float) -> Any:
        for j in range(N):
            tvp_template["_tvp", j, "u"] = inputs["u"][j]
            tvp_template["_tvp", j, "discount_v"] = discount_v[j]
            tvp_template["_tvp", j, "discount_w"] = discount_w[j]
        return tvp_template

    p_template = mhe.get_p_template()

    def p_fun(t_now: float) -> Any:
        p_template["prior"] = inputs["prior"]
        return p_template

    y_template = mhe.get_y_template()

    def y_fun(t_now: float) -> Any:
        for j in range(N):
            y_template["y_meas", j] = inputs["y"][j] / s_y
        return y_template

    mhe.set_tvp_fun(tvp_fun)
    mhe.set_p_fun(p_fun)
    mhe.set_y_fun(y_fun)
    return inputs


def run_dompc_standard_mhe(
    system: System,
    weights: MHEWeights,
    N: int,
    u: ArrayLike,
    y: ArrayLike,
    reference_x_hat: ArrayLike,
    *,
    w_prior: ArrayLike | None = None,
    ipopt_options: dict[str, Any] | None = None,
) -> DompcPeerResult:
    """Run the do-mpc standard MHE over ``u (K, nu)``, ``y (K+1, ny)``; compare with ``reference_x_hat``.

    Parameters
    ----------
    system, weights, N, w_prior, ipopt_options
        As for :func:`build_dompc_mhe`.
    u : array_like (K, nu)
        Known inputs.
    y : array_like (K+1, ny)
        Measurements (finite).
    reference_x_hat : array_like (K+1, nx)
        ``StandardMHE(solver="ipopt")`` estimates of the same data and weights: they give the
        estimates for ``k < N`` (do-mpc has no growing start-up windows) and the deviation.

    Returns
    -------
    DompcPeerResult

    """
    u_arr = np.asarray(u, dtype=float).reshape(-1, system.nu)
    y_arr = np.asarray(y, dtype=float).reshape(-1, system.ny)
    ref = np.asarray(reference_x_hat, dtype=float).reshape(-1, system.nx)
    K = y_arr.shape[0] - 1
    if u_arr.shape[0] != K or ref.shape[0] != K + 1 or K < N:
        raise ValueError(
            f"u, y, reference_x_hat: expected K >= N={N}, K+1, K+1 rows; got {u_arr.shape[0]}, {K + 1}, {ref.shape[0]}"
        )
    mhe, inputs = build_dompc_mhe(system, weights, N, w_prior=w_prior, ipopt_options=ipopt_options)

    x_hat = ref.copy()
    solve_time, cpu_time = np.zeros(K + 1), np.zeros(K + 1)
    iterations = np.zeros(K + 1)
    success = np.ones(K + 1, dtype=bool)
    # initial guess: the prior propagated with w_bar through the first window
    w_bar = system.nominal_w if w_prior is None else np.asarray(w_prior, dtype=float).reshape(system.nw)
    xs = [x_hat[0]]
    for j in range(N):
        xs.append(np.asarray(system.f(xs[-1], u_arr[j], w_bar)).reshape(-1))
    zero_v = np.zeros(system.nv)
    guess = np.concatenate([xs[-1], xs[-2], w_bar, zero_v])
    mhe.x0 = guess
    mhe.set_initial_guess()
    for j in range(N + 1):  # the whole window, not only x0 broadcast
        mhe.opt_x_num["_x", j, -1] = np.concatenate([xs[j], xs[max(j - 1, 0)], w_bar, zero_v]) / np.concatenate(
            [system.x.scale, system.x.scale, system.w.scale, np.ones(system.nv)]
        )
    for k in range(N, K + 1):
        inputs["prior"] = x_hat[k - N]
        inputs["u"] = u_arr[k - N : k]
        inputs["y"] = y_arr[k - N : k]
        start, cpu_start = perf_counter(), thread_time()
        with contextlib.redirect_stdout(io.StringIO()), warnings.catch_warnings():
            warnings.simplefilter("ignore", FutureWarning)
            estimate = mhe.make_step(y_arr[k - 1])
        solve_time[k], cpu_time[k] = perf_counter() - start, thread_time() - cpu_start
        stats = mhe.solver_stats
        iterations[k] = stats.get("iter_count", np.nan)
        success[k] = bool(stats.get("success", False))
        x_hat[k] = np.asarray(estimate).reshape(-1)[: system.nx]
    ms, cpu = 1e3 * solve_time[N:], 1e3 * cpu_time[N:]
    deviation = float(np.abs((x_hat[N:] - ref[N:]) / system.x.scale).max())
    return DompcPeerResult(
        x_hat=x_hat,
        solve_time=solve_time,
        iterations=iterations,
        success=success,
        median_ms=float(np.median(ms)),
        p95_ms=float(np.percentile(ms, 95)),
        max_ms=float(ms.max()),
        median_cpu_ms=float(np.median(cpu)),
        p95_cpu_ms=float(np.percentile(cpu, 95)),
        max_cpu_ms=float(cpu.max()),
        max_dev_vs_ipopt=deviation,
        failures=int((~success).sum()),
    )
