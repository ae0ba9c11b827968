"""Covers of a matrix function over a box: exact (by entries, a parameter box) or, on request, sampled."""

import casadi as ca
import numpy as np
import pytest
import scipy.optimize

from uiest.box import Box
from uiest.detectability.cover import MAX_PARAMETERS, cover
from uiest.errors import ModelError, OptionError


def _matrix_function():
    z = ca.SX.sym("z", 3)
    M = ca.vertcat(ca.horzcat(ca.sin(z[0]) * z[1], 1.0), ca.horzcat(ca.exp(-z[0]) + z[1], ca.sin(z[0])))
    return ca.Function("M", [z], [M])


def _in_hull(points, vertices):
    """Whether each point is a convex combination of the vertices (one LP per point)."""
    m = len(vertices)
    A_eq = np.vstack([vertices.reshape(m, -1).T, np.ones((1, m))])
    inside = []
    for p in points.reshape(len(points), -1):
        res = scipy.optimize.linprog(np.zeros(m), A_eq=A_eq, b_eq=np.append(p, 1.0), bounds=(0, None))
        inside.append(res.status == 0)
    return np.array(inside)


def test_sampled_cover_contains_fresh_samples():
    fun = _matrix_function()
    box = Box([-1.0, 0.0, 5.0], [2.0, 3.0, 5.0])  # the last axis is irrelevant
    found = cover(fun, box, method="sampled", samples=2000)
    assert found.kind == "sampled cover" and not found.sound and found.dimension == 3
    z = box.sample(np.random.default_rng(7), 200)
    values = np.stack([np.asarray(fun(zi)) for zi in z])
    assert _in_hull(values, found.vertices).all()


def test_parameter_cover_is_sound_and_exact_on_its_box():
    fun = _matrix_function()
    box = Box([-1.0, 0.0, 5.0], [2.0, 3.0, 5.0])
    z = ca.SX.sym("z", 3)
    theta = ca.Function("theta", [z], [ca.vertcat(ca.sin(z[0]) * z[1], ca.exp(-z[0]) + z[1], ca.sin(z[0]))])
    found = cover(fun, box, parameters=theta)
    assert found.kind == "parameter box" and found.sound and len(found.vertices) == 8
    entries = found.vertices.reshape(8, -1)
    # the corners reach the true extremes of each parameter (interval bounds are tight)
    assert entries[:, 3].max() == pytest.approx(1.0, abs=1e-3)  # sin over [-1, 2]
    assert entries[:, 0].max() == pytest.approx(3.0, abs=3e-3)  # sin(x) y over [-1, 2] x [0, 3]


def test_constant_and_bad_inputs():
    z = ca.SX.sym("z", 2)
    constant = cover(ca.Function("M", [z], [ca.DM([[1.0, 2.0]])]), Box([-np.inf, 0.0], [np.inf, 1.0]))
    assert constant.kind == "constant" and constant.sound and len(constant.vertices) == 1
    fun = ca.Function("M", [z], [z[0] * z[1]])
    with pytest.raises(ModelError, match=r"z\[0\]"):
        cover(fun, Box([-np.inf, 0.0], [np.inf, 1.0]))
    wrong = ca.Function("theta", [z], [z[0]])
    with pytest.raises(ModelError, match=r"not affine in the given parameters: entry \[0, 0\]"):
        cover(fun, Box([0.0, 0.0], [1.0, 1.0]), parameters=wrong)
    with pytest.raises(OptionError, match="cover"):
        cover(fun, Box([0.0, 0.0], [1.0, 1.0]), method="fitted")


def test_exact_cover_by_entries_holds_every_value_and_counts_proportional_entries_once():
    fun = _matrix_function()
    box = Box([-1.0, 0.0, 5.0], [2.0, 3.0, 5.0])
    found = cover(fun, box)
    assert found.kind == "exact by entries" and found.sound and found.dimension == 3 and len(found.vertices) == 8
    z = box.sample(np.random.default_rng(8), 300)
    values = np.stack([np.asarray(fun(zi)) for zi in z])
    assert _in_hull(values, found.vertices).all()
    assert found.rounding < 1e-14
    # 2 sin + 1 and -3 sin are one function up to a factor and an offset; z0 z1 / 2 - 2 likewise with z0 z1
    w = ca.SX.sym("w", 2)
    M = ca.vertcat(ca.horzcat(2.0 * ca.sin(w[0]) + 1.0, -3.0 * ca.sin(w[0])),
                   ca.horzcat(w[0] * w[1], 0.5 * (w[1] * w[0]) - 2.0))  # fmt: skip
    paired = cover(ca.Function("M", [w], [M]), Box([-1.0, -1.0], [1.0, 1.0]))
    assert paired.dimension == 2 and len(paired.vertices) == 4
    # every vertex keeps the exact relations between entries
    np.testing.assert_allclose(paired.vertices[:, 0, 1], -1.5 * (paired.vertices[:, 0, 0] - 1.0), atol=1e-15)


def test_a_narrow_peak_is_inside_the_exact_cover():
    # a bump 1e-4 wide: interval branch and bound must find it to close its bound
    z = ca.SX.sym("z", 2)
    M = ca.vertcat(0.5 + 0.5 * ca.exp(-(((z[0] - 0.3137) / 1e-4) ** 2)), z[1])
    box = Box([-1.0, -1.0], [1.0, 1.0])
    found = cover(ca.Function("M", [z], [M]), box)
    assert found.vertices[:, 0, 0].max() == pytest.approx(1.0, abs=1e-3)
    assert found.vertices[:, 0, 0].max() >= 1.0
    assert np.min(np.abs(found.extremes[:, 0] - 0.3137)) < 1e-4  # where the peak was found


def test_maps_the_forms_do_not_prove_and_covers_too_large_are_refused():
    z = ca.SX.sym("z", 1)
    box = Box([-2.0], [2.0])
    sech2 = ca.Function("M", [z], [1.0 - ca.tanh(z[0]) ** 2])
    with pytest.raises(ModelError, match="not exact combinations of the parameters' expressions"):
        cover(sech2, box, parameters=ca.Function("theta", [z], [1.0 / ca.cosh(z[0]) ** 2]))
    exact = cover(sech2, box, parameters=ca.Function("theta", [z], [ca.tanh(z[0]) ** 2]))
    assert exact.kind == "parameter box" and exact.dimension == 1
    powers = ca.Function("M", [z], [ca.vertcat(*[z[0] ** k for k in range(1, MAX_PARAMETERS + 2)])])
    whole = r"cover='sampled' \(a check at samples, not a proof\)$"
    with pytest.raises(ModelError, match=f"span {MAX_PARAMETERS + 1} independent functions.*{whole}"):
        cover(powers, box)
    with pytest.raises(ModelError, match=r"interval arithmetic cannot bound.*parameters="):
        cover(ca.Function("M", [z], [ca.floor(z[0]) * z[0]]), box)
    with pytest.raises(ModelError, match="unbounded over the domain"):
        cover(ca.Function("M", [z], [1.0 / z[0]]), box)
