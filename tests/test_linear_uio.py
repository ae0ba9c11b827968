"""The Chen-Patton-Zhang linear unknown input observer: exact error recursion e+ = F e despite huge unknown
inputs, gains (DARE, poles, given), refusal without matching or with unstable zeros, offsets, missing data."""

import casadi as ca
import numpy as np
import pytest

from uiest import DataError, ModelError, OptionError, System, UniformNoise, simulate
from uiest.detectability.linear import linear_strong_detectability
from uiest.estimators import EstimationResult, LinearUIO, Outcome
from uiest.models import closed_form, linear

SYSTEM, A, B, C = linear.with_invariant_zeros([0.5, 0.2], seed=1, v_bounds=(-1e-3, 1e-3))
K = 50
UNKNOWN_INPUTS = {
    "constant 1e6": np.full((K, 1), 1e6),
    "ramp": (1e4 * np.arange(K) + 1e3 * np.sin(np.arange(K)))[:, None],
}


@pytest.mark.parametrize("w_name", list(UNKNOWN_INPUTS))
def test_error_follows_F_exactly_despite_huge_unknown_input(w_name):
    x0, prior = np.array([1.0, -1.0, 0.5]), np.zeros(3)
    traj = simulate(SYSTEM, x0, K, w=UNKNOWN_INPUTS[w_name])
    uio = LinearUIO(SYSTEM, x0_prior=prior)
    result = uio.run(None, traj.y)
    scale = np.abs(traj.x).max()
    # x - x_hat = e with e+ = F e and e0 = T (x0 - prior)
    e = [uio.T @ (x0 - prior)]
    for _ in range(K):
        e.append(uio.F @ e[-1])
    np.testing.assert_allclose(result.error(traj.x), np.array(e), atol=1e-14 * scale * 10)
    assert np.allclose(uio.T @ B, 0.0, atol=1e-12) and uio.spectral_radius == pytest.approx(0.5, abs=1e-9)
    np.testing.assert_allclose(result.w_hat[30:], traj.w[30:], atol=1e-14 * scale * 100)
    assert result.estimator == "LinearUIO" and result.horizon is None and set(result.outcome) == {Outcome.UPDATED}
    assert result.failures == 0 and np.all(result.iterations == 0)
    assert "Lemma 3.5 of Guo et al." in result.guarantee.theorem and uio.guaranteed and result.guarantee.applies


def test_noise_gives_a_bounded_error():
    traj = simulate(SYSTEM, [1.0, -1.0, 0.5], K, w=UNKNOWN_INPUTS["ramp"], v=UniformNoise.symmetric(1e-3), seed=0)
    result = LinearUIO(SYSTEM, x0_prior=np.zeros(3)).run(None, traj.y)
    assert np.abs(result.error(traj.x))[20:].max() < 1e-2


def test_gains_poles_and_given():
    dare = LinearUIO(SYSTEM)
    placed = LinearUIO(SYSTEM, poles=[0.5, 0.2, -0.3])
    np.testing.assert_allclose(np.sort(np.linalg.eigvals(placed.F).real), [-0.3, 0.2, 0.5], atol=1e-8)
    given = LinearUIO(SYSTEM, gain=dare.K1)
    np.testing.assert_allclose(given.F, dare.F)
    np.testing.assert_allclose(dare.K, dare.K1 + dare.F @ dare.H)
    with pytest.raises(OptionError, match="invariant zeros"):
        LinearUIO(SYSTEM, poles=[0.3, 0.2, 0.1])
    with pytest.raises(OptionError, match="3 poles"):
        LinearUIO(SYSTEM, poles=[0.5, 0.2])
    with pytest.raises(OptionError, match="at most one"):
        LinearUIO(SYSTEM, poles=[0.5, 0.2, 0.1], gain=dare.K1)
    with pytest.raises(OptionError, match=r"gain: expected shape \(3, 1\)"):
        LinearUIO(SYSTEM, gain=np.zeros((1, 3)))
    with pytest.raises(OptionError, match="Schur"):
        LinearUIO(SYSTEM, gain=1e3 * np.ones((3, 1)))


def test_refused_without_matching_or_with_unstable_zeros_or_nonlinear():
    no_matching = linear.linear_system(np.eye(2) * 0.5, [[1.0], [0.0]], [[0.0, 1.0]])  # C B = 0
    with pytest.raises(ModelError, match=r"rank\(CB\) = 0 < rank\(B\) = 1"):
        LinearUIO(no_matching)
    with pytest.raises(ModelError, match="not strongly detectable"):
        LinearUIO(linear.with_invariant_zeros([1.5], seed=3)[0])
    with pytest.raises(ModelError, match="linear"):
        LinearUIO(closed_form.system())
    with pytest.raises(OptionError, match="system"):
        LinearUIO(A)


def test_a_zero_on_the_unit_circle_is_not_strongly_detectable_and_no_observer_is_built():
    # the zero at 1 is computed as 0.9999999999999998: an undamped motion no output sees, not a decaying one
    A, E, C = [[0.5, 0.1, 0], [0, 1.0, 0.2], [0.1, 0, 0.7]], [[1], [0], [0]], [[1, 0, 0], [0, 0, 1]]
    det = linear_strong_detectability(A, E, C)
    assert not det.strongly_detectable and "on the unit circle" in det.reason
    with pytest.raises(ModelError, match="on the unit circle"):
        LinearUIO.from_matrices(A, E, C)


def test_from_matrices_offsets_and_known_inputs():
    B_u = np.array([[0.0], [1.0], [0.0]])
    uio = LinearUIO.from_matrices(A, B, C, B_u=B_u, system_options={"v_bounds": (-1.0, 1.0)})
    traj = simulate(uio.system, [1.0, 0.0, 0.0], 30, u=np.sin(np.arange(30.0))[:, None], w=UNKNOWN_INPUTS["ramp"][:30])
    result = uio.run(traj.u, traj.y, x0_prior=np.zeros(3))
    assert np.abs(result.error(traj.x))[25:].max() < 1e-6
    # an affine system: x+ = A x + B w + c, y = C x + v + d
    x, u, w, v = ca.SX.sym("x", 3), ca.SX.sym("u", 0), ca.SX.sym("w", 1), ca.SX.sym("v", 1)
    c, d = ca.DM([0.3, -0.1, 0.2]), 1.5
    affine = System.from_expressions(x, u, w, v, ca.DM(A) @ x + ca.DM(B) @ w + c, ca.DM(C) @ x + v + d)
    traj = simulate(affine, [1.0, -1.0, 0.5], 40, w=UNKNOWN_INPUTS["constant 1e6"][:40])
    result = LinearUIO(affine, x0_prior=np.zeros(3)).run(None, traj.y)
    assert np.abs(result.error(traj.x))[35:].max() < 1e-6 and np.abs(result.w_hat - traj.w)[35:].max() < 1e-6


def test_streaming_missing_data_and_bad_input():
    traj = simulate(SYSTEM, [1.0, -1.0, 0.5], 20, w=np.sin(np.arange(20.0))[:, None])
    uio = LinearUIO(SYSTEM, x0_prior=np.zeros(3))
    result = uio.run(None, traj.y)
    assert isinstance(result, EstimationResult)
    uio.reset()
    for k in range(21):
        step = uio.step(None, traj.y[k])
        np.testing.assert_array_equal(step.x_hat, result.x_hat[k])
    y = traj.y.copy()
    y[0] = np.nan
    y[8] = np.nan
    gap = uio.run(None, y)
    np.testing.assert_array_equal(gap.missing[:, 0], np.isnan(y[:, 0]))
    assert np.all(np.isfinite(gap.x_hat)) and np.abs(gap.error(traj.x))[19:].max() < 1e-2  # recovers with F
    with pytest.raises(OptionError, match="x0_prior: required"):
        LinearUIO(SYSTEM).step(None, [0.0])
    with pytest.raises(DataError, match="x0_prior: expected shape"):
        uio.reset([0.0])
    with pytest.raises(DataError, match=r"y: expected shape \(K\+1, 1\)"):
        uio.run(None, np.zeros(5))
    with pytest.raises(DataError, match=r"u: expected shape \(K, 0\)"):
        uio.run(np.zeros((4, 1)), np.zeros((5, 1)))
    with pytest.raises(DataError, match="v_prior"):
        LinearUIO(SYSTEM, v_prior=[1.0])
    assert "LinearUIO(" in repr(uio)
