"""The reduced certificate's domain: the points whose full state lies in X, not the box around T(X) x Y x V."""

import dataclasses

import numpy as np
import pytest

from uiest import ModelError, System, simulate
from uiest.detectability import certify_reduced_ioss, certify_reduced_model
from uiest.detectability.falsify import pairs_text
from uiest.estimators import TwoStageUISE
from uiest.models import linear
from uiest.reduction import reduce_quasi_state_affine

FAST = {"samples": 500}


def _tanks() -> System:
    """Two tanks in series, sampled by RK4: a leak w on tank 1, its level measured; sqrt(h) needs h >= 0."""

    def rhs(x, u, w):
        return [u[0] - 0.5 * np.sqrt(x[0]) - w[0], 0.5 * np.sqrt(x[0]) - 0.4 * np.sqrt(x[1])]

    return System.from_ode(rhs, lambda x, v: [x[0] + v[0]], nx=2, nu=1, nw=1, nv=1, dt=0.5, substeps=2,
                           x_bounds=(0.1, 1.6), u_bounds=(0.2, 0.6), v_bounds=(-0.005, 0.005),
                           x_names=["h1", "h2"], x_units=["m", "m"], name="tanks")  # fmt: skip


def test_two_tanks_reduction_designs_and_the_two_stage_uise_estimates_under_an_unknown_leak():
    tanks = _tanks()
    red = reduce_quasi_state_affine(tanks)
    # the box T_sharp(X) x Y x V holds points whose full state has h2 < 0, where sqrt has no bound (the old cover
    # of that box raised ModelError: "interval arithmetic finds entry [0, 0] unbounded over the domain")
    corner = red.full_state([0.1 - 0.005], red.z_bounds.lower, tanks.v.bounds.upper)  # y = 0.095 is in h(X, V)
    assert corner[1] < 0.0
    prior = np.array([1.5, 0.15])
    with pytest.warns(UserWarning, match=r"not informative for \['h2'\]"):  # h1 is read from the output
        est = TwoStageUISE.design(red, x0_prior=prior, max_horizon=40, trials=1, steps=60)
    cert = est.certificate
    assert cert.certified and cert.sound, cert.reason
    assert "in X" in cert.to_dict()["domain"]
    # verify draws pairs until the 2000 asked for have both points' full states in X, and scores only those
    check = cert.verify(2000, seed=1)
    assert check.holds and check.pairs_used == 2000 < check.pairs_drawn
    steps = 160
    rng = np.random.default_rng(3)
    u = (0.4 + 0.1 * np.sign(np.sin(0.05 * np.arange(steps))))[:, None]
    leak = np.repeat(rng.uniform(-0.4, 0.3, steps // 20), 20)

    def w(k, x):  # the leak, held where it would take h1 out of [0.15, 0.8]
        f0 = tanks.step(x, u[k], [0.0])[0]
        g = tanks.step(x, u[k], [1.0])[0] - f0
        return [float(np.clip(leak[k], *sorted(((0.8 - f0) / g, (0.15 - f0) / g))))]

    truth = simulate(tanks, [0.12, 1.55], steps, u=u, w=w, seed=0)
    assert np.all((truth.x >= 0.1) & (truth.x <= 1.6))
    result = est.run(truth.u, truth.y)
    error = np.abs(result.x_hat - truth.x)[60:]
    assert error.max() < 0.02 < np.abs(truth.w).max()
    # the certificate covers only nodes held in X: without the node constraints Theorem 4.8 does not apply
    free = TwoStageUISE(red, certificate=cert, N=est.N, x0_prior=prior, state_constraints=False)
    assert est.guarantee.applies and not free.guarantee.applies
    assert "state_constraints=False" in free.guarantee.reason


def test_a_rotated_linear_reduction_certifies_the_same_on_the_states_in_x_as_on_the_box():
    system, *_ = linear.with_invariant_zeros([0.6, -0.3], seed=4, x_bounds=(-2.0, 2.0), v_bounds=(-0.01, 0.01))
    red = reduce_quasi_state_affine(system)
    T = np.asarray(red.T(np.eye(3)), dtype=float)  # columns: T(e_i), T linear
    assert np.count_nonzero(np.abs(T) > 1e-6) > 3  # a rotation, not a selection of states
    lifted = certify_reduced_model(red, **FAST)
    model = lifted.model
    boxed = certify_reduced_ioss(
        red.f_sharp,
        red.h_sharp,
        z_bounds=model.z_box,
        gamma_bounds=(model.d_box.lower[: system.ny], model.d_box.upper[: system.ny]),
        v_bounds=system.v.bounds,
        z_scale=model.z_scale,
        gamma_scale=model.d_scale[: system.ny],
        v_scale=model.d_scale[system.ny :],
        **FAST,
    )
    assert model.lift is not None and boxed.model.lift is None
    assert lifted.certified and boxed.certified, (lifted.reason, boxed.reason)
    assert lifted.mu_min == pytest.approx(0.36, abs=2e-3) and boxed.mu_min == pytest.approx(0.36, abs=2e-3)
    assert lifted.verify(2000, seed=2).holds
    # a certificate on part of the boxes says so where it is read
    assert lifted.reason.endswith("over the points with x = T^-1(psi(gamma, z_sharp, v), z_sharp) in X")
    assert "over the points" not in boxed.reason
    # the falsifier draws pairs until 20,000 have both points in D (a thin slab of the box: about 1 in 7 pairs
    # is in it), and its text counts the pairs it scored and drew
    found = lifted.falsification
    assert 20_000 <= found.scored < found.pairs // 4, found
    assert f"over {found.scored:,} pairs scored of {found.pairs:,} drawn and" in lifted.falsification.text()
    assert lifted.to_dict()["falsification"]["pairs_scored"] == found.scored
    assert pairs_text(1, 1) == "1 pair" and pairs_text(1, 20_000) == "1 pair scored of 20,000 drawn"
    assert pairs_text(0, 500) == "no pairs scored of 500 drawn"
    every = boxed.falsification  # without a lift every pair is scored, and the text says so as before
    assert every.scored == every.pairs >= 20_000 and f"over {every.pairs:,} pairs and" in every.text()


def test_the_lifted_certificate_holds_on_d_although_the_inequality_fails_outside_x():
    # a cubic term in x2 (slope 0.06 x2^2): small in X = [-2, 2]^3, growing past it, where the box's points go
    _, A, B, C = linear.with_invariant_zeros([0.6, -0.3], seed=4)
    cubic = System.from_callables(lambda x, u, w: A @ x + B @ w + 0.02 * np.eye(3)[1] * x[1] ** 3,
                                  lambda x, v: C @ x + v, nx=3, nw=1, nv=1, x_bounds=(-2.0, 2.0),
                                  v_bounds=(-0.01, 0.01), name="cubic")  # fmt: skip
    cert = certify_reduced_model(reduce_quasi_state_affine(cubic), **FAST)
    # the falsifier scores only pairs in D (unmasked, its pairs outside X refute the certificate)
    assert cert.certified, cert.reason
    assert not cert.falsification.refuted and 20_000 <= cert.falsification.scored < cert.falsification.pairs
    check = cert.verify(20000, seed=1)
    assert check.holds and check.pairs_used == 20000 < check.pairs_drawn
    unlifted = dataclasses.replace(cert, model=dataclasses.replace(cert.model, lift=None))
    outside = unlifted.verify(20000, seed=1)
    assert outside.pairs_used == outside.pairs_drawn and outside.worst_ratio > 1.5


def test_a_reduction_that_cannot_be_cut_to_x_names_the_box_that_leaves_x():
    def rhs(x, u, w):
        return [u[0] - 0.5 * np.sqrt(x[0]) - w[0], 0.5 * np.sqrt(x[0]) - 0.4 * np.sqrt(x[1])]

    # y = h1 + v^3: psi is not affine in v, so x(z_sharp, gamma, v) is not affine and the certificate keeps the box
    tanks = System.from_ode(rhs, lambda x, v: [x[0] + v[0] ** 3], nx=2, nu=1, nw=1, nv=1, dt=0.5, substeps=2,
                            x_bounds=(0.1, 1.6), u_bounds=(0.2, 0.6), v_bounds=(-0.17, 0.17), name="tanks")  # fmt: skip
    red = reduce_quasi_state_affine(tanks)
    with pytest.raises(ModelError, match=r"beyond X = \[0.1, 1.6\] x \[0.1, 1.6\]") as caught:
        certify_reduced_model(red, **FAST)
    text = str(caught.value)
    assert "z_sharp in [-0.006953, 1.59]" in text and "x [-0.0009401, 1.701]" in text
    assert "psi affine in (gamma, v)" in text


def test_pairs_admitted_from_a_thin_domain_are_half_close_and_none_admitted_is_reported_not_raised():
    import casadi as ca

    from uiest.box import Box
    from uiest.detectability import falsify
    from uiest.detectability.certificate import ADMIT_DRAWS, sample_admitted_pairs

    box, shared, scale = Box((-1.0, -1.0), (1.0, 1.0)), Box((0.0,), (1.0,)), np.ones(2)

    def slab(a, b, s):  # both points in 0.5 <= z0 <= 1: a close pair lands there four times as often as a far one
        return (a[:, 0] >= 0.5) & (b[:, 0] >= 0.5)

    a, b, s, drawn = sample_admitted_pairs(np.random.default_rng(0), box, shared, 400, scale, slab)
    assert len(a) == len(b) == len(s) == 400 < drawn <= ADMIT_DRAWS * 400 and slab(a, b, s).all()
    distance = np.linalg.norm(a - b, axis=1)  # close pairs first: sample_pairs' steps of at most 0.1 sqrt(8)
    assert np.all(distance[:200] <= 0.1 * np.sqrt(8.0)) and np.median(distance[200:]) > 0.1 * np.sqrt(8.0)
    nothing = sample_admitted_pairs(np.random.default_rng(0), box, shared, 40, scale, lambda a, b, s: a[:, 0] > 2.0)
    assert nothing[0].shape == (0, 2) and nothing[3] == ADMIT_DRAWS * 40
    # the search over a domain no drawn pair lies in scores none and says so
    x, y, u = ca.SX.sym("x", 2), ca.SX.sym("y", 2), ca.SX.sym("u", 1)
    terms = ca.Function("terms", [x, y, u], [ca.sumsqr(x - y), 2.0 * ca.sumsqr(x - y)])
    found = falsify.search(terms, box, shared, scale, admit=lambda a, b, s: a[:, 0] > 2.0, pairs=40)
    assert found.scored == 0 and found.pairs == ADMIT_DRAWS * 40 and not found.refuted
    assert f"no pairs scored of {ADMIT_DRAWS * 40:,} drawn" in found.text()
    # verify on such a domain tests nothing: no ratio (NaN), so it does not hold
    from types import SimpleNamespace

    from uiest.detectability import dissipation

    model = SimpleNamespace(n=2, z_box=box, d_box=Box((-1.0,), (1.0,)), z_scale=scale, d_scale=np.ones(1), u_box=shared,
                            lift=SimpleNamespace(admits=lambda a, b, u, n: np.zeros(len(a), dtype=bool)))  # fmt: skip
    check = dissipation.check_pairs(model, np.eye(2), 0.9, [np.eye(1)], np.eye(1), 10, 0)
    assert check.pairs == 0 and check.drawn == ADMIT_DRAWS * 10 and np.isnan(check.worst_ratio)
