import math

import numpy as np
import pytest
import scipy.linalg
from scipy.optimize import linear_sum_assignment

from uiest.detectability.linear import LinearStrongDetectability, invariant_zeros, linear_strong_detectability
from uiest.errors import ModelError, OptionError
from uiest.models.linear import with_invariant_zeros


def assert_same_multiset(actual, expected, atol):
    """The complex numbers agree one to one (optimal assignment) within atol."""
    actual, expected = np.asarray(actual, dtype=complex), np.asarray(expected, dtype=complex)
    assert actual.shape == expected.shape, (actual, expected)
    if actual.size:
        dist = np.abs(actual[:, None] - expected[None, :])
        rows, cols = linear_sum_assignment(dist)
        assert dist[rows, cols].max() <= atol, (actual, expected)


def unobservable_modes(C, A1):
    """Eigenvalues of A1 restricted to the null space of the observability matrix of (C, A1)."""
    n = A1.shape[0]
    obs = np.vstack([C @ np.linalg.matrix_power(A1, k) for k in range(n)])
    _, s, vt = np.linalg.svd(obs)
    rank = int(np.sum(s > 1e-8 * s[0]))
    W = vt[rank:].T
    return np.linalg.eigvals(W.T @ A1 @ W)


def square_pencil_zeros(A, B, C):
    """Finite generalised eigenvalues of the square pencil (M, N), infinite ones (|z| > 1e8) dropped."""
    n, q = B.shape
    M = np.block([[A, B], [-C, np.zeros((C.shape[0], q))]])
    N = np.zeros_like(M)
    N[:n, :n] = np.eye(n)
    vals = scipy.linalg.eigvals(M, N)
    return vals[np.isfinite(vals) & (np.abs(vals) < 1e8)]


KNOWN = [
    pytest.param([0.5, 0.2], {}, id="real"),
    pytest.param([0.3 + 0.4j, 0.3 - 0.4j, -0.7], {}, id="complex-pair"),
    pytest.param([0.9, -0.6, 0.3 + 0.5j, 0.3 - 0.5j, 0.1], {"seed": 5}, id="several"),
    pytest.param([0.4, 0.1], {"nw": 2, "extra_outputs": 1}, id="non-square"),
    pytest.param([0.8, -0.5, 0.0], {"nw": 2}, id="square-nw2"),
    pytest.param([0.6, 0.6], {"nw": 1, "extra_outputs": 2}, id="double-non-square"),
]


@pytest.mark.parametrize(("zeros", "kwargs"), KNOWN)
def test_known_zeros_are_found_and_certified(zeros, kwargs):
    _, A, B, C = with_invariant_zeros(zeros, **kwargs)
    res = linear_strong_detectability(A, B, C)
    assert isinstance(res, LinearStrongDetectability)
    assert_same_multiset(res.invariant_zeros, zeros, atol=1e-8)
    moduli = np.abs(res.invariant_zeros)
    assert np.all(np.diff(moduli) <= 1e-12), "sorted by decreasing modulus"
    assert res.matching and res.rank_B == res.rank_CB == B.shape[1]
    assert res.strongly_detectable
    assert res.mu_min == pytest.approx(max(abs(z) for z in zeros) ** 2, abs=1e-10)
    n, p = C.shape[1], C.shape[0]
    assert res.observer_gain is not None and res.observer_gain.shape == (n, p)
    assert res.spectral_radius is not None and res.spectral_radius < 1.0
    closed = res.error_matrix - res.observer_gain @ C
    assert np.max(np.abs(np.linalg.eigvals(closed))) == pytest.approx(res.spectral_radius)
    eig_e = np.linalg.eigvals(res.error_matrix)
    for z in zeros:
        assert np.min(np.abs(eig_e - z)) < 1e-6
    assert "strongly detectable" in res.reason and "not" not in res.reason


@pytest.mark.parametrize(("zeros", "kwargs"), KNOWN)
def test_paper_construction(zeros, kwargs):
    _, A, B, C = with_invariant_zeros(zeros, **kwargs)
    res = linear_strong_detectability(A, B, C)
    Bt, Y = res.B_tilde, res.Y
    np.testing.assert_allclose(Bt.T @ Bt, np.eye(res.rank_B), atol=1e-12)
    np.testing.assert_allclose(Bt @ Bt.T @ B, B, atol=1e-12)  # range(B_tilde) = range(B)
    np.testing.assert_allclose(Y @ C @ Bt, np.eye(res.rank_B), atol=1e-10)  # left inverse
    np.testing.assert_allclose(res.error_matrix, A - Bt @ Y @ C @ A, atol=1e-12)
    # e+ = (I - B_tilde Y C)(A e + B dw): the unknown-input difference dw drops out
    np.testing.assert_allclose((np.eye(A.shape[0]) - Bt @ Y @ C) @ B, 0.0, atol=1e-10)


@pytest.mark.parametrize(("zeros", "kwargs"), KNOWN)
def test_zeros_equal_unobservable_modes_of_reduced_pair(zeros, kwargs):
    _, A, B, C = with_invariant_zeros(zeros, **kwargs)
    res = linear_strong_detectability(A, B, C)
    assert_same_multiset(res.invariant_zeros, unobservable_modes(C, res.error_matrix), atol=1e-6)


def test_random_matching_systems_cross_check_with_unobservable_modes():
    rng = np.random.default_rng(11)
    for n, q, p in [(4, 1, 1), (5, 2, 3), (6, 2, 2), (3, 1, 2)]:
        A, B, C = rng.standard_normal((n, n)), rng.standard_normal((n, q)), rng.standard_normal((p, n))
        res = linear_strong_detectability(A, B, C)
        assert res.matching
        assert len(res.invariant_zeros) == n - q if p == q else len(res.invariant_zeros) == 0
        assert_same_multiset(res.invariant_zeros, unobservable_modes(C, res.error_matrix), atol=1e-6)


def test_random_square_pencils_cross_check_with_generalized_eigenvalues():
    rng = np.random.default_rng(7)
    for n, m in [(3, 1), (5, 2), (6, 3), (4, 4), (2, 1)]:
        A, B, C = rng.standard_normal((n, n)), rng.standard_normal((n, m)), rng.standard_normal((m, n))
        expected = square_pencil_zeros(A, B, C)
        assert len(expected) == n - m
        zeros = invariant_zeros(A, B, C)
        assert_same_multiset(zeros, expected, atol=1e-8 * (1 + np.max(np.abs(expected), initial=0.0)))


def test_jordan_block_zero_counts_multiplicity():
    rng = np.random.default_rng(2)
    A = np.zeros((4, 4))
    A[0, 0], A[0, 1:], A[1:, 0] = 0.2, 1.0, [1.0, 0.0, 1.0]
    A[1:, 1:] = [[0.5, 1.0, 0.0], [0.0, 0.5, 1.0], [0.0, 0.0, 0.5]]
    B, C = np.eye(4)[:, :1], np.eye(4)[:1]
    Q, _ = np.linalg.qr(rng.standard_normal((4, 4)))
    zeros = invariant_zeros(Q @ A @ Q.T, Q @ B, C @ Q.T)
    assert_same_multiset(zeros, [0.5, 0.5, 0.5], atol=1e-4)


@pytest.mark.parametrize("zeros", [[1.5], [0.5, -1.2, 0.1]])
def test_zero_outside_unit_disk_is_not_strongly_detectable(zeros):
    _, A, B, C = with_invariant_zeros(zeros, seed=4)
    res = linear_strong_detectability(A, B, C)
    big = max(zeros, key=abs)
    assert res.matching and not res.strongly_detectable
    assert res.mu_min == pytest.approx(big**2, abs=1e-10)
    assert res.observer_gain is None and res.spectral_radius is None
    assert res.error_matrix is not None  # matching holds: the error dynamics exist
    assert "not strongly detectable" in res.reason and f"{abs(big):.6g}" in res.reason


def test_matching_failure_with_rounding_in_cb():
    # Chain x1+ = 0.5 x1 + x2, x2+ = 0.3 x2 + x3, x3+ = -0.2 x3 + w, y = x1: C B = 0, which after a
    # rotation is only round-off (a rank relative to the largest singular value of CB would say 1).
    A = np.array([[0.5, 1.0, 0.0], [0.0, 0.3, 1.0], [0.0, 0.0, -0.2]])
    B, C = np.eye(3)[:, 2:], np.eye(3)[:1]
    Q, _ = np.linalg.qr(np.random.default_rng(0).standard_normal((3, 3)))
    At, Bt, Ct = Q @ A @ Q.T, Q @ B, C @ Q.T
    assert 0 < np.abs(Ct @ Bt).max() < 1e-14
    res = linear_strong_detectability(At, Bt, Ct)
    assert (res.matching, res.rank_B, res.rank_CB) == (False, 1, 0)
    assert not res.strongly_detectable and math.isinf(res.mu_min)
    assert res.Y is None and res.error_matrix is None and res.observer_gain is None
    assert res.spectral_radius is None and res.B_tilde.shape == (3, 1)
    assert res.invariant_zeros.size == 0  # relative degree 3, no zeros: matching alone decides
    assert "rank(CB) = 0 < rank(B) = 1" in res.reason and "matching" in res.reason


def test_candidates_are_confirmed_by_the_pencil_rank(monkeypatch):
    # A spurious value proposed by both compressions must be rejected by the singular-value check.
    import uiest.detectability.linear as mod

    original = mod._compressed_eigenvalues

    def with_spurious(M, N, r, rng):
        return np.append(original(M, N, r, rng), 0.123)

    monkeypatch.setattr(mod, "_compressed_eigenvalues", with_spurious)
    _, A, B, C = with_invariant_zeros([0.5, 0.2])
    assert_same_multiset(mod.invariant_zeros(A, B, C), [0.5, 0.2], atol=1e-8)


def test_zeros_of_non_square_pencil_without_matching():
    # Two inputs, one output: the input hides x2, x3 never reaches the output -> zero at 0.9.
    A = np.diag([0.5, 0.3, 0.9])
    B, C = np.eye(3)[:, :2], np.eye(3)[:1]
    res = linear_strong_detectability(A, B, C)
    assert not res.matching and (res.rank_B, res.rank_CB) == (2, 1)
    assert_same_multiset(res.invariant_zeros, [0.9], atol=1e-10)


@pytest.mark.parametrize("kind", ["identity-output", "no-hidden-states"])
def test_system_without_zeros_has_mu_zero(kind):
    if kind == "identity-output":
        rng = np.random.default_rng(0)
        A, B, C = rng.standard_normal((3, 3)), rng.standard_normal((3, 2)), np.eye(3)
    else:
        _, A, B, C = with_invariant_zeros([], nw=2)
    res = linear_strong_detectability(A, B, C)
    assert res.invariant_zeros.size == 0 and res.invariant_zeros.dtype == complex
    assert res.mu_min == 0.0 and res.strongly_detectable
    assert res.spectral_radius is not None and res.spectral_radius < 1.0
    assert "no invariant zeros" in res.reason


def test_rank_deficient_b_and_empty_inputs():
    _, A, B, C = with_invariant_zeros([0.4, -0.3], seed=2)
    res = linear_strong_detectability(A, np.hstack([B, 2.0 * B]), C)
    assert (res.rank_B, res.rank_CB, res.matching) == (1, 1, True) and res.B_tilde.shape == (3, 1)
    assert_same_multiset(res.invariant_zeros, [0.4, -0.3], atol=1e-8)
    # no unknown input: the zeros are the unobservable modes; no output either: the eigenvalues of A
    A0 = np.diag([0.5, 0.3, 0.9])
    assert_same_multiset(invariant_zeros(A0, np.zeros((3, 0)), np.eye(3)[:1]), [0.3, 0.9], atol=1e-10)
    res0 = linear_strong_detectability(A0, np.zeros((3, 0)), np.zeros((0, 3)))
    assert_same_multiset(res0.invariant_zeros, [0.5, 0.3, 0.9], atol=1e-10)
    assert res0.strongly_detectable and res0.observer_gain.shape == (3, 0)


def test_results_are_deterministic():
    _, A, B, C = with_invariant_zeros([0.3 + 0.4j, 0.3 - 0.4j, -0.7], nw=2, extra_outputs=1)
    np.testing.assert_array_equal(invariant_zeros(A, B, C), invariant_zeros(A, B, C))


@pytest.mark.parametrize(
    ("args", "name", "fragment"),
    [
        ((np.ones((2, 3)), np.ones((2, 1)), np.ones((1, 2))), "A", "(2, 3)"),
        ((np.eye(3), np.ones((2, 1)), np.ones((1, 3))), "B", "(2, 1)"),
        ((np.eye(3), np.ones((3, 1)), np.ones((1, 2))), "C", "(1, 2)"),
        ((np.eye(3), np.ones(3), np.ones((1, 3))), "B", "(3,)"),
        ((np.eye(3), np.ones((3, 1)), np.ones((1, 3, 1))), "C", "(1, 3, 1)"),
        ((np.diag([1.0, np.nan]), np.ones((2, 1)), np.ones((1, 2))), "A", "finite"),
        ((np.eye(2), np.ones((2, 1)) * 1j, np.ones((1, 2))), "B", "real"),
        ((np.zeros((0, 0)), np.zeros((0, 1)), np.zeros((1, 0))), "A", "(0, 0)"),
    ],
)
def test_bad_shapes_raise_model_error_naming_the_argument(args, name, fragment):
    for func in (linear_strong_detectability, invariant_zeros):
        with pytest.raises(ModelError, match=rf"^{name}: ") as info:
            func(*args)
        assert fragment in str(info.value)


def test_bad_rtol_raises_option_error():
    with pytest.raises(OptionError, match="rtol"):
        linear_strong_detectability(np.eye(2), np.ones((2, 1)), np.ones((1, 2)), rtol=0.0)


@pytest.mark.parametrize(("b_scale", "a_scale"), [(1.0, 1.0), (1e-3, 1.0), (1e3, 1.0), (1e6, 1e6)])
def test_sampling_zeros_of_a_sampled_triple_integrator_do_not_depend_on_the_input_scale(b_scale, a_scale):
    # y = x1, x1''' = w sampled with a zero-order hold: C (zI - A)^-1 B = dt^3 (z^2 + 4 z + 1) / (6 (z - 1)^3),
    # so its zeros are -2 +- sqrt(3) and the sampled system is not strongly detectable. CB = dt^3 / 6 is
    # ~2e-7 of |A| at dt = 0.01; with B a thousandth of that, the pencil's rank test once missed them all.
    dt = 0.01
    block = scipy.linalg.expm(np.block([[np.diag([1.0, 1.0], 1), np.eye(3)[:, [2]]], [np.zeros((1, 4))]]) * dt)
    A, B, C = a_scale * block[:3, :3], b_scale * block[:3, 3:], np.eye(3)[:1]  # A and B scaled: zeros scaled
    zeros = invariant_zeros(A, B, C) / a_scale
    np.testing.assert_allclose(np.sort(zeros.real), [-2.0 - math.sqrt(3.0), -2.0 + math.sqrt(3.0)], rtol=1e-5)
    np.testing.assert_allclose(zeros.imag, 0.0, atol=1e-8)
    cert = linear_strong_detectability(A, B, C)
    assert cert.matching and not cert.strongly_detectable and not cert.certified
    assert cert.rate_min == pytest.approx((a_scale * (2.0 + math.sqrt(3.0))) ** 2, rel=1e-5)
