"""Step health as data: outcomes, the solver's status, fallbacks, estimates at X's sides and their warning."""

import pickle
import re
import warnings

import numpy as np
import pandas as pd
import pytest
from failing_solver import FailingSolver
from typer.testing import CliRunner

from uiest import BoundWarning, simulate
from uiest.cli import app
from uiest.estimators import EKF, UISE, EstimationResult, Guarantee, Outcome, UISEWeights
from uiest.estimators import base as base_module
from uiest.health import AT_BOUND_RTOL, BoundTest, at_bound, status_text
from uiest.models import closed_form, linear
from uiest.window import gauss_newton

K = 200
WIDE = 50.0


def _linear(x2_bound):
    # x1+ = 0.8 x1 + w, x2+ = 0.5 x1 + 0.6 x2, y = x1 + v: x2 is seen only through x1's history; |x2| reaches ~6
    A = np.array([[0.8, 0.0], [0.5, 0.6]])
    return linear.linear_system(A, [[1.0], [0.0]], [[1.0, 0.0]], x_bounds=((-WIDE, -x2_bound), (WIDE, x2_bound)),
                                v_bounds=(-0.01, 0.01), name="linear")  # fmt: skip


def _closed_form(x1_bound):
    # x1+ = x1 + 0.5 sin(x2) + w, y = x1 + v: the measured x1 follows the unknown input to |x1| ~ 5
    return closed_form.system(x_bounds=((-x1_bound, -WIDE), (x1_bound, WIDE)))


MODELS = {
    "linear": (_linear, 1, None, lambda k: 2.0 * np.sin(0.05 * k)),
    "closed-form": (_closed_form, 0, lambda k: 0.5 * np.sin(0.1 * k), lambda k: 0.5 * np.sin(0.1 * k)),
}


def _record(model):
    make, _, u_law, w_law = MODELS[model]
    k = np.arange(K)
    u = None if u_law is None else u_law(k)[:, None]
    noise = np.random.default_rng(0).uniform(-0.01, 0.01, (K + 1, 1))
    return simulate(make(WIDE), [0.0, 0.0], K, u=u, w=w_law(k)[:, None], v=noise)


def _estimator(kind, system):
    if kind == "UISE":
        return UISE(system, weights=UISEWeights.from_scales(system, 0.6), N=10, x0_prior=[0.0, 0.0])
    return EKF(system, w_variance=0.1, x0_prior=[0.0, 0.0])


@pytest.mark.parametrize("kind", ["UISE", "EKF"])
@pytest.mark.parametrize("model", list(MODELS))
def test_a_too_narrow_x_reports_at_bound_steps_and_warns_and_a_wide_one_does_not(model, kind):
    make, state, _, _ = MODELS[model]
    truth = _record(model)
    assert np.abs(truth.x[:, state]).max() > 3.0  # beyond the narrow X's side at 1
    u = truth.u if truth.u.shape[1] else None
    with warnings.catch_warnings():
        warnings.simplefilter("error", BoundWarning)
        wide = _estimator(kind, make(WIDE)).run(u, truth.y)
    assert wide.at_bound_steps.tolist() == [0, 0] and wide.counts()["at_bound"] == 0 and wide.failures == 0
    name = make(1.0).x.names[state]
    pattern = (
        rf"{kind}: the estimate of {re.escape(name)} at or beyond X's (lower|upper) side -?1( and upper side 1)? in"
    )
    with pytest.warns(BoundWarning, match=pattern + r" \d+ of 201 steps") as caught:
        narrow = _estimator(kind, make(1.0)).run(u, truth.y)
    message = str(caught[0].message)
    assert "physical limit" in message and "the estimate is wrong there" in message
    assert ("keeps its estimates in X" in message) == (kind == "UISE")  # the filters' estimates may leave X
    beyond = np.abs(truth.x[:, state]) >= 1.0
    counts = narrow.counts()
    assert counts["at_bound"] == counts[f"at_bound_{name}"] == narrow.at_bound_steps[state] > 0.05 * (K + 1)
    assert narrow.at_bound_steps[1 - state] == 0
    # every estimate the side holds is where the truth lies beyond it (past the first window, for the UISE)
    assert narrow.at_bound[beyond, state][20:].mean() > 0.9
    assert f"at a side of X: {name}" in narrow.status[np.argmax(narrow.at_bound[:, state])]
    frame = narrow.to_pandas()
    assert frame[f"{name}_at_bound"].sum() == narrow.at_bound_steps[state]


def test_a_state_on_a_side_that_holds_it_is_at_bound_within_the_relative_tolerance():
    from uiest import Box

    box = Box([0.0, -np.inf, 2.0], [10.0, 1.0, 2.0])  # a half-open axis and a fixed one
    scale = np.array([1.0, 4.0, 1.0])
    x = np.array([[0.0, 1.0, 2.0], [10.0 * (1 - AT_BOUND_RTOL / 2), 1.0 - 3 * AT_BOUND_RTOL, 2.0],
                  [-1.0, 2.0, 2.0], [1e-3, -1e9, 2.0]])  # fmt: skip
    expected = [[True, True, False], [True, True, False], [True, True, False], [False, False, False]]
    np.testing.assert_array_equal(at_bound(box, x, scale), expected)
    test = BoundTest(box, scale)  # the thresholds computed once, for a test repeated every step
    np.testing.assert_array_equal(test(x), expected)
    np.testing.assert_array_equal(test(x[1]), expected[1])


def test_a_failed_solve_is_counted_with_the_solvers_status(monkeypatch):
    system = _linear(WIDE)
    truth = _record("linear")
    ref = []
    real = base_module.make_solver
    monkeypatch.setattr(base_module, "make_solver", lambda *a, **kw: FailingSolver(real(*a, **kw), ref, {30, 31, 90}))
    estimator = _estimator("UISE", system)
    ref.append(estimator)
    result = estimator.run(None, truth.y)
    failed = np.flatnonzero(result.outcome == Outcome.FAILED).tolist()
    assert failed == [30, 31, 90] and result.failures == result.counts()["failures"] == 3
    assert set(result.solver_status[failed]) == {"Injected_Failure"} and not result.success[failed].any()
    assert result.status[30] == "failed (Injected_Failure)" and result.fallbacks == 0
    assert set(result.outcome[np.arange(K + 1) >= 1]) == {Outcome.SOLVED, Outcome.FAILED}


def test_a_gauss_newton_window_handed_to_ipopt_is_counted_from_its_field(monkeypatch):
    system = _linear(WIDE)
    truth = _record("linear")
    real_step = gauss_newton.GaussNewtonSolver._step
    step_of = {"k": -1}

    def qp_fails_at_some_steps(self, point, damping, warm):  # every QP of the steps 50 .. 54 fails
        return None if 50 <= step_of["k"] <= 54 else real_step(self, point, damping, warm)

    monkeypatch.setattr(gauss_newton.GaussNewtonSolver, "_step", qp_fails_at_some_steps)
    estimator = _estimator("UISE", system)
    estimator.reset([0.0, 0.0])
    steps = []
    for k in range(K + 1):
        step_of["k"] = k
        steps.append(estimator.step(None if k == 0 else np.zeros(0), truth.y[k]))
    assert [s.k for s in steps if s.fallback] == [50, 51, 52, 53, 54]
    handed = steps[50]
    assert handed.outcome == Outcome.SOLVED and handed.primary_status == "gn QP_failed"
    assert handed.solver_status == "Solve_Succeeded"
    assert handed.status == "solved (gn QP_failed -> ipopt Solve_Succeeded)"
    result = estimator.run(None, truth.y)  # the same through a run: no QP fails any more (k stays at K)
    assert result.fallbacks == 0 and result.counts()["fallbacks"] == 0


@pytest.mark.slow
def test_the_solver_bench_counts_fallbacks_from_the_field(monkeypatch):
    from uiest.experiments.solver_bench import bench_window_solvers

    monkeypatch.setattr(gauss_newton.GaussNewtonSolver, "_step", lambda self, point, damping, warm: None)
    records = bench_window_solvers(horizons=(3,), estimators=("standard MHE",), long_horizon=10)
    gn = next(r for r in records if r["solver"] == "gn")
    assert gn["fallbacks"] == 300 and gn["failures"] == 0  # every solve, k = 1 .. 300 (k = 0 is the prior)
    assert next(r for r in records if r["solver"] == "ipopt")["fallbacks"] == 0


def test_a_result_keeps_its_health_fields_through_pickle_and_parquet(tmp_path):
    truth = _record("linear")
    with pytest.warns(BoundWarning):
        result = _estimator("UISE", _linear(1.0)).run(None, truth.y)
    copy = pickle.loads(pickle.dumps(result))
    for name in ("outcome", "at_bound", "solver_status", "fallback", "held_input", "on_boundary", "window_at_bound"):
        np.testing.assert_array_equal(getattr(copy, name), getattr(result, name))
    assert not copy.at_bound.flags.writeable and copy.counts() == result.counts()
    frame = result.to_pandas()
    frame.to_parquet(tmp_path / "steps.parquet")
    back = pd.read_parquet(tmp_path / "steps.parquet")
    assert back["outcome"].tolist() == result.outcome.tolist() and back["status"].tolist() == result.status.tolist()
    assert back["x[1]_at_bound"].sum() == result.at_bound_steps[1]


def test_the_status_line_is_derived_from_the_fields():
    assert status_text(Outcome.PROPAGATED) == "propagated (no data)"
    assert status_text("updated", evaluated_inside=True).startswith("updated; the model evaluated inside X")
    line = status_text(Outcome.SOLVED, solver_status="Converged", held_input=True, at_bound_names=("x1",),
                       on_boundary=True)  # fmt: skip
    assert line.startswith("solved (Converged); y[k] misses outputs") and "; at a side of X: x1; held there" in line
    fields = dict(t=np.arange(2.0), x_hat=np.zeros((2, 1)), w_hat=np.zeros((1, 1)), iterations=[0, 0],
                  solve_time=[0.0, 0.0], cost=[0.0, 0.0], window=[0, 0], missing=np.zeros((2, 1), bool),
                  estimator="test", horizon=None,
                  guarantee=Guarantee.none("test", "none", np.ones(1), ("x",), ("",)))  # fmt: skip
    result = EstimationResult(outcome=["prior", "error"], reason=["", "ValueError: x"], **fields)
    assert result.status.tolist() == ["prior", "error (ValueError: x)"] and result.failures == 1
    from uiest import DataError

    with pytest.raises(DataError, match="outcome: expected"):
        EstimationResult(outcome=["prior", "propagated (no data)"], **fields)
    with pytest.raises(DataError, match=r"guarantee: expected a uiest\.guarantee\.Guarantee, got str"):
        EstimationResult(outcome=["prior", "error"], **{**fields, "guarantee": "none"})


@pytest.mark.slow
def test_the_cli_counts_the_steps_and_shows_the_bound_warning_as_a_message(tmp_path):
    model = tmp_path / "narrow.py"
    model.write_text(
        "import numpy as np\n"
        "from uiest.models import linear\n"
        "system = linear.linear_system(np.array([[0.8, 0.0], [0.5, 0.6]]), [[1.0], [0.0]], [[1.0, 0.0]],\n"
        "                              x_bounds=((-50, -1), (50, 1)), v_bounds=(-0.01, 0.01), name='narrow')\n"
    )
    data = tmp_path / "data.csv"
    _record("linear").to_pandas().to_csv(data)
    out = tmp_path / "out"
    result = CliRunner().invoke(app, ["estimate", str(model), "--data", str(data), "--estimator", "uise",
                                      "--estimator", "ekf", "--w-variance", "0.1", "--out", str(out)])  # fmt: skip
    assert result.exit_code == 0, result.output
    text = " ".join(result.output.split())
    assert "warning: UISE: the estimate of x[1] at or beyond X's lower side -1 and upper side 1" in text
    assert "warning: EKF: the estimate of x[1]" in text and "BoundWarning" not in text and "warnings.warn" not in text
    frame = pd.read_csv(out / "estimates_uise.csv")
    assert frame["x[1]_at_bound"].sum() > 0.05 * len(frame) and {"outcome", "fallback", "held_input"} <= set(frame)


@pytest.mark.parametrize("kind", ["EKF", "LinearUIO"])
def test_filters_and_observers_update_and_propagate_without_data(kind):
    from uiest.estimators import LinearUIO

    system = _linear(WIDE)
    y = _record("linear").y.copy()
    y[50:53] = np.nan
    estimator = _estimator("EKF", system) if kind == "EKF" else LinearUIO(system, x0_prior=[0.0, 0.0])
    result = estimator.run(None, y)
    assert np.flatnonzero(result.outcome == Outcome.PROPAGATED).tolist() == [50, 51, 52]
    assert set(np.delete(result.outcome, [50, 51, 52])) == {Outcome.UPDATED}
    assert result.propagated_steps == result.counts()["propagated"] == 3 and result.failures == 0
    assert result.solver_status.tolist() == [""] * (K + 1) and not result.fallback.any()
