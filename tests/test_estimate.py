"""Models of one's own (register, model files), measured records (from_pandas, CSV) and `uiest estimate`."""

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from uiest import DataError, ModelError, OptionError, System, simulate
from uiest.cli import RUN_DESIGNS_ITS_OWN, app
from uiest.estimate import build_estimator
from uiest.models import get, load, names, register
from uiest.models import linear as linear_models
from uiest.results import Trajectory, read_record

ROOT = Path(__file__).resolve().parents[1]
REACTOR = ROOT / "examples" / "reactor.py"
REACTOR_DATA = ROOT / "examples" / "data" / "reactor.csv"


def test_model_files_and_registration(tmp_path):
    entry = load(REACTOR)
    assert entry.name == "reactor" and "reactor" in names() and get("reactor") is entry
    system = entry.build()
    assert system.nx == 2 and system.x.names == ("c_A", "T") and system.dt == 0.05
    assert entry.simulation().steps == 400
    register("my-linear", linear_models.example, summary="mine")
    assert get("my-linear").build().nx == 3 and get("my-linear").setup is None
    with pytest.raises(OptionError, match="has no default simulation"):
        get("my-linear").simulation()
    with pytest.raises(OptionError, match="registered already"):
        register("my-linear", linear_models.example)
    bad = tmp_path / "bad.py"
    bad.write_text("x = 1\n")
    with pytest.raises(ModelError, match="defines neither `system`"):
        load(bad)
    with pytest.raises(OptionError, match="no model file"):
        load(tmp_path / "missing.py")
    raising = tmp_path / "raising.py"
    raising.write_text("def build():\n    raise ValueError('no')\n\ndef setup():\n    return {}\n")
    entry = load(raising)
    with pytest.raises(ModelError, match=r"build\(\) in .*raising.py raised ValueError: no"):
        entry.build()
    with pytest.raises(ModelError, match=r"setup\(\) in .*raising.py returned dict"):
        entry.simulation()
    with pytest.raises(OptionError, match="unknown name 'nope'"):
        load("nope")


def test_measured_records_round_trip_and_refuse_what_is_missing(tmp_path):
    entry = get("closed-form")
    system, setup = entry.build(), entry.setup()
    traj = simulate(system, setup.x0, 30, u=setup.u, w=setup.w, v=setup.noise, seed=2)
    path = tmp_path / "record.csv"
    traj.to_pandas().to_csv(path)
    record = read_record(path, system)
    np.testing.assert_array_equal(record.y, traj.y)
    np.testing.assert_array_equal(record.x, traj.x)
    measured = Trajectory.from_pandas(traj.to_pandas()[[*system.u.names, *system.y.names]], system)
    assert not measured.has_states and np.all(np.isnan(measured.x)) and measured.t[1] == system.dt
    frame = traj.to_pandas()
    with pytest.raises(DataError, match=r"missing y columns"):
        Trajectory.from_pandas(frame.drop(columns=[system.y.names[0]]), system)
    frame.loc[3, system.u.names[0]] = np.nan
    with pytest.raises(DataError, match="the known input u must be given at every k < K; row 3"):
        Trajectory.from_pandas(frame, system)
    shifted = traj.to_pandas()
    shifted["t"] = shifted["t"] * 2.0
    with pytest.raises(DataError, match="spaced by the model's dt"):
        Trajectory.from_pandas(shifted, system)
    with pytest.raises(DataError, match=r"expected a \.csv or \.parquet"):
        (tmp_path / "record.txt").write_text("t\n0\n")
        read_record(tmp_path / "record.txt", system)
    # a plant export: timestamps as text, a time column under another name, a comment column
    plant = traj.to_pandas()[["t", *system.u.names, *system.y.names]]
    stamped = plant.assign(t=pd.date_range("2026-01-01", periods=len(plant), freq="s").astype(str))
    with pytest.raises(DataError, match=r"frame\[t\]: expected numbers in the model's time unit .* convert timestamps"):
        Trajectory.from_pandas(stamped, system)
    with pytest.raises(DataError, match=r"a time column must be named 't'.*got 'time'"):
        Trajectory.from_pandas(plant.rename(columns={"t": "time"}).drop(index=5), system)
    with pytest.warns(UserWarning, match=r"columns \['comment'\] are not signals"):
        Trajectory.from_pandas(plant.assign(comment="ok"), system)


@pytest.mark.slow
def test_uiest_estimate_on_a_model_file_and_its_measurements(tmp_path):
    # the README's third command, with a second estimator and the lag
    out = tmp_path / "out"
    result = CliRunner().invoke(app, ["estimate", str(REACTOR), "--data", str(REACTOR_DATA), "--estimator", "uise",
                                      "--estimator", "ekf", "--lag", "2", "--out", str(out)])  # fmt: skip
    assert result.exit_code == 0, result.output
    uise = pd.read_csv(out / "estimates_uise.csv")
    truth = pd.read_csv(REACTOR_DATA)
    assert len(uise) == len(truth) == 401 and {"c_A_hat", "T_hat", "fault_hat", "status", "c_A_lag"} <= set(uise)
    assert np.sqrt(np.mean((uise["c_A_hat"] - truth["c_A"]) ** 2)) < 5e-3  # measured 8e-4
    assert (out / "estimates_ekf.csv").is_file() and (out / "estimates.png").stat().st_size > 10_000
    assert "likelihood's" in result.output and "interior" in result.output  # fitted to the data given
    assert "(from the model's setup()), the record's true x[0]" in " ".join(result.output.split())
    refused = CliRunner().invoke(app, ["estimate", str(REACTOR), "--data", str(REACTOR_DATA), "--estimator", "uise",
                                       "--estimator", "kf", "--out", str(out)])  # fmt: skip
    assert refused.exit_code == 2 and "--estimator: expected one of" in refused.output  # a name: refused at once
    # one the model does not admit among those asked for: "not run", and the others run (it ended the command)
    some = CliRunner().invoke(app, ["estimate", str(REACTOR), "--data", str(REACTOR_DATA), "--estimator", "uise",
                                    "--estimator", "uio", "--out", str(tmp_path / "some")])  # fmt: skip
    assert some.exit_code == 0 and "uio: not run (system: expected a linear" in " ".join(some.output.split())
    assert (tmp_path / "some" / "estimates_uise.csv").is_file()


def test_estimate_refuses_a_uise_without_matching_and_points_to_the_delayed_one():

    A = np.array([[1.0, 0, 0], [1.0, 0, 0], [0, 0, 0.5]])
    system = linear_models.linear_system(A, [[1.0], [0.0], [0.0]], [[0.0, 1.0, 0.0]], x_bounds=(-100, 100),
                                         v_bounds=(-0.05, 0.05))  # fmt: skip
    entry = register("chain-for-estimate", lambda: system, replace=True)
    with pytest.raises(ModelError, match=r"matching fails .* use --estimator delayed"):
        build_estimator("uise", entry, system, np.zeros(3))
    with pytest.raises(ModelError, match="has no reduction"):
        build_estimator("two-stage", entry, system, np.zeros(3))
    # an input no output ever sees: no pointer to the delayed UISE, which then refused too
    unseen = linear_models.linear_system(np.diag([0.8, 0.7]), [[1.0, 0.0], [0.0, 1.0]], [[1.0, 0.0]],
                                         x_bounds=(-100, 100), v_bounds=(-0.05, 0.05))  # fmt: skip
    entry = register("unseen-for-estimate", lambda: unseen, replace=True)
    with pytest.raises(ModelError, match=r"matching fails .* the delayed UISE does not apply either \("):
        build_estimator("uise", entry, unseen, np.zeros(2))


@pytest.mark.slow
def test_estimate_fits_the_mhe_where_its_certificate_is_vacuous_and_names_why_a_uise_has_none():

    from uiest.results import read_record

    entry = load(REACTOR)
    system = entry.build()
    x0 = np.asarray(entry.setup().x0)
    # the reactor's delta-IOSS certificate holds but bounds the error by 722 on X's width 1: weights by likelihood
    mhe, note = build_estimator("mhe", entry, system, x0, record=read_record(REACTOR_DATA, system))
    assert note.startswith("no informative delta-IOSS design (certified, but its guarantee is vacuous)")
    assert mhe.certificate is None and mhe.likelihood is not None
    # the reactor certifies, but not with a two-sample window: "no certified design", not "not certified", and the
    # hint names the CLI's flag, not the library's argument
    uise, note = build_estimator("uise", entry, system, x0, horizon=2)
    assert note.startswith("no certified design (certified, but with no window within --horizon 2: the shortest is ")
    assert "max_horizon" not in note and uise.N == 2 and not uise.guaranteed
    assert "admits it" in note
    short = Trajectory.from_pandas(read_record(REACTOR_DATA, system).to_pandas().iloc[:7], system)
    _, note = build_estimator("uise", entry, system, x0, horizon=2, record=short)  # a record of 6 samples
    assert ", longer than the record's 6 samples); explicit weights mu=0.8, N=2, no guarantee; output residuals" in note


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore:design. the chosen guarantee is not informative")
def test_the_default_horizon_limit_admits_a_certified_window_longer_than_30():
    # the quadruple tank's shortest certified window is 34: the default limit of 30 once fell back to uncertified
    # weights; without --horizon a window up to 60 is admitted where none of at most 30 certifies
    from uiest.estimate import DEFAULT_MAX_HORIZON, LONGEST_HORIZON, build_estimator

    entry = load(ROOT / "tests" / "quadruple_tank.py")
    system = entry.build()
    uise, note = build_estimator("uise", entry, system, np.asarray(entry.setup().x0))
    assert uise.guarantee.applies and DEFAULT_MAX_HORIZON < uise.N <= LONGEST_HORIZON
    assert not uise.guaranteed  # the bound is vacuous for h1, h3, h4 (the design warns)
    assert note == f"designed: mu={uise.weights.mu:.3g}, N={uise.N}, certified"
    assert uise.design_report.certificate.min_horizon() > DEFAULT_MAX_HORIZON


CHEN_PATTON_WIDE = """
import numpy as np
import scipy.linalg
from uiest.models import linear

A = np.array([[-1.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, -1.0, -1.0]])
E, C = np.array([[-1.0], [0.0], [0.0]]), np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
M = scipy.linalg.expm(np.block([[A, E], [np.zeros((1, 4))]]) * 0.1)
system = linear.linear_system(M[:3, :3], M[:3, 3:], C, x_bounds=(-1e9, 1e9), v_bounds=(-0.01, 0.01))
"""


@pytest.mark.slow
def test_estimate_on_a_model_whose_x_means_unbounded_takes_scales_from_the_data(tmp_path):
    # Chen-Patton with X = +-1e9 and no scales: with X's width as the scales the designed UISE erred by 10.2
    # (RMSE over the states; the UIO 0.10) and each estimator warned about the scales
    model = tmp_path / "chen_patton_wide.py"
    model.write_text(CHEN_PATTON_WIDE)
    system = load(model).build()
    rng = np.random.default_rng(0)
    w = (3 * np.sin(0.05 * np.arange(300)) + 50.0 * (np.arange(300) >= 150))[:, None]
    traj = simulate(system, [1.0, -1.0, 2.0], 300, w=w, v=rng.uniform(-0.01, 0.01, (301, 2)))
    data = tmp_path / "record.csv"
    traj.to_pandas().to_csv(data)
    out = tmp_path / "out"
    result = CliRunner().invoke(app, ["estimate", str(model), "--data", str(data), "--estimator", "uise",
                                      "--estimator", "uio", "--x0", "0,0,0", "--out", str(out)])  # fmt: skip
    assert result.exit_code == 0, result.output
    assert "scale" not in result.output, result.output
    assert "prior x[0]: x[0] 0, x[1] 0, x[2] 0 (from --x0)" in " ".join(result.output.split())
    columns = [f"x[{i}]_hat" for i in range(3)]
    rmse = {kind: np.sqrt(np.mean((pd.read_csv(out / f"estimates_{kind}.csv")[columns].to_numpy() - traj.x) ** 2))
            for kind in ("uise", "uio")}  # fmt: skip
    assert rmse["uise"] <= 1.2 * rmse["uio"], rmse


@pytest.mark.slow
def test_without_an_estimator_the_cli_runs_the_analysis_recommendation(tmp_path):
    # the reactor certifies with an informative bound: the UISE; a pendulum sampled every 0.05 s has a sampling zero
    # at -0.997: an estimator that assumes a smooth unknown input
    reactor = CliRunner().invoke(app, ["estimate", str(REACTOR), "--data", str(REACTOR_DATA), "--out",
                                       str(tmp_path / "reactor")], terminal_width=400)  # fmt: skip
    assert reactor.exit_code == 0, reactor.output
    assert reactor.output.startswith("recommended: uise: UISE: strong detectability is certified")
    assert RUN_DESIGNS_ITS_OWN in reactor.output  # the analysis's mu, N and bound are not the run's
    assert (tmp_path / "reactor" / "estimates_uise.csv").exists()
    pendulum = ROOT / "examples" / "pendulum.py"
    entry = load(pendulum)
    setup = entry.simulation()
    truth = simulate(entry.build(), setup.x0, 120, w=setup.w, v=setup.noise, seed=0)
    data = tmp_path / "pendulum.csv"
    truth.to_pandas().to_csv(data)
    result = CliRunner().invoke(app, ["estimate", str(pendulum), "--data", str(data), "--out",
                                      str(tmp_path / "pendulum")], terminal_width=400)  # fmt: skip
    assert result.exit_code == 0, result.output
    first = result.output.split("\n")[0]
    assert first.startswith("recommended: smooth: smooth-input MHE") and "created by sampling" in first
    estimates = pd.read_csv(tmp_path / "pendulum" / "estimates_smooth.csv")
    rate = truth.x[20:, 1] - estimates[f"{entry.build().x.names[1]}_hat"].to_numpy()[20:]
    assert np.sqrt(np.mean(rate**2)) < 0.1 * entry.build().x.bounds.width[1]


@pytest.mark.slow
def test_estimator_all_runs_every_estimator_the_model_admits(tmp_path):
    out, data = tmp_path / "all", tmp_path / "reactor.csv"
    data.write_text("".join(REACTOR_DATA.read_text().splitlines(keepends=True)[:121]))  # the first 120 samples
    result = CliRunner().invoke(app, ["estimate", str(REACTOR), "--data", str(data), "--estimator", "all",
                                      "--out", str(out)], terminal_width=400)  # fmt: skip
    assert result.exit_code == 0, result.output
    ran = {"uise", "mhe", "smooth", "ekf", "ukf"}
    assert {path.stem.removeprefix("estimates_") for path in out.glob("estimates_*.csv")} == ran
    assert (out / "estimates.png").exists() and len(list(out.glob("*.png"))) == 1
    for kind in ("delayed", "two-stage", "uio"):
        assert f"{kind}: not run (" in result.output
    # the standard MHE predicts x[k] from y[..k-1]: labelled, not ranked silently beside the filtered estimates
    assert result.output.count("(one step") == 1 and "mhe (one step" in result.output  # the table wraps its cells
    assert json.loads((out / "manifest.json").read_text())["one_step_ahead"] == ["mhe"]


@pytest.mark.slow
def test_build_all_builds_the_others_where_one_estimator_cannot_be_built_on_the_record():
    # two coupled logistic maps in X = +-1e4: from the default P0 (X's uniform variance) every UKF of the fit's grid
    # fails on this record; --estimator all once ended there, with nothing written
    from uiest import UniformNoise
    from uiest.estimate import build_all
    from uiest.models import ModelEntry

    def f(x, u, w):
        return [3.7 * x[0] * (1 - x[0]) + 0.05 * (x[1] - x[0]) + w[0], 3.7 * x[1] * (1 - x[1]) + 0.05 * (x[0] - x[1])]

    system = System.from_callables(f, lambda x, v: [x[0] + v[0]], nx=2, nw=1, nv=1, x_bounds=(-1e4, 1e4),
                                   v_bounds=(-1e-4, 1e-4), name="logistic")  # fmt: skip
    x0 = np.array([0.3, 0.6])
    record = simulate(system, x0, 60, w=lambda k, x: [0.01 * np.sin(0.2 * k)], v=UniformNoise.symmetric(1e-4), seed=0)
    entry = ModelEntry(name="logistic", summary="coupled logistic maps", build=lambda: system)
    built, _, skipped = build_all(entry, system, x0, horizon=10, record=record)
    assert "every filter of the grid" in skipped["ukf"] and "--x0" in skipped["ukf"]
    assert {"uise", "ekf"} <= set(built) and not set(built) & set(skipped)


@pytest.mark.parametrize("estimator", ["mhe", "smooth"])
@pytest.mark.slow
def test_a_lag_longer_than_the_default_window_lengthens_it_without_a_horizon(tmp_path, estimator):
    # without --horizon the windows hold x[k - lag] (the check allows lags below 60); a given horizon is kept
    entry = get("closed-form")
    setup = entry.simulation()
    truth = simulate(entry.build(), setup.x0, 60, u=setup.u, w=setup.w, v=setup.noise, seed=1)
    data = tmp_path / "data.csv"
    truth.to_pandas().to_csv(data)
    base = ["estimate", "closed-form", "--data", str(data), "--estimator", estimator, "--w-variance", "0.01"]
    result = CliRunner().invoke(app, [*base, "--lag", "35", "--out", str(tmp_path / "out")], terminal_width=300)
    assert result.exit_code == 0, result.output
    lagged = pd.read_csv(tmp_path / "out" / f"estimates_{estimator}.csv")
    assert np.isfinite(lagged["x1_lag"].to_numpy()[:25]).all()  # row j: x[j] from the window at j + 35
    refused = CliRunner().invoke(app, [*base, "--lag", "35", "--horizon", "20", "--out", str(tmp_path / "out2")])
    assert refused.exit_code == 2 and "--lag: expected an integer below the horizon (--horizon = 20)" in refused.output


def test_estimate_writes_a_manifest_of_its_record_and_removes_the_estimates_of_an_earlier_one(tmp_path):
    # the folder kept estimates_ukf.csv of another record beside the new estimates, and nothing named the record
    import hashlib
    import json

    out = tmp_path / "out"
    first = tmp_path / "closed_form.csv"
    entry = get("closed-form")
    setup = entry.simulation()
    simulate(entry.build(), setup.x0, 20, u=setup.u, w=setup.w, v=setup.noise, seed=1).to_pandas().to_csv(first)
    kinds = ["--estimator", "ekf", "--estimator", "ukf", "--w-variance", "0.01"]
    result = CliRunner().invoke(app, ["estimate", "closed-form", "--data", str(first), *kinds, "--out", str(out)])
    assert result.exit_code == 0, result.output
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["estimators"] == ["ekf", "ukf"] and manifest["model"] == {"name": "closed-form", "sha256": ""}
    assert list(manifest["weights"]) == ["ekf", "ukf"] and "random-walk variance 0.01" in manifest["weights"]["ekf"]
    assert manifest["files"] == ["estimates.png", "estimates_ekf.csv", "estimates_ukf.csv"]
    (out / "notes.txt").write_text("mine")
    model = tmp_path / "gain.py"
    model.write_text((Path(__file__).parent / "gain_model.py").read_text())
    gain = load(model)
    second = tmp_path / "gain.csv"
    simulate(gain.build(), [0.0, 1.0], 15, w=np.full((15, 1), 0.1)).to_pandas().to_csv(second)
    command = ["estimate", str(model), "--data", str(second), "--estimator", "ekf", "--w-variance", "0.01"]
    result = CliRunner().invoke(app, [*command, "--out", str(out)], terminal_width=300)
    assert result.exit_code == 0, result.output
    assert f"warning: out: removed estimates_ukf.csv from {out}: written by an earlier run" in result.stderr
    assert sorted(p.name for p in out.iterdir()) == ["estimates.png", "estimates_ekf.csv", "manifest.json", "notes.txt"]
    manifest = json.loads((out / "manifest.json").read_text())
    digest = {path: hashlib.sha256(path.read_bytes()).hexdigest() for path in (second, model)}
    assert manifest["data"] == {"path": str(second.resolve()), "sha256": digest[second]}
    assert manifest["model"] == {"name": str(model.resolve()), "sha256": digest[model]}
    assert manifest["estimators"] == ["ekf"] and manifest["files"] == ["estimates.png", "estimates_ekf.csv"]
    assert manifest["options"]["w_variance"] == 0.01 and manifest["code_version"]
    from uiest.estimate import write_estimates
    from uiest.estimators import EKF

    # written from Python without a manifest, the estimates of a third record leave no manifest of the second
    third = simulate(gain.build(), [0.0, 2.0], 10, w=np.full((10, 1), 0.2))
    estimator = EKF(gain.build(), x0_prior=[0.0, 1.0], w_variance=0.01)
    with pytest.warns(UserWarning, match="removed estimates_ekf.csv, manifest.json"):
        write_estimates(out, gain.build(), third, {"EKF": estimator.run(third.u, third.y)})
    assert sorted(p.name for p in out.iterdir()) == ["estimates.png", "estimates_EKF.csv", "notes.txt"]


def test_the_one_step_prediction_error_of_the_true_states_is_the_output_noise():
    from uiest.noise import UniformNoise
    from uiest.tuning import prediction_error

    # x[k+1] = f(x[k], u[k], w[k]): with the true states and the newest estimate w_hat[k-1] equal to the true w[k]
    # (the truth shifted by one step), y[k+1] - h(f(...)) is the noise v[k+1]
    system = linear_models.linear_system([[0.9, 0.2], [0.0, 0.7]], [[1.0], [0.5]], [[1.0, 0.0]], x_bounds=(-50, 50),
                                         v_bounds=(-0.1, 0.1))  # fmt: skip
    w = np.sin(0.3 * np.arange(80))[:, None]
    truth = simulate(system, [1.0, -1.0], 80, w=w, v=UniformNoise.symmetric(0.1), seed=2)
    newest = np.vstack([w[1:], [[np.nan]]])  # w_hat[k-1] = w[k]
    u = np.zeros((80, 0))
    error = prediction_error(system, truth.x, newest, u, truth.y)
    noise = truth.v[41:, 0] / system.y.scale[0]
    assert error == pytest.approx(np.sqrt(np.mean(noise**2)), rel=1e-12)
    assert prediction_error(system, truth.x, w, u, truth.y) > 1.5 * error  # w_hat[k] taken for w[k]: one step late
    # a missing output is left out; estimates that are not finite anywhere score inf
    y = truth.y.copy()
    y[60] = np.nan
    assert prediction_error(system, truth.x, newest, u, y) == pytest.approx(
        np.sqrt(np.mean(np.delete(noise, 60 - 41) ** 2)), rel=1e-12
    )
    assert prediction_error(system, np.full_like(truth.x, np.nan), newest, u, y) == np.inf


def test_another_discount_replaces_the_design_only_when_it_predicts_more_than_two_percent_better():
    from uiest.tuning import preferred_discount

    assert preferred_discount({0.8: 1.0, 0.95: 0.99, 0.99: 0.985}, 0.8) == 0.8  # within the scatter
    assert preferred_discount({0.8: 1.0, 0.95: 0.97, 0.99: 0.975}, 0.8) == 0.95
    assert (
        preferred_discount({0.8: 1.0, 0.95: np.inf}, 0.8) == 0.8
        and preferred_discount({0.8: np.inf, 0.95: 1.0}, 0.8) == 0.95
    )


def test_the_data_tuned_smooth_mhe_takes_the_discount_whose_run_predicts_the_outputs_best():

    from uiest.tuning import SMOOTH_DISCOUNTS, prediction_error, preferred_discount

    # the crop model's augmented model does not certify: from the exact prior the window prior is the EKF's settled
    # covariance on the data (per-window priors do not predict the record better), and the discount (0.8 by default)
    # is chosen among it, 0.95 and 0.99 by the one-step prediction error
    entry = get("crop-growth")
    system, setup = entry.build(), entry.simulation()
    record = simulate(system, setup.x0, 100, u=setup.u, w=setup.w, v=setup.noise, seed=1)
    smooth, note = build_estimator("smooth", entry, system, setup.x0, record=record)
    tried = _tried_discounts(note)
    design = next(iter(tried))
    assert list(tried)[1:] == list(SMOOTH_DISCOUNTS) and design < SMOOTH_DISCOUNTS[0]
    assert smooth.weights.eta == preferred_discount(tried, design) != design  # 0.95 or 0.99 predicts better here
    assert f"eta={smooth.weights.eta:.3g} (its one-step output prediction error" in note
    assert "window prior: the EKF's settled covariance of (x, w) on the data" in note and smooth.arrival_P is None
    result = smooth.run(record.u, record.y, x0_prior=setup.x0)  # the chosen estimator's own run scores as noted
    chosen = prediction_error(system, result.x_hat, result.w_hat, record.u, record.y)
    assert chosen == pytest.approx(tried[smooth.weights.eta], rel=1e-3)
    # on the closed-form model the three predict alike: the design's eta stays, and the note says why
    entry = get("closed-form")
    system, setup = entry.build(), entry.simulation()
    record = simulate(system, setup.x0, 100, u=setup.u, w=setup.w, v=setup.noise, seed=1)
    smooth, note = build_estimator("smooth", entry, system, setup.x0, record=record)
    tried = _tried_discounts(note)
    assert smooth.weights.eta == pytest.approx(next(iter(tried)), rel=1e-3) and next(iter(tried)) < SMOOTH_DISCOUNTS[0]
    assert "(the design's: no other eta's one-step output prediction error over the record's second half is" in note


def _tried_discounts(note):
    """The etas and prediction errors a data-tuned smooth MHE's note lists."""
    listed = note.split("; the errors in output scales: ")[1].split("), N=")[0]
    return {float(eta): float(error) for eta, error in (part[len("eta ") :].split(": ") for part in listed.split(", "))}


def test_a_design_eta_above_every_discount_tried_is_kept_without_a_trial_run():
    from types import SimpleNamespace

    from uiest.estimate import _smooth_discount

    system = get("closed-form").build()  # no run: the record is never read
    built = []
    chosen, why = _smooth_discount(system, lambda eta: built.append(eta) or SimpleNamespace(eta=eta), 0.995,
                                   np.zeros(2), None, None)  # fmt: skip
    eta = chosen.eta
    assert built == [0.995]
    assert eta == 0.995 and why == "the design's; none of 0.95, 0.99 is above it"


def test_the_prior_line_asks_for_x0_only_where_it_was_not_given():
    from types import SimpleNamespace

    from uiest.cli import _prior_text

    entry = get("closed-form")
    system = entry.build()
    x0 = np.asarray(entry.simulation().x0, dtype=float)
    record = SimpleNamespace(x=x0[None, :])  # the record's truth starts at the prior
    given, default = _prior_text(system, record, x0, "1,2", entry), _prior_text(system, record, x0, None, entry)
    assert "the record's true x[0]" in given and "give --x0" not in given and "(from --x0)" in given
    assert default.endswith("(give --x0)")


def test_an_estimator_that_fails_unexpectedly_is_named_and_the_others_still_run(tmp_path, monkeypatch):
    import uiest.cli

    def build(kind, *args, **kwargs):
        if kind == "ukf":
            raise ValueError("a defect")
        return build_estimator(kind, *args, **kwargs)

    monkeypatch.setattr(uiest.cli, "build_estimator", build)
    data = tmp_path / "closed_form.csv"
    setup = get("closed-form").simulation()
    simulate(get("closed-form").build(), setup.x0, 20, u=setup.u, w=setup.w, v=setup.noise, seed=1).to_pandas().to_csv(
        data
    )
    kinds = ["--estimator", "ekf", "--estimator", "ukf", "--w-variance", "0.01", "--out", str(tmp_path / "out")]
    result = CliRunner().invoke(app, ["estimate", "closed-form", "--data", str(data), *kinds], terminal_width=400)
    assert result.exit_code == 0, result.output
    assert "ukf: not run (internal error, please report it: ValueError: a defect)" in " ".join(result.output.split())
    assert (tmp_path / "out" / "estimates_ekf.csv").exists()


def test_the_fallback_uise_weighs_an_output_mismatch_by_the_noise_not_by_x_s_width():
    # I counted to +-100 on an X 1e7 wide: weighted by y's scale, a residual of 5e4 cost (5e-3)^2 and the SIR model's
    # fallback UISE put I at 0 for 199 of 200 steps (RMSE 6.2e5 persons; 94 with these weights)
    from uiest.estimate import fallback_weights

    system = linear_models.linear_system(np.array([[0.9, 0.2], [0.0, 0.5]]), [[1.0], [0.0]], [[1.0, 0.0]],
                                         x_bounds=(0.0, 1e7), v_bounds=(-100.0, 100.0))  # fmt: skip
    weights = fallback_weights(system)
    np.testing.assert_allclose(weights.R_y, [[12.0 / 200.0**2]])  # 1 / V's uniform variance
    assert weights.mu == 0.8 and weights.P[0, 0] == pytest.approx(1.0 / system.x.scale[0] ** 2)


@pytest.mark.slow
def test_the_fallback_uise_holds_an_output_to_its_noise_where_that_predicts_the_record_better():
    from uiest.estimate import build_estimator as build

    N, gamma, K = 1e7, 0.1, 200  # an epidemic: infected counted to +-100 persons, the contact rate unknown
    system = System.from_callables(
        lambda x, u, w: [x[0] - w[0] * x[0] * x[1] / N, x[1] + w[0] * x[0] * x[1] / N - gamma * x[1]],
        lambda x, v: [x[1] + v[0]], nx=2, nw=1, nv=1, x_bounds=((0.0, 0.0), (N, N)), v_bounds=(-100.0, 100.0),
        w_range=(0.0, 1.0), name="sir")  # fmt: skip
    beta = np.where(np.arange(K) < 60, 0.3, 0.18 + 0.002 * np.maximum(np.arange(K) - 120, 0))[:, None]
    truth = simulate(system, [N - 1.0, 1.0], K, w=beta, v=np.random.default_rng(3).uniform(-100, 100, (K + 1, 1)))
    register("sir-fallback", lambda: system)
    uise, note = build("uise", get("sir-fallback"), system, np.array([N / 2, N / 2]), record=truth)
    assert "explicit weights" in note and "output residuals weighted per noise" in note
    error = uise.run(None, truth.y, x0_prior=[N / 2, N / 2]).x_hat[50:, 1] - truth.x[50:, 1]
    assert np.sqrt(np.mean(error**2)) < 300.0  # per y's scale: I held at 0, RMSE 6e5


@pytest.mark.slow
def test_the_data_tuned_smooth_mhe_forgets_a_wrong_prior_as_fast_as_the_ekf():
    # a cart on a spring sampled at 10 ms, position measured, an unknown force; the prior a quarter of X's width off.
    # The window prior once weighed x[0] by the EKF's settled covariance from the first sample: 4.7x the EKF's error.
    # The data say the prior is wrong (the first predictions miss), so each window's prior is weighed by what the EKF
    # knew of its first node.
    from uiest.estimators import EKF
    from uiest.tuning import arrival_covariances

    def rhs(x, u, w):
        return [x[1], (-8.0 * x[0] - 1.0 * x[1] + w[0]) / 2.0]

    system = System.from_ode(rhs, lambda x, v: [x[0] + v[0]], nx=2, nw=1, nv=1, dt=0.01,
                             x_bounds=((-1.0, -5.0), (1.0, 5.0)), v_bounds=(-1e-4, 1e-4), name="cart")  # fmt: skip
    K = 300
    force = (2.0 * np.sin(1.5 * 0.01 * np.arange(K)) + 3.0 * (0.01 * np.arange(K) > 2.0))[:, None]
    truth = simulate(system, [0.1, 0.0], K, w=force, v=np.random.default_rng(1).uniform(-1e-4, 1e-4, (K + 1, 1)))
    register("cart-prior", lambda: system)
    prior = np.array([0.6, 2.5])
    errors = {}
    for kind in ("smooth", "ekf"):
        estimator, note = build_estimator(kind, get("cart-prior"), system, prior, record=truth)
        if kind == "smooth":
            assert "window prior: the EKF's covariance of (x, w) at each window's first node" in note
        errors[kind] = np.sqrt(np.mean(((estimator.run(None, truth.y, x0_prior=prior).x_hat - truth.x) / 2.0) ** 2))
    assert errors["smooth"] < 1.5 * errors["ekf"]
    # each window's prior: the EKF's prior covariance at k = 0, its posterior ones after
    ekf = EKF(system, w_variance=1.0, x0_prior=prior)
    settled, starts = arrival_covariances(ekf, np.zeros((K, 0)), truth.y, with_input=True)
    np.testing.assert_allclose(starts[0], np.diag([ekf.P0[0, 0], ekf.P0[1, 1], ekf.W0[0, 0]]))
    assert starts.shape == (K + 1, 3, 3) and np.trace(starts[-1, :2, :2]) < 1e-3 * np.trace(starts[0, :2, :2])
    np.testing.assert_allclose(starts[K // 2 :].mean(axis=0), settled, rtol=0.05)
