"""Covers of a matrix function over a box by the vertices of a polytope or a parameter box."""

import casadi as ca
import numpy as np
import pytest
import scipy.optimize

from uiest.box import Box
from uiest.detectability.cover import cover
from uiest.errors import ModelError


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
    found = cover(fun, box, samples=2000)
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
    with pytest.raises(ModelError, match="not affine"):
        cover(fun, Box([0.0, 0.0], [1.0, 1.0]), parameters=wrong)
