"""Sweeps: the same numbers serially, in local processes and on a Dask LocalCluster; resume; failures."""

import math

import pandas as pd
import pytest

from uiest import OptionError
from uiest.errors import DomainWarning
from uiest.experiments import EstimatorSpec, Scenario
from uiest.experiments import runner as runner_module
from uiest.experiments.sweep import Sweep, collect, run_task, sweep


def design():
    scenario = Scenario(
        name="tiny-sweep",
        model="closed-form",
        steps=10,
        runs=2,
        cases=("noisy",),
        prior=(math.nan, 0.0),
        prior_from_output=((0, 0),),
        settle=3,
        focus_state=1,
        estimators=(EstimatorSpec("UISE", "uise", N=3, mu=0.64, output_weight=1e4),),
    )
    return Sweep(scenario, grid={"N": (2, 4), "noise_scale": (0.5,)})


def test_each_row_counts_the_samples_whose_noise_left_v():
    # a sweep over noise_scale put the noise outside V, and its rows said nothing (a study's runs count it)
    loud = Sweep(design().scenario, grid={"noise_scale": (0.5, 3.0)})
    with pytest.warns(UserWarning, match="v left V"):
        rows = pd.concat([run_task(task) for task in loud.tasks()])
    by_scale = rows.groupby("noise_scale")["v_outside"].max()
    assert by_scale[0.5] == 0 and by_scale[3.0] > 0


def test_a_later_design_in_the_same_folder_leaves_no_plot_or_summary_of_the_earlier_one(tmp_path):
    # sweep_noise_scale.png of a design over N and noise_scale stayed beside the results of one over N alone
    sweep(design(), tmp_path, workers=1)
    assert {p.name for p in tmp_path.glob("sweep_*.png")} == {"sweep_N.png", "sweep_noise_scale.png"}
    later = Sweep(design().scenario, grid={"N": (3,)})
    with pytest.warns(UserWarning, match=r"removed sweep_noise_scale.png from .*: made from an earlier design's"):
        results = sweep(later, tmp_path, workers=1)
    assert {p.name for p in tmp_path.glob("sweep_*.png")} == {"sweep_N.png"}
    assert set(pd.read_parquet(tmp_path / "results.parquet")["N"]) == set(results["N"]) == {3}


def numbers(frame):
    """Everything but timings, in a canonical order."""
    cols = [c for c in frame.columns if not c.endswith("_ms")]
    return frame[cols].sort_values(["key", "estimator"]).reset_index(drop=True)


@pytest.mark.slow
def test_serial_processes_and_dask_agree_bit_for_bit(tmp_path):
    serial = sweep(design(), tmp_path / "serial", workers=1)
    assert len(serial) == 4 and set(serial["N"]) == {2, 4} and (serial["error"] == "").all()
    processes = sweep(design(), tmp_path / "processes", workers=2)
    pd.testing.assert_frame_equal(numbers(serial), numbers(processes))
    dask = sweep(design(), tmp_path / "dask", workers=2, scheduler="local")
    pd.testing.assert_frame_equal(numbers(serial), numbers(dask))
    assert (tmp_path / "serial" / "summary.csv").exists() and (tmp_path / "serial" / "sweep_N.png").exists()


@pytest.mark.slow
def test_interrupted_sweep_resumes_without_recomputing(tmp_path):
    first = sweep(design(), tmp_path, workers=1, max_tasks=2)
    assert len(first) == 2
    stored = {p.name: p.stat().st_mtime_ns for p in (tmp_path / "runs").glob("*.parquet")}
    seen = []
    full = sweep(design(), tmp_path, workers=1, progress=seen.append)
    assert len(full) == 4 and full["key"].is_unique
    assert len(seen) == 3 and seen[0].skipped == 2 and seen[0].remaining == 2 and seen[-1].remaining == 0
    for name, mtime in stored.items():
        assert (tmp_path / "runs" / name).stat().st_mtime_ns == mtime


def test_a_failing_estimator_is_recorded_and_the_sweep_goes_on(tmp_path, monkeypatch):
    calls = {"n": 0}
    real = runner_module.BUILDERS["uise"]

    def flaky(study, spec, prior, solver):
        calls["n"] += 1
        if calls["n"] == 2:
            raise OptionError("broken on purpose")
        return real(study, spec, prior, solver)

    monkeypatch.setitem(runner_module.BUILDERS, "uise", flaky)
    results = sweep(design(), tmp_path, workers=1)
    assert len(results) == 4 and (results["error"] == "OptionError: broken on purpose").sum() == 1


def test_bad_designs_are_refused(tmp_path):
    base = design().scenario
    with pytest.raises(OptionError, match="cannot be swept"):
        Sweep(base, grid={"colour": (1,)})
    with pytest.raises(OptionError, match="estimator"):
        Sweep(base, grid={"estimator": ("Kalman",)})
    random = Sweep(base, random=3, ranges={"N": (2, 5), "output_weight": (1e2, 1e6)})
    points = random.points()
    assert len(points) == 3 and all(2 <= p["N"] <= 5 and 1e2 <= p["output_weight"] <= 1e6 for p in points)
    (tmp_path / "s.toml").write_text("[scenario]\nname='x'\nmodel='closed-form'\n[sweep]\ngrid={N=[2]}\nextra=1\n")
    with pytest.raises(OptionError, match="extra"):
        Sweep.from_toml(tmp_path / "s.toml")


def test_the_readme_example_sweep_file_parses():
    from pathlib import Path

    design = Sweep.from_toml(Path(__file__).parents[1] / "examples" / "crop_sweep.toml")
    assert len(design.points()) == 6 and len(design.tasks()) == 6 * design.scenario.runs


@pytest.mark.slow
def test_every_backend_collects_its_rows_and_the_manifest_records_provenance(tmp_path):
    import json

    results = sweep(design(), tmp_path, workers=1, solver="rti")
    assert len(results) == 4 and set(results["solver"]) == {"rti"}
    manifest = json.loads((tmp_path / "manifest.json").read_text())
    assert manifest["solver"] == "rti" and manifest["tasks"] == 4
    assert manifest["design"]["sweep"]["grid"] == {"N": [2, 4], "noise_scale": [0.5]}
    (call,) = manifest["calls"]
    assert call["new_tasks"] == 4 and call["code_version"] and call["git_revision"]
    assert {"casadi", "numpy", "uiest"} <= set(call["versions"])
    assert len(collect(design(), tmp_path)) == 4  # the manifest's backend by default
    sweep(design(), tmp_path, workers=1, solver="rti")
    assert len(json.loads((tmp_path / "manifest.json").read_text())["calls"]) == 2


def test_task_keys_change_with_the_code(monkeypatch):
    from uiest.experiments import sweep_design

    before = {task.key for task in design().tasks()}
    monkeypatch.setattr(sweep_design, "code_version", lambda: "other code")  # read when tasks are made
    after = {task.key for task in design().tasks()}
    assert before.isdisjoint(after) and len(after) == len(before)


def test_help_texts_keep_their_brackets():
    from typer.testing import CliRunner

    from uiest.cli import app

    text = CliRunner().invoke(app, ["sweep", "--help"], terminal_width=200).output
    assert "[scenario] and [sweep]" in text


def gain_sweep(model):
    scenario = Scenario(name="gain", model=str(model), steps=20, runs=1, cases=("noise-free",), settle=2,
                        estimators=(EstimatorSpec("EKF", "ekf", w_variance=1.0),))  # fmt: skip
    return Sweep(scenario)


def test_an_edited_model_file_is_computed_again_and_the_manifest_records_its_hash(tmp_path):
    import hashlib
    import json
    import os
    from pathlib import Path

    model = tmp_path / "gain.py"
    text = (Path(__file__).parent / "gain_model.py").read_text()
    model.write_text(text)
    first = sweep(gain_sweep(model), tmp_path / "out", workers=1)
    assert (first["x_outside"] == 0).all() and (first["error"] == "").all()
    model.write_text(text.replace("GAIN = 0.5", "GAIN = 1.5"))
    later = model.stat().st_mtime_ns + 10**9  # a distinct version for the per-process model cache too
    os.utime(model, ns=(later, later))
    seen = []
    with pytest.warns(DomainWarning, match="x left X"):
        second = sweep(gain_sweep(model), tmp_path / "out", workers=1, progress=seen.append)
    assert seen[0].skipped == 0 and seen[-1].done == 1
    assert (second["x_outside"] > 0).all()  # the edited model's state leaves X: computed, not the stored rows
    manifest = json.loads((tmp_path / "out" / "manifest.json").read_text())
    digest = hashlib.sha256(model.read_bytes()).hexdigest()
    assert manifest["model"] == {"name": str(model), "sha256": digest}
    assert manifest["calls"][-1]["model_sha256"] == digest != manifest["calls"][0]["model_sha256"]


def test_a_model_file_edited_during_a_sweep_leaves_the_later_tasks_unstored(tmp_path):
    from pathlib import Path

    model = tmp_path / "gain.py"
    text = (Path(__file__).parent / "gain_model.py").read_text()
    model.write_text(text)
    design = Sweep(gain_sweep(model).scenario, grid={"w_gain": (1.0, 2.0)})

    states = []

    def edit(state):
        states.append(state)
        if state.done == 1:  # after the first task: the second would run another model than its key says
            model.write_text(text.replace("GAIN = 0.5", "GAIN = 0.25"))

    with pytest.warns(UserWarning, match="none of this design .* and this model file content"):
        results = sweep(design, tmp_path / "out", workers=1, progress=edit)
    assert results.empty  # the one stored task belongs to the file before the edit
    assert len(list((tmp_path / "out" / "runs").glob("*.parquet"))) == 1
    log = (tmp_path / "out" / "lost_tasks.log").read_text()
    assert "ModelChangedError: the model file" in log and "changed after the sweep started" in log
    assert states[-1].lost == states[-1].lost_to_model_change == 1


def test_task_keys_do_not_change_with_the_run_count_or_the_spelling_of_a_model_file_s_path(tmp_path, monkeypatch):
    # a run's result depends on neither: adding runs recomputed every stored task, and naming the same model file by
    # a relative and then an absolute path recomputed everything
    import dataclasses
    from pathlib import Path

    keys = {(t.case, t.run, t.params): t.key for t in design().tasks()}
    more = Sweep(dataclasses.replace(design().scenario, runs=3), grid=design().grid)
    added = {(t.case, t.run, t.params): t.key for t in more.tasks()}
    assert all(added[task] == key for task, key in keys.items()) and len(added) == len(keys) * 3 // 2
    model = tmp_path / "gain.py"
    model.write_text((Path(__file__).parent / "gain_model.py").read_text())
    monkeypatch.chdir(tmp_path)
    spelled = [Sweep(dataclasses.replace(design().scenario, model=path), grid=design().grid).tasks()
               for path in ("gain.py", str(model), "./gain.py")]  # fmt: skip
    assert [t.key for t in spelled[0]] == [t.key for t in spelled[1]] == [t.key for t in spelled[2]]
    edited = model.read_text().replace("GAIN = 0.5", "GAIN = 1.5")
    model.write_text(edited)  # its bytes still key the tasks
    again = Sweep(dataclasses.replace(design().scenario, model="gain.py"), grid=design().grid).tasks()
    assert {t.key for t in again}.isdisjoint(t.key for t in spelled[0])


def test_a_sweep_where_one_estimator_fails_in_every_task_and_another_does_not_succeeds(tmp_path):
    # "every task failed" (exit 1) came where every task had the EKF's results and only the two-stage UISE failed
    from typer.testing import CliRunner

    from uiest.cli import app

    path = tmp_path / "mixed.toml"
    path.write_text(
        "[scenario]\nname = 'x'\nmodel = 'linear-example'\nsteps = 8\nruns = 1\ncases = ['noisy']\nsettle = 2\n"
        "[[scenario.estimators]]\nname = '2s'\nkind = 'two-stage'\nN = 3\n"
        "[[scenario.estimators]]\nname = 'EKF'\nkind = 'ekf'\nw_variance = 1.0\n[sweep]\ngrid = {N = [2, 3]}\n"
    )
    result = CliRunner().invoke(app, ["sweep", str(path), "--out", str(tmp_path / "out"), "--workers", "1"])
    assert result.exit_code == 0, result.output
    assert "2 of 2 tasks stored (2 with an error)" in result.output and "every task failed" not in result.output


def test_a_sweep_file_that_cannot_be_read_leaves_no_output_folder(tmp_path):
    from typer.testing import CliRunner

    from uiest.cli import app

    result = CliRunner().invoke(app, ["sweep", str(tmp_path / "none.toml"), "--out", str(tmp_path / "out")])
    assert result.exit_code == 2 and "cannot read" in result.output
    assert not (tmp_path / "out").exists()


def _gain_sweep_file(tmp_path, w_gains):
    """The gain model's file, its text, and a sweep file over ``w_gains`` (a TOML list) of an EKF on it."""
    from pathlib import Path

    model = tmp_path / "gain.py"
    text = (Path(__file__).parent / "gain_model.py").read_text()
    model.write_text(text)
    path = tmp_path / "gain.toml"
    path.write_text(
        "[scenario]\nname = 'gain'\nmodel = 'gain.py'\nsteps = 20\nruns = 1\ncases = ['noise-free']\nsettle = 2\n"
        "[[scenario.estimators]]\nname = 'EKF'\nkind = 'ekf'\nw_variance = 1.0\n"
        f"[sweep]\ngrid = {{w_gain = {w_gains}}}\n"
    )
    return model, text, path


def test_a_model_file_edited_during_a_cli_sweep_is_named_and_its_lost_tasks_are_not_counted_done(tmp_path, monkeypatch):
    # the progress line said "2 of 2 tasks done, 0 left" beside "0 of 2 tasks stored, 1 lost", without the cause; a
    # later run that stored every task left lost_tasks.log listing the task as lost

    from typer.testing import CliRunner

    from uiest.cli import app
    from uiest.experiments import sweep as sweep_module

    model, text, path = _gain_sweep_file(tmp_path, "[1.0, 2.0]")
    run_task = sweep_module.run_task

    def edit_after_the_first(task):
        rows = run_task(task)
        model.write_text(text.replace("GAIN = 0.5", "GAIN = 0.25"))
        return rows

    monkeypatch.setattr(sweep_module, "run_task", edit_after_the_first)
    log = tmp_path / "out" / "lost_tasks.log"
    log.parent.mkdir()
    log.write_text("2020-01-01T00:00:00+00:00 0123abcd noise-free run 0 {}: lost by an earlier run\n")
    command = ["sweep", str(path), "--out", str(tmp_path / "out"), "--workers", "1"]
    first = CliRunner().invoke(app, command, terminal_width=300)
    assert first.exit_code == 1, first.output
    assert "sweep: 1 of 2 tasks done, 1 lost, 0 left" in first.stderr
    said = " ".join(first.stderr.split())  # the warning line, unwrapped
    assert f"warning: the model file {model} changed during the run: 1 task begun after it was refused, and the 1 " \
        "task finished before it is stored for the file's earlier content" in said  # fmt: skip
    assert "error: 1 task was not computed: the model file changed during the run (see" in first.stderr
    assert len(log.read_text().splitlines()) == 1 and "earlier run" not in log.read_text()  # this run's lost task
    monkeypatch.setattr(sweep_module, "run_task", run_task)
    second = CliRunner().invoke(app, command, terminal_width=300)
    assert second.exit_code == 0, second.output
    assert "sweep: 2 of 2 tasks done, 0 left" in second.stderr and "2 of 2 tasks stored" in second.stdout
    assert not log.exists()  # every task stored: no task of this folder is lost


def test_a_sweep_counts_the_tasks_lost_to_a_model_edit_apart_from_those_lost_otherwise(tmp_path, monkeypatch):
    # every lost task was blamed on the edit: "2 tasks were not computed: the model file changed", "(2 lost)"

    from typer.testing import CliRunner

    from uiest.cli import app
    from uiest.experiments import sweep as sweep_module

    model, text, path = _gain_sweep_file(tmp_path, "[1.0, 2.0, 3.0]")
    run_task = sweep_module.run_task
    seen: list[float] = []

    def edit_after_the_first_and_lose_the_second(task):
        seen.append(dict(task.params)["w_gain"])
        if len(seen) == 2:
            raise RuntimeError("the worker's connection dropped")  # lost, not for the edit
        rows = run_task(task)  # the third is refused: the file changed
        model.write_text(text.replace("GAIN = 0.5", "GAIN = 0.25"))
        return rows

    monkeypatch.setattr(sweep_module, "run_task", edit_after_the_first_and_lose_the_second)
    result = CliRunner().invoke(app, ["sweep", str(path), "--out", str(tmp_path / "out"), "--workers", "1"],
                                terminal_width=300)  # fmt: skip
    assert result.exit_code == 1, result.output
    said = " ".join(result.stderr.split())
    assert "1 task begun after it was refused, and the 1 task finished before it is stored" in said
    assert "; 1 more task was lost for another reason (see lost_tasks.log)" in said
    assert "error: 2 tasks were not computed, 1 because the model file changed during the run (see" in said
    log = (tmp_path / "out" / "lost_tasks.log").read_text().splitlines()
    assert len(log) == 2 and "RuntimeError" in log[0] and "ModelChangedError" in log[1]
