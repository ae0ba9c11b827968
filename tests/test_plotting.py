"""Figures: shapes checked, files written."""

import numpy as np
import pytest

from uiest import DataError, simulate
from uiest.estimators import UISE, UISEWeights
from uiest.models import closed_form
from uiest.plotting import plot_estimates, save_figure


def test_plot_estimates_writes_a_figure_and_checks_lengths(tmp_path):
    system = closed_form.system()
    truth = simulate(system, [0.5, 1.0], 12, u=np.zeros(1), w=lambda k, x: [0.1 * k])
    weights = UISEWeights.from_scales(system, 0.5)
    result = UISE(system, weights=weights, N=4, x0_prior=[0.0, 0.0]).run(truth.u, truth.y)
    fig = plot_estimates(truth, {"UISE": result})
    assert len(fig.axes) == 2 * (system.nx + system.nw)
    path = save_figure(fig, tmp_path / "estimates.png")
    assert path.stat().st_size > 10_000
    short = simulate(system, [0.5, 1.0], 5, u=np.zeros(1), w=np.zeros((5, 1)))
    with pytest.raises(DataError, match="UISE"):
        plot_estimates(short, {"UISE": result})
