"""The study runner, metrics and report files on a tiny scenario."""

import dataclasses
import json
import math
import pickle
import traceback
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from uiest import OptionError
from uiest.errors import DomainWarning
from uiest.experiments import (
    EstimatorSpec,
    Scenario,
    accuracy,
    crop_growth_study,
    run_study,
    timing,
    write_report,
)
from uiest.experiments import runner as runner_module
from uiest.experiments.study_model import study_model


def tiny():
    return Scenario(
        name="tiny",
        model="closed-form",
        steps=12,
        runs=2,
        x0_lower=(0.0, 0.5),
        x0_upper=(1.0, 1.5),
        prior=(math.nan, 0.0),
        prior_from_output=((0, 0),),
        settle=4,
        focus_state=1,
        estimators=(
            EstimatorSpec("UISE", "uise", N=4, mu=0.64, output_weight=1e4),
            EstimatorSpec("standard MHE", "standard-mhe", N=4, mu=0.64),
        ),
    )


def test_scenario_round_trips_through_toml(tmp_path):
    scenario = crop_growth_study()
    path = scenario.to_toml(tmp_path / "s.toml")
    back = Scenario.from_toml(path)
    assert back.to_dict() == scenario.to_dict()
    assert math.isnan(back.prior[0]) and back.estimators == scenario.estimators
    assert scenario.with_overrides(runs=3, steps=None).runs == 3
    with pytest.raises(OptionError, match="unknown"):
        scenario.with_overrides(nonsense=1)
    with pytest.raises(OptionError, match="kind"):
        EstimatorSpec("x", "kalman")
    (tmp_path / "bad.toml").write_text('name = "x"\nmodel = "closed-form"\ncolour = 3\n')
    with pytest.raises(OptionError, match="colour"):
        Scenario.from_toml(tmp_path / "bad.toml")


def test_runner_metrics_and_report(tmp_path):
    scenario = tiny()
    labels = []
    study = run_study(scenario, progress=labels.append)
    assert len(labels) == 2 * 2 * 2 and study.runs["error"].eq("").all()
    # run 0 uses the nominal x0 (model default), run 1 a random one in the box
    assert study.truths[("noise-free", 0)].x[0].tolist() == [0.5, 1.0]
    x1 = study.truths[("noise-free", 1)].x[0]
    assert np.all((x1 >= [0.0, 0.5]) & (x1 <= [1.0, 1.5]))
    # the prior takes x1 from y0
    steps = study.steps
    assert len(steps) == 2 * 2 * 2 * 13 and {"x1", "x1_hat", "w", "w_hat", "solve_time", "status"} <= set(steps.columns)
    acc = accuracy(study)
    uise = acc[(acc.case == "noise-free") & (acc.estimator == "UISE") & (acc.state == "x1")]
    frame = steps[(steps.case == "noise-free") & (steps.estimator == "UISE") & (steps.k >= 4)]
    expected = np.sqrt(((frame.x1 - frame.x1_hat) ** 2).mean())
    assert float(uise.rmse.iloc[0]) == pytest.approx(expected)
    times = timing(study)
    per_run = steps[(steps.case == "noisy") & (steps.estimator == "standard MHE")].groupby("run").solve_time.mean()
    row = times[(times.case == "noisy") & (times.estimator == "standard MHE")]
    assert float(row.t_max_ms.iloc[0]) == pytest.approx(1e3 * per_run.max())
    manifest = write_report(study, tmp_path, wall_time=1.0)
    for name in ("report.md", "table1.md", "table1.csv", "figure1_states.png", "figure2_errors.pdf",
                 "figure3_unknown_input.png", "steps.parquet", "manifest.json", "scenario.toml"):  # fmt: skip
        assert (tmp_path / name).stat().st_size > 0, name
    assert pd.read_parquet(tmp_path / "steps.parquet").shape == steps.shape
    data = json.loads((tmp_path / "manifest.json").read_text())
    assert data["versions"]["casadi"] and data["scenario"]["name"] == "tiny" and manifest["files"]
    assert data["solver"] == "ipopt" == study.solver
    report = (tmp_path / "report.md").read_text()
    assert "Claims of the paper" in report and "Window solver: IPOPT" in report


def test_an_estimator_that_raises_is_recorded_and_the_study_goes_on(monkeypatch):
    def broken(*args):
        raise OptionError("broken on purpose")

    monkeypatch.setitem(runner_module.BUILDERS, "standard-mhe", broken)
    study = run_study(tiny().with_overrides(runs=1, cases=("noise-free",)))
    errors = study.runs.set_index("estimator")["error"]
    assert errors["standard MHE"] == "OptionError: broken on purpose" and errors["UISE"] == ""
    assert set(study.steps.estimator) == {"UISE"}


@pytest.mark.slow
def test_certificate_weights_reach_the_study_and_its_report(tmp_path):
    base = tiny()
    certified = EstimatorSpec("UISE (certified)", "uise", N=0, mu=0.9, weights="certificate")
    scenario = base.with_overrides(runs=1, estimators=(*base.estimators, certified))
    study = run_study(scenario)
    (row,) = study.certificates
    assert row["status"] == "certified" and row["rate"] == pytest.approx(0.9)
    assert row["N"] == row["min_horizon"] >= 1 and len(row["noise_gain"]) == 2
    result = study.results[("noisy", 0, "UISE (certified)")]
    assert result.guarantee.applies and "Theorem 3.6 of Guo et al." in result.guarantee.theorem
    write_report(study, tmp_path, wall_time=1.0)
    report = (tmp_path / "report.md").read_text()
    assert "## Certificates and guarantees" in report and f"guarantee: {result.guarantee.text}." in report
    guarantees = pd.read_csv(tmp_path / "guarantees.csv").set_index("estimator")
    # the closed-form model's certified UISE: a bound below X's width (20) in every state
    assert guarantees.loc["UISE (certified)", "guarantee"] == result.guarantee.text
    assert result.guarantee.text.startswith("holds, bound x1 ") and "(informative)" in result.guarantee.text
    # the study's runs are shorter than the bound's settling: the run's guarantee says so
    assert result.guarantee.text.endswith(f"The run ends at k = {len(result.t) - 1}, before the bound applies")
    assert float(guarantees.loc["UISE (certified)", "bound x2"]) == pytest.approx(result.guarantee.error_bound[1])
    assert guarantees.loc["UISE", "guarantee"] == "none: explicit weights without a strong-detectability certificate"
    assert json.loads((tmp_path / "manifest.json").read_text())["certificates"][0]["status"] == "certified"
    with pytest.raises(OptionError, match="N"):
        EstimatorSpec("x", "uise", N=0)  # N = 0 (the certificate's horizon) needs certificate weights
    with pytest.raises(OptionError, match="weights"):
        EstimatorSpec("x", "uise", weights="guess")


@pytest.mark.slow
def test_the_crop_report_says_its_certified_uise_bound_is_vacuous_in_kg_per_m2():
    from uiest.experiments.metrics import accuracy
    from uiest.experiments.report import guarantee_table

    study_spec = crop_growth_study()
    (certified,) = [spec for spec in study_spec.estimators if spec.name == "UISE (certified)"]
    study = run_study(study_spec.with_overrides(runs=1, steps=40, cases=("noisy",), estimators=(certified,)),
                      solver="gn")  # fmt: skip
    table = guarantee_table(study, accuracy(study)).set_index("estimator")
    text = table.loc["UISE (certified)", "guarantee"]
    assert text.startswith("holds but vacuous: bound ") and "kg/m^2 > X's width 0.02 kg/m^2 for x_d1" in text
    assert table.loc["UISE (certified)", "bound x_d1 (kg/m^2)"] > 100 * 0.02


def test_a_certificate_that_cannot_be_had_is_recorded_and_the_study_goes_on():
    base = tiny()
    no_reduction = EstimatorSpec("two-stage", "two-stage", N=4, weights="certificate")
    changes = {"model": "linear-example", "runs": 1, "cases": ("noise-free",), "prior": (), "prior_from_output": (),
               "focus_state": 0, "x0_lower": (), "x0_upper": ()}  # fmt: skip
    changes["estimators"] = (base.estimators[0], no_reduction)
    scenario = base.with_overrides(**changes)
    study = run_study(scenario)
    assert study.certificates[0]["status"] == "not available" and "reduction" in study.certificates[0]["reason"]
    errors = study.runs.set_index("estimator")["error"]
    assert "reduction" in errors["two-stage"] and errors["UISE"] == ""


def test_a_state_leaving_x_is_counted_and_reported(tmp_path):
    base = tiny()
    leaving = base.with_overrides(runs=1, cases=("noise-free",), w_gain=30.0, estimators=(base.estimators[0],))
    with pytest.warns(UserWarning, match="x left X"):
        study = run_study(leaving)
    row = study.runs.iloc[0]
    assert row["x_outside"] > 0 and row["on_boundary"] > 0 and row["at_bound"] >= row["on_boundary"]
    per_state = [row[column] for column in study.runs.columns if column.startswith("at_bound_")]
    assert len(per_state) == 2 and max(per_state) <= row["at_bound"] <= sum(per_state)
    write_report(study, tmp_path, wall_time=1.0)
    report = (tmp_path / "report.md").read_text()
    assert "The true state left X in 1 run (" in report and "held on the boundary of X" in report
    health = pd.read_csv(tmp_path / "health.csv")
    assert health.loc[0, "at_bound"] == row["at_bound"] and health.loc[0, "failures"] == row["failures"]
    share = 100 * row["at_bound"] / row["steps"]
    assert share > 5 and "Estimates at a side of X in more than 5 % of the steps: UISE (noise-free): " in report
    assert "## Failures and step health" in report and "Estimator runs that raised: none." in report


@pytest.mark.slow
def test_runs_in_worker_processes_give_the_same_numbers():
    scenario = tiny()
    serial = run_study(scenario, solver="gn")
    labels = []
    parallel = run_study(scenario, solver="gn", workers=2, progress=labels.append)
    assert len(labels) == 2 * 2 * 2
    columns = ["case", "run", "estimator", "k", "x1_hat", "x2_hat", "w_hat", "status"]
    pd.testing.assert_frame_equal(serial.steps[columns], parallel.steps[columns])
    assert serial.runs[["case", "run", "estimator", "failures"]].equals(parallel.runs[["case", "run", "estimator",
                                                                                       "failures"]])  # fmt: skip
    assert set(parallel.results) == set(serial.results) and set(parallel.truths) == set(serial.truths)


@pytest.mark.slow
def test_studies_run_the_ekf_and_the_ukf_tuned_or_given():
    specs = (EstimatorSpec("EKF (tuned)", "ekf"), EstimatorSpec("UKF", "ukf", w_variance=0.01))
    scenario = dataclasses.replace(tiny(), runs=1, estimators=specs)
    study = run_study(scenario, solver="gn")
    assert study.runs["error"].eq("").all() and set(study.runs["estimator"]) == {"EKF (tuned)", "UKF"}
    assert study_model("closed-form").tuned_variance("ekf") > 0
    with pytest.raises(OptionError, match="w_variance"):
        EstimatorSpec("EKF", "ekf", w_variance=-1.0)


@pytest.mark.slow
def test_a_study_of_a_model_file():
    from pathlib import Path

    reactor = Path(__file__).resolve().parents[1] / "examples" / "reactor.py"
    scenario = Scenario(name="reactor-study", model=str(reactor), steps=60, runs=1, x0_lower=(0.6, 1.0),
                        x0_upper=(0.7, 1.1), prior=(0.65, 1.05), settle=20, focus_state=0,
                        estimators=(EstimatorSpec("UISE", "uise", N=10, mu=0.8, output_weight=1.0),
                                    EstimatorSpec("EKF", "ekf")))  # fmt: skip
    study = run_study(scenario, solver="gn")
    assert study.runs["error"].eq("").all() and study.runs["failures"].eq(0).all()
    acc = accuracy(study)
    assert acc[(acc.case == "noise-free") & (acc.state == "c_A")].rmse.max() < 0.01


@pytest.mark.slow
def test_a_study_of_a_model_given_as_an_object_computes_each_certificate_once(monkeypatch, tmp_path):
    from uiest import models
    from uiest.experiments import study_model as study_module

    entry = models.get("closed-form")
    mine = models.ModelEntry("not-registered", "a model handed to the runner", entry.build, entry.setup)
    certified = EstimatorSpec("UISE (certified)", "uise", N=0, mu=0.9, weights="certificate")
    scenario = dataclasses.replace(tiny(), model="not-registered", estimators=(*tiny().estimators, certified))
    calls = []
    real = study_module.certify_strong_detectability
    monkeypatch.setattr(study_module, "certify_strong_detectability", lambda *a, **k: calls.append(1) or real(*a, **k))
    study = run_study(scenario, model=mine, workers=2)
    assert study.runs["error"].eq("").all() and len(study.runs) == 2 * 2 * 3
    assert study.certificates[0]["status"] == "certified"
    assert len(calls) == 2  # the default rate and mu = 0.9, once for the whole study
    with pytest.raises(OptionError, match="unknown name"):
        run_study(scenario)  # by name, the runner finds no such model
    with pytest.raises(OptionError, match="model: expected a ModelEntry"):
        run_study(scenario, model="closed-form")
    assert write_report(study, tmp_path, wall_time=1.0)["files"]  # the report uses the given model too


def test_a_failing_tuning_is_recorded_per_run_and_kept(monkeypatch):
    from uiest.experiments import study_model as study_module

    def broken(self, kind):
        raise IndexError("tuning broke")

    monkeypatch.setattr(study_module.StudyModel, "_tune", broken)
    scenario = dataclasses.replace(tiny(), estimators=(*tiny().estimators, EstimatorSpec("EKF", "ekf")))
    study = run_study(scenario)
    errors = study.runs.set_index("estimator")["error"]
    assert (errors["EKF"] == "IndexError: tuning broke").all() and (errors["UISE"] == "").all()
    model = study.model
    for _ in range(50):  # raised again from the cache, its traceback does not grow
        with pytest.raises(IndexError) as caught:
            model.tuned_variance("ekf")
    assert len(traceback.extract_tb(caught.value.__traceback__)) < 5
    with pytest.raises(OptionError, match="kind"):
        model.tuned_variance("kalman")
    with pytest.raises(OptionError, match="mu"):
        model.certificate("uise", "abc")


def test_a_run_whose_simulation_fails_is_recorded_and_the_study_and_its_report_go_on(monkeypatch, tmp_path):
    # a model not finite for some initial states: the simulation's ModelError once ended the whole study (and every
    # rerun of uiest reproduce), with no report
    from uiest import ModelError

    failing = {1}
    simulate_run = runner_module.simulate_run

    def simulation(scenario, case, run, study=None):
        if run in failing:
            raise ModelError("f: non-finite state at step k=6 (on purpose)")
        return simulate_run(scenario, case, run, study)

    monkeypatch.setattr(runner_module, "simulate_run", simulation)
    scenario = tiny().with_overrides(runs=3, cases=("noise-free",))
    study = run_study(scenario)
    failed = study.runs[study.runs["run"] == 1]
    expected = "simulation: ModelError: f: non-finite state at step k=6 (on purpose)"
    assert len(failed) == 2 and (failed["error"] == expected).all()
    assert set(study.truths) == {("noise-free", 0), ("noise-free", 2)} and set(study.steps.run) == {0, 2}
    write_report(study, tmp_path / "report", wall_time=1.0)
    text = (tmp_path / "report" / "report.md").read_text()
    assert "simulation: ModelError" in text and "left X" not in text  # a run not simulated left nothing
    failing.add(0)  # the figures show the first run whose simulation succeeded
    write_report(run_study(scenario), tmp_path / "report0", wall_time=1.0)
    assert (tmp_path / "report0" / "figure1_states.png").exists()
    failing.add(2)  # no run simulated: the report is written, without figures, and says so
    write_report(run_study(scenario), tmp_path / "none", wall_time=1.0)
    text = (tmp_path / "none" / "report.md").read_text()
    assert "No run was simulated in every case: no figures." in text and "figure1_states.png" not in text


def test_a_changed_model_file_is_read_again(tmp_path):
    import os

    path = tmp_path / "drift.py"
    text = (Path(__file__).resolve().parents[1] / "examples" / "reactor.py").read_text()
    path.write_text(text)
    first = study_model(path)
    assert study_model(str(path)) is first and first.system.x.names == ("c_A", "T")
    path.write_text(text.replace('x_names=("c_A", "T")', 'x_names=("conc", "temp")'))
    later = path.stat().st_mtime_ns + 10**9  # a distinct version even on a coarse clock
    os.utime(path, ns=(later, later))
    assert study_model(path).system.x.names == ("conc", "temp")


@pytest.mark.parametrize("name", ["../x", "a/b", "/tmp/abs", "a\\b", "..", ".", ""])
def test_a_study_name_that_would_leave_the_output_folder_is_refused(name):
    with pytest.raises(OptionError, match=r"^name: expected "):
        dataclasses.replace(tiny(), name=name)


def test_reproduce_refuses_a_scenario_file_whose_name_leaves_out(tmp_path, monkeypatch):
    from typer.testing import CliRunner

    from uiest.cli import app

    monkeypatch.chdir(tmp_path)
    path = tmp_path / "escape.toml"
    path.write_text(tiny().to_toml(tmp_path / "ok.toml").read_text().replace('name = "tiny"', 'name = "../escaped"'))
    result = CliRunner().invoke(app, ["reproduce", "--scenario", str(path)])
    assert result.exit_code == 2 and result.output.strip().splitlines() == [
        "error: name: expected a plain name without path separators, '.' or '..' (it names a path inside the output "
        "folder), got '../escaped'"
    ]
    assert not (tmp_path / "escaped").exists() and not (tmp_path / "out").exists()


def test_a_model_file_in_a_scenario_or_sweep_file_is_found_beside_it(tmp_path, monkeypatch):
    from uiest.experiments.sweep import Sweep

    folder = tmp_path / "study"
    folder.mkdir()
    (folder / "gain.py").write_text((Path(__file__).parent / "gain_model.py").read_text())
    text = dataclasses.replace(tiny(), model="gain.py", prior=(), prior_from_output=(), x0_lower=(), x0_upper=(),
                               focus_state=0).to_dict()  # fmt: skip
    import tomli_w

    (folder / "scenario.toml").write_text(tomli_w.dumps(text))
    (folder / "sweep.toml").write_text(tomli_w.dumps({"scenario": text, "sweep": {"grid": {"N": [3, 4]}}}))
    monkeypatch.chdir(tmp_path)  # not the files' folder
    scenario = Scenario.from_toml(Path("study/scenario.toml"))
    assert Path(scenario.model).resolve() == (folder / "gain.py").resolve()
    assert study_model(scenario.model).system.nx == 2
    assert Path(Sweep.from_toml(Path("study/sweep.toml")).scenario.model).resolve() == (folder / "gain.py").resolve()
    copy = scenario.to_toml(tmp_path / "elsewhere" / "deeper" / "scenario.toml")  # written relative to its folder
    assert Path(Scenario.from_toml(copy).model).resolve() == (folder / "gain.py").resolve()


def numbers_of(study):
    """The study's step and run tables without timings."""
    timings = {"solve_time", "cpu_time", "wall_time_s"}
    steps = study.steps.drop(columns=[c for c in study.steps.columns if c in timings])
    runs = study.runs.drop(columns=[c for c in study.runs.columns if c in timings])
    return steps, runs.reset_index(drop=True)


@pytest.mark.slow
def test_a_stored_study_reads_its_finished_runs_back_and_computes_only_the_others(tmp_path):
    store = tmp_path / "runs"
    first = run_study(tiny(), store=store)
    files = sorted(store.glob("*.pickle"))
    assert len(files) == 2 * 2  # one per (case, run), written as each finished
    files[0].unlink()  # a run the interruption lost
    files[1].write_bytes(b"not a run")  # a damaged file: set aside, computed again
    files[2].write_bytes(pickle.dumps({"key": files[2].stem, "outcome": "not a run"}))  # its key, not a run: the same
    kept = {path: path.stat().st_mtime_ns for path in files[3:]}
    labels = []
    with pytest.warns(UserWarning, match=r"could not be read .*set aside as .*corrupt") as caught:
        again = run_study(tiny(), store=store, progress=labels.append)
    assert sum("set aside" in str(w.message) for w in caught) == 2  # said, not silent
    assert len(labels) == 3 * 2  # three (case, run)s of two estimators computed; the other read back
    assert len(list((store / "corrupt").iterdir())) == 2 and len(list(store.glob("*.pickle"))) == 4
    assert {path: path.stat().st_mtime_ns for path in files[3:]} == kept
    for mine, theirs in zip(numbers_of(first), numbers_of(again), strict=True):
        pd.testing.assert_frame_equal(mine, theirs)
    assert again.results.keys() == first.results.keys() and again.truths.keys() == first.truths.keys()
    labels.clear()
    more = run_study(dataclasses.replace(tiny(), runs=3), store=store, progress=labels.append)
    assert len(labels) == 2 * 2 and len(more.runs) == 3 * 2 * 2  # run 2 of each case is new; runs 0 and 1 stored
    labels.clear()
    run_study(tiny(), store=store, solver="gn", progress=labels.append)
    assert len(labels) == 2 * 2 * 2  # another backend: nothing taken from the store


def test_a_stored_study_of_an_edited_model_file_is_computed_again(tmp_path):
    model = tmp_path / "gain.py"
    text = (Path(__file__).parent / "gain_model.py").read_text()
    model.write_text(text)
    scenario = Scenario(name="gain", model=str(model), steps=20, runs=1, cases=("noise-free",), settle=2,
                        estimators=(EstimatorSpec("EKF", "ekf", w_variance=1.0),))  # fmt: skip
    first = run_study(scenario, store=tmp_path / "runs")
    assert first.runs["x_outside"].eq(0).all()
    model.write_text(text.replace("GAIN = 0.5", "GAIN = 1.5"))
    later = model.stat().st_mtime_ns + 10**9  # a distinct version for the per-process model cache too
    import os

    os.utime(model, ns=(later, later))
    labels = []
    with pytest.warns(DomainWarning, match="x left X"):
        again = run_study(scenario, store=tmp_path / "runs", progress=labels.append)
    assert len(labels) == 1 and again.runs["x_outside"].gt(0).all()  # computed on the edited file, not read back
    import hashlib

    manifest = write_report(again, tmp_path / "report", wall_time=1.0)
    assert manifest["model"] == {"name": str(model), "sha256": hashlib.sha256(model.read_bytes()).hexdigest()}


def test_a_store_needs_the_model_by_name_or_file(tmp_path):
    from uiest import models

    entry = models.get("closed-form")
    with pytest.raises(OptionError, match=r"^store: "):
        run_study(tiny(), model=entry, store=tmp_path)
    models.register("registered-here", entry.build, setup=entry.setup, replace=True)
    with pytest.raises(OptionError, match=r"^store: .*registered at run time"):
        run_study(dataclasses.replace(tiny(), model="registered-here"), store=tmp_path)


def test_noise_leaving_v_is_counted_and_reported(tmp_path):
    # a sweep's noise_scale = 3 put 90 % of the samples outside V, and neither the runs nor the report said so
    base = tiny()
    loud = base.with_overrides(runs=1, cases=("noisy",), noise_scale=3.0, estimators=(base.estimators[0],))
    with pytest.warns(UserWarning, match="v left V"):
        study = run_study(loud)
    assert study.runs.iloc[0]["v_outside"] > 0
    write_report(study, tmp_path, wall_time=1.0)
    assert "The noise left V in 1 run (" in (tmp_path / "report.md").read_text()
