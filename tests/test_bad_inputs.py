"""Every bad input of tests/bad_inputs.py gets a typed error naming the argument, or a recorded status."""

import contextlib
import tempfile
from pathlib import Path

import numpy as np
import pytest
from bad_inputs import api_cases, classify, cli_cases, system, uise
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from uiest import DataError, OptionError, UiestError, simulate
from uiest.cli import app
from uiest.experiments import Scenario, executors
from uiest.experiments.sweep import Sweep

TMP = Path(tempfile.mkdtemp(prefix="uiest-bad-inputs-"))
API = api_cases(TMP)
CLI = cli_cases(TMP)


@pytest.mark.parametrize("case", API, ids=[c.name for c in API])
def test_api_bad_input(case):
    verdict, detail = classify(case)
    assert verdict in ("good", "handled"), detail
    assert verdict == ("good" if case.error is not None else "handled"), detail


@pytest.mark.parametrize("case", CLI, ids=[c.name for c in CLI])
def test_cli_bad_input(case, monkeypatch):
    monkeypatch.setattr(executors, "SCHEDULER_TIMEOUT", 1.0)  # a scheduler that is not there: 1 s, not 10, of waiting
    result = CliRunner().invoke(app, list(case.args))
    text = result.output + (result.stderr if result.stderr_bytes is not None else "")
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(result.exception)
    assert "Traceback" not in text
    assert result.exit_code == case.code, text
    assert case.match in text, text


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    st.lists(st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=2), st.none()), max_size=4),
    st.integers(-3, 12),
)
def test_simulate_random_inputs_give_a_trajectory_or_a_typed_error(x0, steps):
    try:
        traj = simulate(system(), x0, steps, u=np.zeros(1))
    except UiestError:
        return
    assert traj.x.shape == (steps + 1, 2)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.integers(0, 6), st.integers(0, 3), st.sampled_from([0.0, np.nan, np.inf, 1e300, -5.0]))
def test_runs_on_random_measurements_give_a_result_or_a_typed_error(rows, cols, value):
    y = np.full((rows, cols), value)
    try:
        result = uise().run(np.zeros((max(rows - 1, 0), 1)), y)
    except DataError:
        return
    assert result.x_hat.shape == (rows, 2) and np.all(np.isfinite(result.x_hat))


@settings(max_examples=80, deadline=None)
@given(
    st.dictionaries(
        st.sampled_from(["runs", "steps", "seed", "settle", "focus_state", "noise_scale", "w_gain"]),
        st.one_of(st.integers(-5, 20), st.floats(allow_nan=True), st.text(max_size=2), st.booleans()),
    )
)
def test_random_scenario_fields_give_a_scenario_or_an_option_error(fields):
    data = {"name": "x", "model": "closed-form", "estimators": [{"name": "u", "kind": "uise"}], **fields}
    with contextlib.suppress(OptionError):
        Scenario.from_dict(data)


@settings(max_examples=80, deadline=None)
@given(
    st.sampled_from(["N", "mu", "output_weight", "noise_scale", "w_gain", "steps", "solver", "estimator"]),
    st.lists(st.one_of(st.integers(-3, 40), st.floats(allow_nan=True), st.text(max_size=3), st.booleans()), max_size=3),
)
def test_random_sweep_grids_give_a_sweep_or_an_option_error(name, values):
    base = Scenario.from_dict(
        {"name": "x", "model": "closed-form", "steps": 20, "settle": 2, "estimators": [{"name": "u", "kind": "uise"}]}
    )
    try:
        design = Sweep(base, grid={name: tuple(values)})
    except OptionError:
        return
    applied = [point[name] for point in design.points()]  # every accepted value as given, never rounded
    assert applied == list(values) and design.grid[name] == tuple(values)
    if name in ("N", "steps"):
        assert all(type(value) is int for value in applied)
