"""Guarantees in the user's units: the Guarantee object, each estimator's bound, and what the CLI says of them."""

import dataclasses
import pickle
import warnings

import numpy as np
import pytest

from uiest import System, simulate
from uiest.detectability import certify_delta_ioss, certify_reduced_model, certify_strong_detectability
from uiest.estimators import EKF, FIE, UISE, DelayedUISE, Guarantee, LinearUIO, StandardMHE, TwoStageUISE, Verdict
from uiest.estimators.bounds import SETTLED, box_quadratic_max, strong_bound
from uiest.experiments import crop_growth_study
from uiest.models import closed_form, linear
from uiest.reduction import ReducedModel


def _tank(bound):
    return Guarantee(theorem="UISE theorem (theo:MHE_full)", applies=True, x_width=[24.0, 24.0], names=("h1", "h2"),
                     units=("cm", "cm"), error_bound=bound, settling_steps=12)  # fmt: skip


def test_the_text_follows_the_numbers():
    vacuous = _tank([31015.0, 3.0])
    assert vacuous.verdict is Verdict.VACUOUS and not vacuous.informative and vacuous.applies
    assert vacuous.informative_states.tolist() == [False, True] and vacuous.vacuous_states.tolist() == [True, False]
    expected = "holds but vacuous: bound 31015 cm > X's width 24 cm for h1; informative for h2 3 cm after 12 steps"
    assert vacuous.text == expected
    informative = _tank([3e-3, 0.5])
    assert informative.verdict is Verdict.INFORMATIVE and informative.informative
    assert str(informative) == "holds, bound h1 0.003 cm, h2 0.5 cm after 12 steps (informative)"
    partial = _tank([3e-3, np.nan])
    assert partial.verdict is Verdict.PARTIAL and not partial.informative
    assert str(partial) == "holds, bound h1 0.003 cm after 12 steps (informative there); no bound for h2: "
    none = Guarantee.none("UISE theorem (theo:MHE_full)", "N=2 < min_horizon()=18", [24.0], ("h",), ("cm",))
    assert none.verdict is Verdict.NONE and str(none) == "none: N=2 < min_horizon()=18" and not none.informative
    unbounded = Guarantee(
        theorem="x",
        applies=True,
        x_width=[np.inf],
        names=("h",),
        units=("cm",),
        error_bound=[np.inf],
        bound_note="V is unbounded",
    )
    assert unbounded.verdict is Verdict.NO_BOUND and str(unbounded) == "holds, no finite bound: V is unbounded"
    wide = Guarantee(
        theorem="x", applies=True, x_width=[np.inf], names=("h",), units=("cm",), error_bound=[5.0], settling_steps=None
    )
    assert wide.informative and str(wide) == "holds, bound 5 cm once the initial error has decayed (informative)"
    for g in (vacuous, none, partial):  # the words never claim without the numbers
        assert "applies" not in str(g) and "guaranteed" not in str(g)
        back = pickle.loads(pickle.dumps(g))
        assert back.text == g.text and back.to_dict()["verdict"] == g.verdict.value


def test_box_quadratic_maximum_is_at_a_vertex():
    W = np.array([[2.0, -1.0], [-1.0, 1.0]])
    assert box_quadratic_max(W, np.array([-1.0, -2.0]), np.array([1.0, 3.0])) == pytest.approx(17.0)  # at (-1, 3)
    assert box_quadratic_max(W, np.array([-np.inf, 0.0]), np.array([1.0, 0.0])) == np.inf
    big = np.eye(14)  # beyond the vertex limit: the triangle inequality's upper bound
    assert box_quadratic_max(big, -np.ones(14), np.ones(14)) >= 14.0


def test_the_uise_bound_is_the_proofs_formula():
    # theo:MHE_full: V_k <= 8 lam^k V_0 + 32 s_v / (lam (1 - lam)), lam = 8^(1/N) mu; |e_i| <= sqrt(V (P^-1)_ii)
    P, R_v = np.array([[4.0, 1.0], [1.0, 2.0]]), np.array([[3.0]])
    V = linear.linear_system(np.eye(2) * 0.5, [[1.0], [0.0]], [[1.0, 0.0]], x_bounds=(-1, 1),
                             v_bounds=(-0.1, 0.2)).v.bounds  # fmt: skip
    bound, settling = strong_bound(P, R_v, 0.5, 10, V, np.zeros(1), np.array([2.0, 2.0]))
    lam = 8**0.1 * 0.5
    settled = 32 * 3.0 * 0.2**2 / (lam * (1 - lam))  # the largest |v - v_bar| is 0.2
    np.testing.assert_allclose(bound, SETTLED * np.sqrt(settled * np.diag(np.linalg.inv(P))))
    initial = max(e @ P @ e for e in np.array([[2, 2], [2, -2], [-2, 2], [-2, -2]], dtype=float))
    assert 8 * lam**settling * initial <= (SETTLED**2 - 1) * settled < 8 * lam ** (settling - 1) * initial
    fie, _ = strong_bound(P, R_v, 0.5, None, V, np.zeros(1), np.array([2.0, 2.0]))  # lem:FIE: 16 s_v / (mu (1 - mu))
    np.testing.assert_allclose(fie, SETTLED * np.sqrt(16 * 3.0 * 0.04 / 0.25 * np.diag(np.linalg.inv(P))))
    assert np.all(np.isinf(strong_bound(P, R_v, 0.9, 1, V, np.zeros(1), np.array([2.0, 2.0]))[0]))  # 8 mu >= 1


@pytest.mark.slow
def test_crop_certified_uise_holds_but_is_vacuous_in_kg_per_m2():
    from uiest.experiments.runner import BUILDERS
    from uiest.experiments.study_model import StudyModel

    study = StudyModel.of("crop-growth")
    (spec,) = [s for s in crop_growth_study().estimators if s.name == "UISE (certified)"]
    uise = BUILDERS["uise"](study, spec, study.setup.x0, "gn")  # the study's certified UISE
    g = uise.guarantee
    assert g.applies and not g.informative and g.verdict is Verdict.VACUOUS
    assert g.units == ("kg/m^3", "kg/m^2", "kg/m^2") and np.all(g.vacuous_states)
    assert np.all(g.error_bound > 100 * g.x_width)  # the bound of x_d1 is hundreds of kg/m^2 on X's 0.02 kg/m^2
    assert str(g).startswith("holds but vacuous: bound ") and "kg/m^2 > X's width 0.02 kg/m^2 for x_d1" in str(g)
    assert 'guarantee="holds but vacuous: bound' in repr(uise)


def test_closed_form_certified_uise_is_informative():
    system = closed_form.system()
    g = UISE(system, certificate=certify_strong_detectability(system)).guarantee
    assert g.applies and g.informative and g.verdict is Verdict.INFORMATIVE
    assert str(g).startswith("holds, bound x1 ") and str(g).endswith("(informative)") and g.settling_steps > 0
    assert np.all(g.error_bound < g.x_width)


def _zeros_system():
    return linear.with_invariant_zeros([0.5, 0.2], seed=1, x_bounds=(-10, 10), v_bounds=(-1e-3, 2e-3))[0]


def _extreme_noise(rng, system, K):
    V = system.v.bounds
    return np.where(rng.random((K + 1, system.nv)) < 0.5, V.lower, V.upper)


def test_a_linear_uise_bound_is_informative_and_holds_on_noise_at_the_extremes_of_v():
    system = _zeros_system()
    uise = UISE(system, certificate=certify_strong_detectability(system), x0_prior=np.zeros(3))
    g = uise.guarantee
    assert g.informative and g.settling_steps is not None
    rng = np.random.default_rng(0)
    for _ in range(2):  # the true state stays in X (the theorem's constraint); any unknown input
        truth = simulate(system, rng.uniform(-3, 3, 3), 80, w=lambda k, x: [-0.3 * x[0] + 0.5 * np.sin(k)],
                         v=_extreme_noise(rng, system, 80))  # fmt: skip
        assert truth.x_outside.sum() == 0
        error = np.abs(uise.run(None, truth.y).x_hat - truth.x)[g.settling_steps :]
        assert np.all(error <= g.error_bound)


def test_the_linear_uio_bound_is_the_simulated_worst_case():
    system = _zeros_system()
    uio = LinearUIO(system, x0_prior=np.zeros(3))
    g = uio.guarantee
    assert g.applies and g.informative
    K = 120
    lo, hi = system.v.bounds.lower - uio.v_prior, system.v.bounds.upper - uio.v_prior
    G = [uio.H @ uio.D] + [np.linalg.matrix_power(uio.F, m - 1) @ uio.K @ uio.D for m in range(1, K + 1)]
    for i in range(system.nx):  # noise at V's extremes, each sample on the side that moves state i's error most
        worst = 0.0
        for sign in (1.0, -1.0):
            v = np.array([np.where(sign * G[K - k][i] > 0, hi, lo) for k in range(K + 1)]) + uio.v_prior
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # the unknown input takes x out of X; the UIO has no constraint
                truth = simulate(system, np.zeros(3), K, w=lambda k, x: [50 * np.sin(k)], v=v)
            worst = max(worst, abs(uio.run(None, truth.y).x_hat[K, i] - truth.x[K, i]))
        assert worst == pytest.approx(g.error_bound[i] / SETTLED, rel=1e-9)  # exact: the limit is attained
    rng = np.random.default_rng(1)
    for _ in range(5):  # from an initial error up to X's width, whatever the unknown input
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # a ramp leaves X, as above
            truth = simulate(system, rng.choice([-9.9, 9.9], 3), 200, w=lambda k, x: [1e3 * k],
                             v=_extreme_noise(rng, system, 200))  # fmt: skip
        result = uio.run(None, truth.y)
        assert np.all(np.abs(result.x_hat - truth.x)[g.settling_steps :] <= g.error_bound)
    back = pickle.loads(pickle.dumps(result))  # the result holds the object, and pickles with it
    assert back.guarantee.text == result.guarantee.text == g.text and back.to_pandas().equals(result.to_pandas())


def test_an_fie_stopping_below_its_certificates_horizon_has_no_guarantee(monkeypatch):
    A, B, C = np.array([[0.6, 0.2], [0.0, 0.5]]), [[1.0], [0.5]], [[1.0, 0.0]]
    system = linear.linear_system(A, B, C, x_bounds=(-10, 10), v_bounds=(-0.01, 0.01), w_range=(-0.5, 0.5))
    cert = certify_strong_detectability(system)
    monkeypatch.setattr(type(cert), "min_horizon", lambda self: 50)
    fie = FIE(system, certificate=cert, x0_prior=np.zeros(2))
    assert fie.N == 13 and not fie.guarantee.applies
    assert str(fie.guarantee).startswith("none: its window stops growing at N=13, below min_horizon()=50")


def test_the_fie_the_standard_mhe_and_the_filters():
    A, B, C = np.array([[0.6, 0.2], [0.0, 0.5]]), [[1.0], [0.5]], [[1.0, 0.0]]
    system = linear.linear_system(A, B, C, x_bounds=(-10, 10), v_bounds=(-0.01, 0.01), w_range=(-0.5, 0.5))
    fie = FIE(system, certificate=certify_strong_detectability(system), x0_prior=np.zeros(2))
    # mu = 0.177: the window stops growing at 13 transitions, and from there the FIE is the UISE with N = 13
    assert fie.N == 13 and fie.guarantee.grows and fie.guarantee.informative
    assert "Theorem 3.6 of Guo et al." in fie.guarantee.theorem
    delta = certify_delta_ioss(system)
    mhe = StandardMHE(system, certificate=delta, N=10, x0_prior=np.zeros(2))
    g = mhe.guarantee
    assert g.applies and np.all(np.isfinite(g.error_bound)) and "[-0.5], upper=[0.5]" in g.assumes
    assert str(g).startswith("holds while w in [-0.5, 0.5]")  # its condition in the text, not only in assumes
    rng = np.random.default_rng(2)
    for estimator in (fie, mhe):
        bound, settling = estimator.guarantee.error_bound, estimator.guarantee.settling_steps
        truth = simulate(system, rng.uniform(-3, 3, 2), 40, w=np.where(rng.random((40, 1)) < 0.5, -0.5, 0.5),
                         v=_extreme_noise(rng, system, 40))  # fmt: skip
        assert np.all(np.abs(estimator.run(None, truth.y).x_hat - truth.x)[settling:] <= bound)
    free = linear.linear_system(A, B, C, x_bounds=(-10, 10), v_bounds=(-0.01, 0.01))  # no known range of w
    unknown = StandardMHE(free, certificate=delta, N=10).guarantee
    assert unknown.applies and unknown.error_bound is not None  # the certificate's own range of w bounds it
    ekf = EKF(system, w_variance=1.0).guarantee
    assert not ekf.applies and ekf.error_bound is None and str(ekf).startswith("none: the EKF assumes")


def test_the_two_stage_bound_is_per_state_and_nan_where_the_map_is_nonlinear():
    reduced = closed_form.reduction()
    two_stage = TwoStageUISE(reduced, certificate=certify_reduced_model(reduced))
    g = two_stage.guarantee
    # x1 = y - v: its error is v_bar - v, at most 0.01, at every step; x2 carries theo:stab's loose bound
    assert g.error_bound[0] == pytest.approx(SETTLED * 0.01) and g.informative_states.tolist()[0]
    assert g.vacuous_states.tolist() == [False, True] and "for x2; informative for x1 0.011" in str(g)
    # x2 > 0 is reduced to z = log x2: its state is exp(z_sharp), not affine in it, so it gets no bound (an output
    # nonlinear in v would make the map nonlinear too, but then the reduced certificate is not proved)
    logs = ReducedModel.from_maps(
        System.from_callables(
            lambda x, u, w: [x[0] + 0.5 * np.sin(x[1]) + w[0], 0.5 * x[1] + u[0]], lambda x, v: [x[0] + v[0]],
            nx=2, nu=1, nw=1, nv=1, x_bounds=((-10, 0.1), (10, 10)), u_bounds=(0.1, 1.0), v_bounds=(-0.01, 0.01)),
        lambda x: [x[0], np.log(x[1])], lambda z: [z[0], np.exp(z[1])], lambda y, z, v: [y[0] - v[0]], n_flat=1,
    )  # fmt: skip
    g = TwoStageUISE(logs, certificate=certify_reduced_model(logs)).guarantee
    assert g.applies and np.isfinite(g.error_bound[0]) and np.isnan(g.error_bound[1])
    assert "no bound for x[1]: x depends nonlinearly on (z_sharp, v)" in str(g) and g.verdict is not Verdict.NONE
    exact = TwoStageUISE(reduced, certificate=certify_reduced_model(reduced), projection="exact").guarantee
    assert np.all(np.isnan(exact.error_bound)) and "exact projection" in exact.bound_note


def test_the_delayed_uise_bounds_the_states_b_alone_determines():
    from uiest.delay import delayed_system

    # w drives x1, only x2 = x1[k-1] is measured; x3 is an independent stable state seen through y2
    A = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 0.5]])
    C = [[0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    system = linear.linear_system(A, [[1.0], [0.0], [0.0]], C, x_bounds=(-10, 10), v_bounds=(-1e-3, 1e-3))
    delayed = delayed_system(system)
    cert = certify_strong_detectability(delayed.system)
    g = DelayedUISE(system, certificate=cert).guarantee
    free = np.abs(delayed.M_a).max(axis=1) == 0
    assert g.applies and free.tolist() == [False, True, True]
    assert np.isnan(g.error_bound[0]) and np.all(np.isfinite(g.error_bound[1:]))
    assert "no bound for x[0]: these states depend on a = T_a x" in str(g)
    assert "; it bounds x_hat[k], not the lagged estimates x[k-lag]" in g.assumes


def test_a_run_with_an_outage_suspends_its_guarantee_and_says_until_when():
    # the missing-data guide's outage: the run's guarantee once said "holds" while x1's error reached 73 times its
    # bound after the gap; the bound assumes every output measured
    system = closed_form.system(x_bounds=((-100.0, -10.0), (100.0, 10.0)))
    truth = simulate(system, [0.5, 1.0], 90, u=np.zeros(1), w=lambda k, x: [-0.5 * x[0] + np.sin(0.2 * k)])
    y = truth.y.copy()
    y[20:60] = np.nan
    uise = UISE(system, certificate=certify_strong_detectability(system), x0_prior=[0.0, 0.0])
    settling = uise.guarantee.settling_steps
    result = uise.run(truth.u, y)
    run = result.guarantee
    assert run.suspended == (20, 59) and run.resumes == 59 + uise.N + 1 + settling and run.run_steps == 91
    assert run.applies and run.to_dict()["suspended"] == [20, 59]
    assert "at k = 20..59" in run.text and f"again from k = {run.resumes}, after the run's end (k = 90)" in run.text
    full = uise.run(truth.u, truth.y).guarantee
    assert full.suspended is None and full.text == uise.guarantee.text  # settles within the run: nothing to add
    short = uise.run(truth.u[:10], truth.y[:11]).guarantee
    assert short.text.endswith("The run ends at k = 10, before the bound applies") and settling > 10
    assert UISE(system, weights=uise.weights, N=5, x0_prior=[0.0, 0.0]).run(truth.u, y).guarantee.suspended is None


def test_a_runs_suspension_says_how_many_steps_and_a_growing_window_does_not_resume():
    tank = _tank([3e-3, 0.5])  # settles after 12 steps; no window (an observer's)
    broken = np.zeros(91, dtype=bool)
    broken[[2, 80]] = True  # two single missing outputs, not an outage from 2 to 80
    run = tank.for_run(broken)
    assert run.suspended == (2, 80) and run.suspended_steps == 2 and run.resumes == 80 + 1 + 12
    assert "at 2 steps from k = 2 to 80, and the bound assumes every output measured, every window solved" in run.text
    assert "it applies again from k = 93, after the run's end (k = 90)" in run.text
    assert run.verdict is Verdict.INFORMATIVE  # the flags stay the estimator's; the text says what the run did
    assert run.for_study().text == tank.for_run(np.zeros(91, dtype=bool)).text == tank.text
    growing = dataclasses.replace(tank, grows=True, horizon=None)  # the FIE without N keeps the missing outputs
    fie = growing.for_run(broken)
    assert fie.resumes is None and fie.text.endswith(
        "it does not apply again (the growing window keeps the steps that broke it)"
    )
    assert Guarantee.none("x", "no certificate", [24.0], ("h",), ("cm",)).for_run(broken).suspended is None


def test_an_estimate_the_data_put_beyond_xs_side_suspends_the_guarantee_after_the_settling():
    # beyond X's side with the output missed by more than 10 noise bounds: the true state may have left X (a record
    # whose truth went to 250 against X = +-20 said "applies again"); before the settling steps it is the transient
    # from a wrong prior that the bound allows (a correct run was once suspended at k = 0)
    from uiest.estimators.base import _breaks_assumptions

    y = np.array([[0.0], [np.nan], [0.0], [0.0]])
    assert _breaks_assumptions(["solved", "solved", "failed", "solved"], y).tolist() == [False, True, True, False]
    tank = _tank([3e-3, 0.5])  # settles after 12 steps
    outside = np.zeros(40, dtype=bool)
    outside[3] = True
    assert tank.for_run(np.zeros(40, dtype=bool), outside=outside).suspended is None
    outside[20] = True
    late = tank.for_run(np.zeros(40, dtype=bool), outside=outside)
    assert late.suspended == (20, 20) and "the data put the estimate beyond X's side at k = 20" in late.text
