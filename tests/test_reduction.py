"""Reduced-order models (sec:UISE_red): checks of ass and the crop model's reduction."""

import numpy as np
import pytest

from uiest import ModelError, System
from uiest.detectability import certify_reduced_model
from uiest.models import crop_growth
from uiest.reduction import ReducedModel


def test_crop_reduction_recovers_the_state_and_matches_the_model():
    reduced = crop_growth.reduction()
    system = reduced.system
    rng = np.random.default_rng(0)
    x = system.x.bounds.sample(rng, 1)[0]
    u, w, v = np.array([25.0]), np.array([0.97]), np.array([1e-6, -2e-6])
    z = np.asarray(reduced.T(x), dtype=float).ravel()
    y = system.output(x, v)
    # eq:fullest recovers x from y and z_sharp
    np.testing.assert_allclose(reduced.full_state(y, z[1:], v), x, rtol=1e-12)
    # the reduced model reproduces T_sharp of the full model's step and the output
    z_next = np.asarray(reduced.f_sharp(z[1:], y, u, v), dtype=float).ravel()
    expected = np.asarray(reduced.T(system.step(x, u, w)), dtype=float).ravel()[1:]
    np.testing.assert_allclose(z_next, expected, rtol=1e-12)
    np.testing.assert_allclose(np.asarray(reduced.h_sharp(z[1:], y, v), dtype=float).ravel(), y, rtol=1e-12)
    assert reduced.n_sharp == 2 and reduced.z_bounds.contains(z[1:])


def test_reduction_rejects_maps_that_violate_the_assumption():
    system = crop_growth.system()
    identity = (lambda x: x, lambda z: z)
    with pytest.raises(ModelError, match=r"Eq\. \(18\) of Guo et al\."):  # x^{d,2} sees w
        ReducedModel.from_maps(system, *identity, lambda y, z, v: [y[0] - v[0]], n_flat=1)
    ratio = 0.8 * 4.1
    T = lambda x: [x[0], x[1], ratio * x[0] + x[2]]  # noqa: E731
    with pytest.raises(ModelError, match="T_inv"):
        ReducedModel.from_maps(system, T, lambda z: z, lambda y, z, v: [y[0] - v[0]], n_flat=1)
    T_inv = lambda z: [z[0], z[1], z[2] - ratio * z[0]]  # noqa: E731
    with pytest.raises(ModelError, match="psi"):
        ReducedModel.from_maps(system, T, T_inv, lambda y, z, v: [y[1]], n_flat=1)
    with pytest.raises(ModelError, match="n_flat"):
        ReducedModel.from_maps(system, T, T_inv, lambda y, z, v: [y[0]], n_flat=4)


def test_automatic_reduction_of_the_crop_model_agrees_with_the_papers_map():
    from uiest.reduction import reduce_quasi_state_affine

    paper = crop_growth.reduction()
    auto = reduce_quasi_state_affine(crop_growth.system())
    assert auto.n_flat == paper.n_flat == 1
    # z_sharp of the two constructions differ by a linear change K: z_auto = K z_paper
    rng = np.random.default_rng(1)
    system = paper.system
    x = system.x.bounds.sample(rng, 10)
    z_paper = np.array([np.asarray(paper.T(xi), dtype=float).ravel()[1:] for xi in x])
    z_auto = np.array([np.asarray(auto.T(xi), dtype=float).ravel()[1:] for xi in x])
    K = np.linalg.lstsq(z_paper, z_auto, rcond=None)[0].T
    np.testing.assert_allclose(z_paper @ K.T, z_auto, rtol=1e-10, atol=1e-14)
    # the same reduced dynamics and output at random (z, gamma, u, v), not only on trajectories
    for _ in range(5):
        z = paper.z_bounds.sample(rng, 1)[0]
        gamma = system.output(system.x.bounds.sample(rng, 1)[0], np.zeros(2)) + rng.uniform(-1e-4, 1e-4, 2)
        u, v = np.array([25.0]), rng.uniform(-3e-6, 3e-6, 2)
        f_paper = np.asarray(paper.f_sharp(z, gamma, u, v), dtype=float).ravel()
        f_auto = np.asarray(auto.f_sharp(K @ z, gamma, u, v), dtype=float).ravel()
        np.testing.assert_allclose(K @ f_paper, f_auto, rtol=1e-10)
        h_paper = np.asarray(paper.h_sharp(z, gamma, v), dtype=float).ravel()
        np.testing.assert_allclose(np.asarray(auto.h_sharp(K @ z, gamma, v), dtype=float).ravel(), h_paper, rtol=1e-10)


def test_automatic_reduction_refuses_without_matching():
    from uiest.models import linear
    from uiest.reduction import reduce_quasi_state_affine

    system = linear.linear_system(np.array([[0.5, 1.0], [0.0, 0.3]]), [[0.0], [1.0]], [[1.0, 0.0]],
                                  x_bounds=(-1, 1), v_bounds=(-0.1, 0.1))  # fmt: skip
    with pytest.raises(ModelError, match=r"rank\(C B\) = 0 != rank\(B\) = 1"):
        reduce_quasi_state_affine(system)
    with pytest.raises(ModelError, match="phi"):
        reduce_quasi_state_affine(system, phi=lambda x: x)


def test_assumption_report_of_the_crop_reduction():
    report = crop_growth.reduction().check_assumptions(n_points=300)
    assert report.holds and report.points == 300
    assert report.inverse_error < 1e-12 and report.psi_error < 1e-12 and report.w_sensitivity < 1e-12
    # dh_T/dz_flat: y^c -> 1, y^d -> -a_d3/a_c1 (x^{d,2} = z_2 - (a_d3/a_c1) x^c): the best margin is 3.28
    assert report.dominance_outputs == (1,)
    assert report.dominance_margin == pytest.approx(0.8 * 4.1)


def test_the_reduced_domain_is_proved_not_read_off_a_grid():
    # z3 = x3 + 0.3 sin(4 x2) reaches 1.3 at x2 = pi/8, between the points of a 5-point grid of X (1.273 there):
    # a box from the grid would leave part of T_sharp(X) outside the certificate's domain
    system = System.from_callables(
        lambda x, u, w: [0.5 * x[0] + 0.2 * x[1] + w[0], 0.5 * x[1] + 0.1 * x[0], 0.5 * x[2] + 0.1 * x[1]],
        lambda x, v: [x[0] + v[0]], nx=3, nw=1, nv=1, x_bounds=(-1.0, 1.0), v_bounds=(-0.01, 0.01),
    )  # fmt: skip
    reduced = ReducedModel.from_maps(
        system, lambda x: [x[0], x[1], x[2] + 0.3 * np.sin(4.0 * x[1])],
        lambda z: [z[0], z[1], z[2] - 0.3 * np.sin(4.0 * z[1])], lambda y, z, v: [y[0] - v[0]], n_flat=1,
    )  # fmt: skip
    assert reduced.z_bounds_note == "" and reduced.z_bounds.upper[1] >= 1.3 and reduced.z_bounds.lower[1] <= -1.3
    cert = certify_reduced_model(reduced)
    assert cert.certified and cert.sound, cert.reason
