"""Strong-detectability certificates (theo:Lyapunov) against known answers."""

import numpy as np
import pytest

from uiest import CertificationError, OptionError
from uiest.detectability import certify_strong_detectability, linear_strong_detectability
from uiest.models import closed_form, linear

LINEAR_SPEC = {"x_bounds": (-10.0, 10.0), "v_bounds": (-1e-3, 1e-3)}


@pytest.mark.parametrize(
    ("zeros", "kwargs"),
    [
        ([0.5, 0.2], {}),
        ([0.3 + 0.4j, 0.3 - 0.4j, -0.7], {}),
        ([0.6, 0.1], {"nw": 2, "extra_outputs": 1}),
    ],
)
def test_linear_mu_min_is_largest_zero_squared(zeros, kwargs):
    system, A, B, C = linear.with_invariant_zeros(zeros, seed=3, **kwargs, **LINEAR_SPEC)
    cert = certify_strong_detectability(system, grid=2, pool_grid=2, pool_random=10)
    expected = max(abs(z) for z in zeros) ** 2
    assert cert.certified, cert.reason
    assert cert.mu_min == pytest.approx(expected, abs=1e-3)
    # the nonlinear certificate's linear special case agrees with the Hautus test
    assert cert.mu_min == pytest.approx(linear_strong_detectability(A, B, C).mu_min, abs=1e-3)
    assert cert.mu > cert.mu_min
    report = cert.verify(5000, seed=1)
    assert report.pairs_used > 20 and report.holds, report


def test_zero_outside_unit_disk_is_not_certified():
    system, *_ = linear.with_invariant_zeros([1.5], seed=3, **LINEAR_SPEC)
    cert = certify_strong_detectability(system, grid=2, pool_grid=2, pool_random=10)
    assert not cert.certified
    assert "infeasible" in cert.reason
    with pytest.raises(CertificationError):
        cert.min_horizon()


def test_matching_failure_is_not_certified_at_any_mu():
    # w enters x2, only x1 is measured: C B = 0 while B != 0
    A = np.array([[0.5, 1.0], [0.0, 0.3]])
    system = linear.linear_system(A, [[0.0], [1.0]], [[1.0, 0.0]], **LINEAR_SPEC)
    cert = certify_strong_detectability(system, grid=2, pool_grid=2, pool_random=10)
    assert not cert.certified and "rank" in cert.reason


def test_contractive_nonlinear_system_certifies_with_its_rate():
    # closed-form model: x2+ = a(x1) x2 + u with a in [0.2, 0.8] -> mu* = 0.8^2 = 0.64
    system = closed_form.system()
    cert = certify_strong_detectability(system)
    assert cert.certified, cert.reason
    assert cert.mu_min == pytest.approx(0.64, abs=5e-3)
    assert cert.verify(20_000, seed=2).holds


def test_given_mu_and_horizon():
    system, *_ = linear.with_invariant_zeros([0.5, 0.2], seed=3, **LINEAR_SPEC)
    cert = certify_strong_detectability(system, mu=0.48, grid=2, pool_grid=2, pool_random=10)
    assert cert.certified and cert.mu == 0.48
    n = cert.min_horizon()
    assert 8 * cert.mu**n * cert.condition < 1 <= 8 * cert.mu ** (n - 1) * cert.condition
    low = certify_strong_detectability(system, mu=0.2, grid=2, pool_grid=2, pool_random=10)
    assert not low.certified and "below" in low.reason
    with pytest.raises(OptionError, match="mu"):
        certify_strong_detectability(system, mu=1.5)


def test_certificate_serialises():
    import json

    system = closed_form.system()
    cert = certify_strong_detectability(system, grid=2, pool_grid=3, pool_random=50)
    data = json.loads(json.dumps(cert.to_dict()))
    assert data["certified"] is cert.certified and data["kind"] == "strong_detectability"
