"""Scales from data where X's width is no scale (uiest.scales), and where each scale came from (ScaleSource)."""

import dataclasses

import numpy as np
import pytest

from uiest import DataError, System, simulate
from uiest.box import Box
from uiest.estimators import UISE, UISEWeights
from uiest.models import get, linear
from uiest.scales import ROUNDING, WIDE_DOMAIN, data_scales, state_peaks
from uiest.signal import ScaleSource, Signal

A = np.array([[0.8, 0.3, 0.0], [-0.2, 0.7, 0.4], [0.1, -0.3, 0.6]])
B, C = np.array([[1.0], [0.0], [0.5]]), np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


def wide(**spec):
    """A stable 3-state linear system (x2 unmoved by w from 0: the input's direction is invariant), y = (x1, x2)."""
    return linear.linear_system(A, B, C, v_bounds=(-1e-3, 1e-3), **{"x_bounds": (-1e9, 1e9), **spec})


def test_each_scale_says_where_it_came_from():
    system = System.from_callables(
        lambda x, u, w: [0.5 * x[0] + w[0], 0.5 * x[1] + u[0]], lambda x, v: [x[0] + x[1] + v[0]],
        nx=2, nu=1, nw=1, nv=1, x_bounds=((-1.0, -np.inf), (1.0, np.inf)), v_bounds=(-0.1, 0.1), u_scale=3.0,
    )  # fmt: skip
    assert system.x.scale_source == (ScaleSource.WIDTH, ScaleSource.UNIT) and system.x.scale.tolist() == [2.0, 1.0]
    assert system.u.scale_source == (ScaleSource.GIVEN,) and system.w.scale_source == (ScaleSource.UNIT,)
    assert system.y.scale_source == (ScaleSource.OUTPUT,) and system.v.scale_source == (ScaleSource.WIDTH,)
    known = linear.linear_system(A, B, C, x_bounds=(-5, 5), w_range=(-2.0, 2.0), y_bounds=(-np.inf, np.inf))
    assert known.w.scale.tolist() == [4.0] and known.w.scale_source == (ScaleSource.WIDTH,)
    # a Signal built with its scales has them from the user; with_scales marks data and explicit scales
    assert Signal("x", ("a",), ("",), Box.unbounded(1), [2.0]).scale_source == (ScaleSource.GIVEN,)
    traj = simulate(system, [0.5, 0.0], 20, u=np.zeros((20, 1)), w=np.full((20, 1), 0.1))
    moved = system.with_scales(traj)
    assert moved.x.scale_source == (ScaleSource.DATA, ScaleSource.UNIT)  # x2 stays 0 throughout: kept
    assert moved.with_scales(x=[1.0, 2.0]).x.scale_source == (ScaleSource.GIVEN, ScaleSource.GIVEN)


def test_a_domain_meant_as_unbounded_gets_the_magnitudes_of_the_prior_and_a_short_simulation():
    system = wide()
    assert system.x.scale.tolist() == [2e9] * 3 and system.y.scale.tolist() == [2e9] * 2
    scaled = data_scales(system, np.zeros(3))
    peaks = state_peaks(system, np.zeros(3))
    assert peaks[1] <= ROUNDING * peaks.max()  # x2 is moved by rounding only: it takes the largest magnitude
    np.testing.assert_array_equal(scaled.x.scale, [peaks[0], peaks.max(), peaks[2]])
    assert np.all((scaled.x.scale > 0.1) & (scaled.x.scale < 10)) and set(scaled.x.scale_source) == {ScaleSource.DATA}
    # the output scales derived from X's widths are derived again, at the prior, from the new state scales
    np.testing.assert_allclose(scaled.y.scale, np.sqrt(scaled.x.scale[:2] ** 2 + 2e-3**2))
    assert scaled.y.scale_source == (ScaleSource.DATA, ScaleSource.DATA)
    assert scaled.v.scale.tolist() == system.v.scale.tolist() and scaled.x.bounds == system.x.bounds
    assert data_scales(scaled, np.zeros(3)) is scaled  # data scales are never replaced again
    # a prior larger than the simulation's magnitudes is the magnitude
    np.testing.assert_array_equal(data_scales(system, [300.0, -200.0, 100.0]).x.scale[:2], [300.0, 200.0])
    unbounded = wide(x_bounds=None)
    assert unbounded.x.scale_source == (ScaleSource.UNIT,) * 3
    np.testing.assert_array_equal(data_scales(unbounded, np.zeros(3)).x.scale, scaled.x.scale)


def test_scales_the_user_gave_and_widths_of_the_signals_order_are_kept():
    for system in (wide(x_scale=1e9), wide(x_bounds=(-10.0, 10.0)), wide(x_bounds=(-10.0, 10.0), y_scale=5.0)):
        assert data_scales(system, np.zeros(3)) is system
    # the rule: a width above WIDE_DOMAIN times the magnitude
    magnitude = data_scales(wide(), np.zeros(3)).x.scale
    for factor, source in ((0.5, ScaleSource.WIDTH), (2.0, ScaleSource.DATA)):
        half = factor * WIDE_DOMAIN * magnitude / 2
        assert set(data_scales(wide(x_bounds=(-half, half)), np.zeros(3)).x.scale_source) == {source}
    # the crop model and the closed-form model: X is of the signal's order, no scale changes, no simulation
    for name in ("crop-growth", "closed-form"):
        entry = get(name)
        model = entry.build()
        assert data_scales(model, entry.setup().x0) is model
        assert data_scales(model, model.x.bounds.center) is model


@pytest.mark.filterwarnings("ignore:design. the chosen guarantee is not informative")
@pytest.mark.slow
def test_the_closed_form_design_keeps_its_system_and_certificate_bit_for_bit():
    entry = get("closed-form")
    system = entry.build()
    designed = UISE.design(system, x0_prior=entry.setup().x0, rates=(0.5,), trials=1, steps=40)
    assert designed.system is system and designed.design_report.certificate.system is system


def test_the_measured_outputs_give_the_output_scales():
    system = wide()
    rng = np.random.default_rng(0)
    record = simulate(system, [1.0, -1.0, 2.0], 60, w=(5 * rng.standard_normal(60))[:, None])
    y = record.y.copy()
    y[3, 0] = np.nan  # a missing sample is ignored
    measured = data_scales(system, np.zeros(3), record=dataclasses.replace(record, y=y))
    np.testing.assert_array_equal(measured.y.scale, np.nanmax(np.abs(y), axis=0))
    np.testing.assert_array_equal(measured.x.scale, data_scales(system, np.zeros(3)).x.scale)  # states: not from y
    # an output scale from Y's width is replaced by the measured magnitude under the same rule
    boxed = wide(y_bounds=(-1e9, 1e9))
    assert boxed.y.scale_source == (ScaleSource.WIDTH,) * 2
    np.testing.assert_array_equal(data_scales(boxed, np.zeros(3), record=record).y.scale, np.abs(record.y).max(axis=0))


def test_a_bad_prior_is_refused_by_name():
    with pytest.raises(DataError, match=r"x0_prior: expected shape \(3,\)"):
        data_scales(wide(), np.zeros(2))
    with pytest.raises(DataError, match="x0_prior: expected finite values"):
        UISE(wide(), weights=UISEWeights.from_scales(wide(), 0.5), N=3, x0_prior=[0.0, np.nan, 0.0])


def test_a_simulation_that_escapes_x_does_not_set_the_scales():
    # the Henon map in X = +-1e6: excited by w up to its unit scale it escapes (1e5 on its way out), on its attractor
    # it stays below 1.3; the escape's peaks once kept x1's scale at X's width and UISE.design refused the weights
    henon = System.from_callables(lambda x, u, w: [1.0 - 1.4 * x[0] ** 2 + x[1] + w[0], 0.3 * x[0]],
                                  lambda x, v: [x[0] + v[0]], nx=2, nw=1, nv=1, x_bounds=(-1e6, 1e6),
                                  v_bounds=(-1e-3, 1e-3))  # fmt: skip
    scaled = data_scales(henon, [0.0, 0.0])
    np.testing.assert_allclose(scaled.x.scale, [1.264, 0.378], rtol=1e-3)
    designed = UISE.design(henon, x0_prior=[0.0, 0.0], trials=1, steps=60)
    assert designed.guarantee.informative


def test_without_a_record_the_known_input_over_u_moves_the_states_it_drives():
    # a DC motor (current, speed), voltage in U = +-24 V, the load torque unknown: from rest with the voltage at U's
    # centre (0 V) the current barely moves (3.5e-3 A, mostly through the load), and its width of 40 A was taken for
    # "no scale" and replaced; the voltage drawn over U drives it to amperes, as the record's voltage does
    def rhs(x, u, w):
        return [(u[0] - x[0] - 0.01 * x[1]) / 0.5, (0.01 * x[0] - 0.1 * x[1] - w[0]) / 0.01]

    spec = {"x_bounds": ((-20.0, -50.0), (20.0, 50.0)), "u_bounds": (-24.0, 24.0), "v_bounds": (-0.01, 0.01)}
    motor = System.from_ode(rhs, lambda x, v: [x[1] + v[0]], nx=2, nu=1, nw=1, nv=1, dt=0.01, **spec)
    peaks = state_peaks(motor, np.zeros(2))
    assert peaks[0] > 1.0  # amperes: the excited run's voltage
    kept = data_scales(motor, np.zeros(2))
    assert kept is motor and kept.x.scale_source == (ScaleSource.WIDTH, ScaleSource.WIDTH)
    record = simulate(motor, np.zeros(2), 60, u=np.full((60, 1), 12.0), w=np.zeros((60, 1)))
    assert data_scales(motor, np.zeros(2), record=record) is motor  # the record's voltage: the same decision
