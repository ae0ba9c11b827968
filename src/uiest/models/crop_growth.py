r"""The simplified crop-growth process of the paper's numerical example (Section "Numerical example").

States ``x = (x^c, x^{d,1}, x^{d,2})``: CO2 concentration of the air and the dry weights of two
crops. Known input: the temperature ``u^d`` (kept at 25 degC in the paper). Unknown input ``w``:
the output of an unknown function of the state, ``w_k = W(x^{d,2}_k) = 1 - exp(-45 x^{d,2}_k)``.
With sampling time ``Delta_t``::

    x^c_{k+1}     = x^c_k + Delta_t a_c1 (F(x^d_k) - w_k) phi(u^d_k, x^c_k)
                    + Delta_t a_c2 (g_1(x^d_k, u^d_k) + g_2(x^d_k, u^d_k))
    x^{d,1}_{k+1} = x^{d,1}_k - Delta_t (a_d1 F(x^d_k) phi(u^d_k, x^c_k) + a_d2 g_1(x^d_k, u^d_k))
    x^{d,2}_{k+1} = x^{d,2}_k + Delta_t (a_d3 phi(u^d_k, x^c_k) w_k - a_d4 g_2(x^d_k, u^d_k))
    y^c_k = x^c_k + v^c_k,    y^d_k = x^{d,1}_k + x^{d,2}_k + v^d_k

with ``F(x^d) = exp(-xi_1 x^{d,1}) - 1`` (the paper's f(x^d)), ``g_j(x^d, u^d) =
x^{d,j} 2^(0.1 u^d - 2.5)`` and the photosynthesis rate (van Henten 2003, with the paper's
factor 100 in place of the radiation)::

    phi(u^d, x^c) = 100 c_rad,phot (x^c - c_Gamma) phi_u(u^d) / (100 c_rad,phot + (x^c - c_Gamma) phi_u(u^d))
    phi_u(u^d)    = -c_CO2,1 (u^d)^2 + c_CO2,2 u^d - c_CO2,3

Parameters (the defaults are the paper's values)

==============  =====================  ===============  ===============================================
name            default                unit             source
==============  =====================  ===============  ===============================================
dt              60                     s                paper (Delta_t)
a_c1            1/4.1                  1/m              paper (= 1/c_cap,c of van Henten 2003)
a_c2            4.87e-7 / 4.1          1/(m s)          paper (a_c2 = 4.87e-7 a_c1; c_resp,c / c_cap,c)
xi_1            53                     m^2/kg           paper (c_pl,d of van Henten 2003)
a_d1            0.544                  --               paper (c_alpha,beta of van Henten 2003)
a_d2            2.65e-7                1/s              paper (c_resp,d of van Henten 2003)
a_d3            0.8                    --               paper
a_d4            1.85e-7                1/s              paper
c_rad_phot      3.55e-9                kg/J             van Henten 2003
c_gamma         5.2e-5                 kg/m^3           van Henten 2003 (c_Gamma)
c_co2_1         5.11e-6                m/(s degC^2)     van Henten 2003
c_co2_2         2.3e-4                 m/(s degC)       van Henten 2003
c_co2_3         6.29e-4                m/s              van Henten 2003
radiation       100                    W/m^2            paper (the factor 100 in phi)
temperature     25                     degC             paper (u^d kept at 25 degC; U is this point)
w_gain          45                     m^2/kg           paper (W(x^{d,2}) = 1 - exp(-45 x^{d,2}))
w_range         (0.965, 1)             --               paper (known range, standard MHE only)
noise_bound     3e-6                   as y             paper (``|v^c|, |v^d| <= 3e-6``, uniform)
x_lower         (0, 0.08, 0.08)        kg/m^3, kg/m^2   paper (X)
x_upper         (0.0027, 0.1, 0.1)     kg/m^3, kg/m^2   paper (X)
==============  =====================  ===============  ===============================================

The paper's citation for phi's constants is van Henten (2009, thesis); their values are those of
van Henten (2003), Biosystems Engineering 85(3):355-364 (see ``shared/notes/references.md``).

What the paper leaves open is collected in :class:`CropScenario` (initial states, simulation
length, priors); :data:`DEFAULT_SCENARIO` holds this project's choices.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from typing import Any

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike

from uiest.box import Box, FloatArray
from uiest.errors import OptionError
from uiest.noise import UniformNoise
from uiest.reduction import ReducedModel
from uiest.system import System

__all__ = [
    "DEFAULT_SCENARIO",
    "NAME",
    "CropParameters",
    "CropScenario",
    "UnknownInputLaw",
    "jacobian_parameters",
    "photosynthesis",
    "reduction",
    "system",
    "unknown_input_value",
]

NAME = "crop-growth"


@dataclass(frozen=True)
class CropParameters:
    """Parameters of the crop-growth model; see the module docstring for units and sources."""

    dt: float = 60.0
    a_c1: float = 1.0 / 4.1
    a_c2: float = 4.87e-7 / 4.1
    xi_1: float = 53.0
    a_d1: float = 0.544
    a_d2: float = 2.65e-7
    a_d3: float = 0.8
    a_d4: float = 1.85e-7
    c_rad_phot: float = 3.55e-9
    c_gamma: float = 5.2e-5
    c_co2_1: float = 5.11e-6
    c_co2_2: float = 2.3e-4
    c_co2_3: float = 6.29e-4
    radiation: float = 100.0
    temperature: float = 25.0
    w_gain: float = 45.0
    w_range: tuple[float, float] = (0.965, 1.0)
    noise_bound: float = 3e-6
    x_lower: tuple[float, float, float] = (0.0, 0.08, 0.08)
    x_upper: tuple[float, float, float] = (0.0027, 0.1, 0.1)

    def with_overrides(self, **overrides: Any) -> CropParameters:
        """A copy with some parameters replaced; unknown names raise :class:`OptionError`."""
        known = {f.name for f in fields(self)}
        unknown = sorted(set(overrides) - known)
        if unknown:
            raise OptionError(f"crop-growth parameters: unknown {unknown}; expected some of {sorted(known)}")
        return replace(self, **overrides)


def photosynthesis(params: CropParameters, temperature: Any, co2: Any) -> Any:
    """phi(u^d, x^c) for numbers or CasADi expressions (see the module docstring)."""
    p = params
    phi_u = -p.c_co2_1 * temperature**2 + p.c_co2_2 * temperature - p.c_co2_3
    light = p.radiation * p.c_rad_phot
    co2_term = (co2 - p.c_gamma) * phi_u
    return light * co2_term / (light + co2_term)


def unknown_input_value(params: CropParameters, x: FloatArray) -> float:
    """W(x^{d,2}) = 1 - exp(-w_gain x^{d,2}) for a numeric state vector x, shape (3,)."""
    return float(1.0 - np.exp(-params.w_gain * x[2]))


@dataclass(frozen=True)
class UnknownInputLaw:
    """The paper's unknown input as a function of the state, for :func:`uiest.simulate`.

    Call as ``law(k, x) -> array (1,)``. Picklable, so it can travel to worker processes.
    """

    params: CropParameters = field(default_factory=CropParameters)

    def __call__(self, k: int, x: FloatArray) -> FloatArray:
        """``w_k`` for the state ``x_k`` (shape (3,)); ``k`` is unused."""
        return np.array([unknown_input_value(self.params, x)])


def system(params: CropParameters | None = None, **overrides: Any) -> System:
    """The crop-growth model as a :class:`~uiest.system.System` (nx=3, nu=1, nw=1, nv=2, ny=2).

    Parameters
    ----------
    params : CropParameters, optional
        Defaults to the paper's values.
    **overrides
        Individual parameters to replace (e.g. ``dt=30``).

    """
    p = (params or CropParameters()).with_overrides(**overrides)
    x = ca.SX.sym("x", 3)
    u = ca.SX.sym("u", 1)
    w = ca.SX.sym("w", 1)
    v = ca.SX.sym("v", 2)
    xc, xd1, xd2, temp = x[0], x[1], x[2], u[0]
    phi = photosynthesis(p, temp, xc)
    growth = ca.exp(-p.xi_1 * xd1) - 1.0
    temp_factor = 2.0 ** (0.1 * temp - 2.5)
    g1, g2 = xd1 * temp_factor, xd2 * temp_factor
    x_next = ca.vertcat(
        xc + p.dt * p.a_c1 * (growth - w[0]) * phi + p.dt * p.a_c2 * (g1 + g2),
        xd1 - p.dt * (p.a_d1 * growth * phi + p.a_d2 * g1),
        xd2 + p.dt * (p.a_d3 * phi * w[0] - p.a_d4 * g2),
    )
    y = ca.vertcat(xc + v[0], xd1 + xd2 + v[1])
    return System.from_expressions(
        x,
        u,
        w,
        v,
        x_next,
        y,
        x_bounds=(p.x_lower, p.x_upper),
        u_bounds=(p.temperature, p.temperature),
        v_bounds=(-p.noise_bound, p.noise_bound),
        w_range=p.w_range,
        x_names=("x_c", "x_d1", "x_d2"),
        u_names=("u_d",),
        w_names=("w",),
        v_names=("v_c", "v_d"),
        y_names=("y_c", "y_d"),
        x_units=("kg/m^3", "kg/m^2", "kg/m^2"),
        u_units=("degC",),
        w_units=("-",),
        v_units=("kg/m^3", "kg/m^2"),
        y_units=("kg/m^3", "kg/m^2"),
        dt=p.dt,
        time_unit="s",
        name=NAME,
    )


def jacobian_parameters(params: CropParameters | None = None, **overrides: Any) -> Any:
    """The three functions of the state the certificate's state Jacobian is affine in, as ``theta(x, u)``.

    With the unknown input's direction projected out, ``df/dx`` varies through
    ``F(x^{d,1}) phi'(x^c)`` and ``phi'(x^c)`` (its first column) and ``exp(-xi_1 x^{d,1}) phi(x^c)``
    (its second) only (u is the fixed temperature), each entry an exact combination of these three
    as the model writes them, so the box of theta over X gives an exact cover
    (``certify_strong_detectability(..., parameters=jacobian_parameters())``). The first column is
    nearly a multiple of ``(exp(-xi_1 x^{d,1}) - 1) phi'(x^c)`` alone, but only up to the rounding of
    the model's constants, so that is not a proof.
    """
    p = (params or CropParameters()).with_overrides(**overrides)

    def theta(x: Any, u: Any) -> list[Any]:
        co2 = ca.SX.sym("co2")
        phi = ca.Function("phi", [co2], [photosynthesis(p, p.temperature, co2)])
        dphi = ca.Function("dphi", [co2], [ca.jacobian(photosynthesis(p, p.temperature, co2), co2)])
        decay = np.exp(-p.xi_1 * x[1])
        return [decay * dphi(x[0]), dphi(x[0]), decay * phi(x[0])]

    return theta


def reduction(params: CropParameters | None = None, **overrides: Any) -> ReducedModel:
    """The paper's reduction for the two-stage UISE (Section "Numerical example").

    ``T(x) = (x^c, x^{d,1}, (a_d3 / a_c1) x^c + x^{d,2})`` with ``T_flat(x) = x^c`` and
    ``psi(y, z_sharp, v) = y^c - v^c``: the unknown input cancels in the third coordinate
    (``(a_d3 / a_c1) Delta_t a_c1 phi w = Delta_t a_d3 phi w``), so Eq. (18) of Guo et al. holds. Further
    arguments as in :func:`system`.
    """
    p = (params or CropParameters()).with_overrides(**overrides)
    ratio = p.a_d3 / p.a_c1
    return ReducedModel.from_maps(
        system(p),
        lambda x: [x[0], x[1], ratio * x[0] + x[2]],
        lambda z: [z[0], z[1], z[2] - ratio * z[0]],
        lambda y, z_sharp, v: [y[0] - v[0]],
        n_flat=1,
    )


@dataclass(frozen=True)
class CropScenario:
    """The choices the paper leaves open, made explicit.

    Attributes
    ----------
    x0 : tuple of 3 floats
        Nominal initial state (kg/m^3, kg/m^2, kg/m^2), used for single runs.
    x0_box : tuple of two 3-tuples
        Box from which Monte Carlo runs draw x0 uniformly.
    steps : int
        Simulation length K (samples of 60 s).
    prior_d : tuple of 2 floats
        Prior of (x^{d,1}, x^{d,2}) for every estimator: the centre of X's crop part.
        The prior of x^c is the first measurement y^c_0, as in the paper.
    noise_bound : float
        Half-width of the uniform measurement noise (paper: 3e-6).

    """

    x0: tuple[float, float, float] = (2.2e-3, 0.085, 0.083)
    x0_box: tuple[tuple[float, float, float], tuple[float, float, float]] = (
        (1.8e-3, 0.082, 0.081),
        (2.6e-3, 0.088, 0.085),
    )
    steps: int = 300
    prior_d: tuple[float, float] = (0.09, 0.09)
    noise_bound: float = 3e-6

    def noise(self) -> UniformNoise:
        """Uniform noise ``|v_i| <= noise_bound``."""
        return UniformNoise.symmetric(self.noise_bound)

    def prior(self, y0: ArrayLike) -> FloatArray:
        """Prior of x_0 from the first measurement: ``(y^c_0, prior_d)``, shape (3,)."""
        return np.array([float(np.asarray(y0)[0]), *self.prior_d])

    def sample_x0(self, rng: np.random.Generator) -> FloatArray:
        """One initial state drawn uniformly from ``x0_box``, shape (3,)."""
        lower, upper = (np.asarray(corner, dtype=float) for corner in self.x0_box)
        return Box(lower, upper).sample(rng, 1)[0]


DEFAULT_SCENARIO = CropScenario()
"""This project's choices for what the paper leaves open (see :class:`CropScenario`)."""
