import pandas as pd
import pytest
from typer.testing import CliRunner

from uiest import models
from uiest.cli import app

runner = CliRunner()


def test_models_lists_the_registry_and_a_broken_model_beside_the_others(tmp_path):
    broken = tmp_path / "broken_model.py"
    broken.write_text("def build():\n    raise ValueError('no')\n")
    models.load(broken)
    try:
        result = runner.invoke(app, ["models"], terminal_width=300)
        assert result.exit_code == 0, result.output
        assert "crop-growth" in result.output and "closed-form" in result.output
        assert "broken_model" in result.output and "cannot be built" in result.output
    finally:
        models._REGISTRY.pop("broken_model")


def test_simulate_writes_csv_and_png(tmp_path):
    result = runner.invoke(app, ["simulate", "crop-growth", "--steps", "25", "--seed", "4", "--out", str(tmp_path)])
    assert result.exit_code == 0, result.output
    frame = pd.read_csv(tmp_path / "trajectory.csv", index_col="k")
    assert len(frame) == 26 and {"x_c", "x_d1", "x_d2", "w", "y_c", "y_d"} <= set(frame.columns)
    assert (tmp_path / "trajectory.png").stat().st_size > 10_000


def test_bad_input_gives_one_line_and_exit_code_2(tmp_path):
    for args, needle in (
        (["simulate", "no-such-model", "--out", str(tmp_path)], "unknown name"),
        (["simulate", "crop-growth", "--steps", "-3", "--out", str(tmp_path)], "steps"),
    ):
        result = runner.invoke(app, args)
        assert result.exit_code == 2
        assert needle in result.output
        assert len(result.output.strip().splitlines()) == 1


def test_unknown_option_is_a_usage_error():
    result = runner.invoke(app, ["simulate", "crop-growth", "--no-such-option", "1"])
    assert result.exit_code == 2


def test_certify_prints_the_table_and_writes_json(tmp_path):
    import json

    out = tmp_path / "certs.json"
    result = runner.invoke(app, ["certify", "closed-form", "--out", str(out), "--verify", "500"])
    assert result.exit_code == 0, result.output
    assert "min horizon" in result.output and "e-IOSS" in result.output
    data = json.loads(out.read_text())
    kinds = [c["kind"] for c in data["certificates"]]
    assert kinds == ["strong_detectability", "reduced_eioss", "delta_ioss"]
    assert all(c["certified"] for c in data["certificates"])
    assert all(c["verify_worst_ratio"] <= 1.0 for c in data["certificates"])
    # the closed-form model's certified UISE: a bound below X's width in every state, in the table and the JSON
    strong = data["certificates"][0]["guarantee"]
    assert strong["estimator"] == "UISE" and strong["applies"] and strong["informative"]
    assert "UISE: informative" in result.output and "(Theorem 3.6 of Guo et al.): holds, bound x1 " in result.output
    assert strong["text"].endswith("(informative)") and strong["text"] in result.output.replace("\n", "")
    assert all(c["falsification"]["worst_ratio"] <= 1.0 + 1e-6 for c in data["certificates"])
    assert "search: max ratio" in result.output
    # the pairs scored (a lifted domain or a model undefined outside X drops some) and the pairs drawn
    assert all(0 < c["verify_pairs"] <= 500 <= c["verify_pairs_drawn"] for c in data["certificates"])
    assert all(0 < c["falsification"]["pairs_scored"] <= c["falsification"]["pairs"] for c in data["certificates"])
    bad = runner.invoke(app, ["certify", "closed-form", "--structure", "diagonal", "--out", str(out)])
    assert bad.exit_code == 2 and "structure" in bad.output


def test_reproduce_runs_a_scenario_file(tmp_path):
    from test_experiments import tiny

    path = tiny().with_overrides(runs=1, cases=("noise-free",)).to_toml(tmp_path / "tiny.toml")
    result = runner.invoke(app, ["reproduce", "--scenario", str(path), "--out", str(tmp_path / "out")])
    assert result.exit_code == 0, result.output
    assert (tmp_path / "out" / "report.md").exists() and "UISE (measured, CPU)" in result.output
    bad = runner.invoke(app, ["reproduce", "no-such-model", "--out", str(tmp_path)])
    assert bad.exit_code == 2 and "unknown name" in bad.output
    none = runner.invoke(app, ["reproduce", "closed-form", "--out", str(tmp_path)])
    assert none.exit_code == 2 and "has no study()" in none.output


@pytest.mark.slow
def test_reproduce_runs_the_study_of_a_model_file(tmp_path):
    from pathlib import Path

    reactor = Path(__file__).resolve().parents[1] / "examples" / "reactor.py"
    args = ["reproduce", str(reactor), "--runs", "1", "--steps", "60", "--solver", "gn", "--out", str(tmp_path)]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    report = (tmp_path / "report.md").read_text()
    assert report.startswith("# reactor:") and "UISE (certified)" in report and "EKF (tuned)" in report
    assert "is below its smallest rate" not in report  # the example asks for a rate its certificate has
    # the written scenario names the model file from where it ends up (it was written relative to the staging
    # folder, one level deeper: here the path then pointed beside tmp_path)
    from uiest.experiments import Scenario

    model = tmp_path / "models" / "reactor.py"
    model.parent.mkdir()
    model.write_bytes(reactor.read_bytes())
    out = tmp_path / "out"
    args = ["reproduce", str(model), "--runs", "1", "--steps", "60", "--solver", "gn", "--out", str(out)]
    assert runner.invoke(app, args).exit_code == 0
    assert Path(Scenario.from_toml(out / "scenario.toml").model).resolve() == model.resolve()


def test_sweep_command_runs_and_resumes(tmp_path):
    design = tmp_path / "sweep.toml"
    design.write_text(
        "[scenario]\nname = 'cli-sweep'\nmodel = 'closed-form'\nsteps = 8\nruns = 1\ncases = ['noise-free']\n"
        "settle = 2\n[[scenario.estimators]]\nname = 'UISE'\nkind = 'uise'\nN = 3\nmu = 0.64\n"
        "[sweep]\ngrid = { N = [2, 3] }\n"
    )
    args = ["sweep", str(design), "--out", str(tmp_path / "out"), "--workers", "1"]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    assert "2 of 2 tasks stored (0 with an error), 0 lost" in result.output
    assert "sweep: 2 of 2 tasks done, 0 left" in result.output  # progress lines: no terminal
    again = runner.invoke(app, args)
    assert again.exit_code == 0 and "2 of 2 tasks stored" in again.output
    assert "sweep: 2 of 2 tasks done (2 stored before), 0 left" in again.output


@pytest.mark.slow
def test_bench_runs_only_the_chosen_estimator_and_window_length(tmp_path):
    import json

    out = tmp_path / "bench.json"
    result = runner.invoke(app, ["bench", "-N", "3", "--estimator", "standard MHE", "--json", str(out)])
    assert result.exit_code == 0, result.output
    records = json.loads(out.read_text())
    assert {(r["estimator"], r["N"]) for r in records} == {("standard MHE", 3)}
    assert {"ipopt", "gn", "rti", "gn-riccati"} <= {r["solver"] for r in records}


@pytest.mark.parametrize("args", [["--estimator", "EKF"], ["-N", "0"]], ids=["estimator", "horizon"])
def test_bench_rejects_unknown_estimators_and_window_lengths_before_running(args):
    result = runner.invoke(app, ["bench", *args])
    assert result.exit_code == 2 and "expected" in result.output
    assert "cpu ms" not in result.output  # no table was started


@pytest.mark.slow
def test_bench_quick_writes_one_record_per_estimator_and_backend(tmp_path):
    import json

    out = tmp_path / "bench.json"
    result = runner.invoke(app, ["bench", "--quick", "--json", str(out)])
    assert result.exit_code == 0, result.output
    records = json.loads(out.read_text())
    keys = {"estimator", "solver", "N", "median_ms", "p95_ms", "max_ms", "iterations", "max_dev_vs_ipopt",
            "max_cost_excess_vs_ipopt", "closed_loop_dev_vs_ipopt", "speedup_vs_ipopt", "median_dev_vs_ipopt",
            "windows_compared", "windows_dev_above_1e-6", "windows_cost_above_1e-8",
            "windows_cost_above_ipopt_plus_1e-8", "median_cpu_ms", "p95_cpu_ms",
            "max_cpu_ms", "cpu_ratio_vs_ipopt", "median_solve_ms", "samples", "fallbacks", "qp_fallbacks",
            "load"}  # fmt: skip
    from uiest.experiments.solver_bench import _dompc_available

    # 3 estimators x 4 backends, plus the do-mpc peer of the standard MHE where do-mpc is installed
    assert len(records) == 12 + _dompc_available() and all(keys <= set(r) for r in records)
    assert {(r["estimator"], r["solver"]) for r in records if r["max_dev_vs_ipopt"] == 0.0} >= {
        ("UISE", "ipopt"),
        ("two-stage UISE", "ipopt"),
        ("standard MHE", "ipopt"),
    }
    assert all(r["failures"] == 0 for r in records if r["solver"] != "rti")
    # whole steps cost more CPU than their solves; 100 samples after 30 warm-up ones are timed
    assert all(r["median_cpu_ms"] > 0 and r["samples"] == 71 for r in records if r["solver"] != "do-mpc")
    # on the same windows, the Gauss-Newton optimum is at least as good as IPOPT's
    assert all(r["max_cost_excess_vs_ipopt"] <= 1e-7 for r in records if r["solver"] == "gn")
    # 100 samples after 30 warm-up ones: the full windows k = 30 .. 100 (71) are compared
    gn = [r for r in records if r["solver"] == "gn"]
    assert all(r["windows_compared"] == 71 and r["median_dev_vs_ipopt"] <= r["max_dev_vs_ipopt"] for r in gn)
    assert all((r["windows_cost_above_1e-8"] > 0) == (r["max_cost_excess_vs_ipopt"] > 1e-8) for r in gn)
    # the absolute count (cost above IPOPT's + 1e-8) includes every window the relative one counts
    assert all(r["windows_cost_above_ipopt_plus_1e-8"] >= r["windows_cost_above_1e-8"] for r in records)


@pytest.mark.slow
def test_certify_says_the_crop_uise_bound_is_vacuous_in_kg_per_m2(tmp_path):
    import json

    out = tmp_path / "crop.json"
    result = runner.invoke(app, ["certify", "crop-growth", "--out", str(out), "--verify", "200"], terminal_width=400)
    assert result.exit_code == 0, result.output
    strong = json.loads(out.read_text())["certificates"][0]["guarantee"]
    assert strong["applies"] and not strong["informative"] and strong["verdict"] == "vacuous"
    line = next(line for line in result.output.splitlines() if line.startswith("  UISE with N = min horizon"))
    assert "holds but vacuous: bound " in line and "kg/m^2 > X's width 0.02 kg/m^2 for x_d1" in line
    assert "UISE: vacuous" in result.output and "applies" not in line


@pytest.mark.slow
def test_estimate_prints_warnings_as_messages_and_the_guarantee_with_its_verdict(tmp_path):
    import numpy as np

    from uiest import simulate
    from uiest.models import linear

    # y = 0.01 x + v, |v| <= 0.05, X = [-1, 1]: certified, but the noise can leave an error far beyond X
    model = tmp_path / "weak_output.py"
    model.write_text(
        "import numpy as np\nfrom uiest.models import linear\nsystem = linear.linear_system(np.array([[0.5]]), "
        "[[1.0]], [[0.01]], x_bounds=(-1, 1), v_bounds=(-0.05, 0.05))\n"
    )
    system = linear.linear_system(np.array([[0.5]]), [[1.0]], [[0.01]], x_bounds=(-1, 1), v_bounds=(-0.05, 0.05))
    rng = np.random.default_rng(0)
    truth = simulate(system, [0.1], 40, w=0.2 * np.sin(np.arange(40))[:, None], v=rng.uniform(-0.05, 0.05, (41, 1)))
    data = tmp_path / "data.csv"
    truth.to_pandas().to_csv(data)
    result = runner.invoke(app, ["estimate", str(model), "--data", str(data), "--out", str(tmp_path / "out"),
                                 "--estimator", "uise"],
                           terminal_width=400)  # fmt: skip
    assert result.exit_code == 0, result.output
    lines = result.output.splitlines()
    warned = [line for line in lines if line.startswith("warning: design: the chosen guarantee is not informative")]
    assert len(warned) == 1 and "holds but vacuous: bound" in warned[0]
    assert "UserWarning" not in result.output and "warnings.warn" not in result.output and ".py:" not in result.output
    column = " ".join(line.split("│")[4].strip() for line in lines if line.startswith("│"))  # the guarantee column
    assert column.startswith("holds but vacuous: bound ") and "> X's width 2 for x[0]" in column


def test_certify_prints_a_certificate_that_does_not_hold_beside_the_others(tmp_path):
    import json

    # an invariant zero at 1.5: strong detectability does not hold, so no estimator guarantee to print for it
    model = tmp_path / "unstable_zero.py"
    model.write_text(
        "from uiest.models import linear\nsystem, *_ = linear.with_invariant_zeros([1.5], seed=1, x_bounds=(-10, 10), "
        "v_bounds=(-1e-3, 1e-3))\n"
    )
    out = tmp_path / "certs.json"
    result = runner.invoke(app, ["certify", str(model), "--out", str(out), "--verify", "200"], terminal_width=400)
    assert result.exit_code == 0, result.output
    strong = json.loads(out.read_text())["certificates"][0]
    assert not strong["certified"] and strong["guarantee"] is None
    assert f"strong detectability: {strong['reason']}" in result.output.replace("\n", "")


def live_processes(group):
    """Pids of the processes of a process group that still run (zombies, already dead, are not counted)."""
    import os
    from pathlib import Path

    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(fields[2]) == group and fields[0] != "Z" and int(entry.name) != os.getpid():
                found.append(int(entry.name))
    return found


@pytest.mark.slow
def test_reproduce_interrupted_by_ctrl_c_keeps_its_finished_runs_and_the_rerun_computes_only_the_others(tmp_path):
    import os
    import signal
    import subprocess
    import sys
    import time
    from pathlib import Path

    out = tmp_path / "out"
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1] / "src")}
    args = [sys.executable, "-m", "uiest", "reproduce", "crop-growth", "--quick", "--steps", "35", "--solver", "gn",
            "--workers", "2", "--out", str(out)]  # fmt: skip
    # a Ctrl-C's default action in the job, even where this test runs with SIGINT ignored (a shell's background job)
    job = subprocess.Popen(args, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                           start_new_session=True,
                           preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))  # fmt: skip
    while job.poll() is None and not list((out / "runs").glob("*.pickle")):
        time.sleep(0.1)
    os.killpg(job.pid, signal.SIGINT)  # Ctrl-C: to the job's process group, its workers included
    _, err = job.communicate(timeout=120)
    assert job.returncode == 130, err
    for _ in range(100):  # the workers end with the job (a dead worker may wait a moment to be reaped by init)
        if not live_processes(job.pid):
            break
        time.sleep(0.1)
    assert live_processes(job.pid) == []
    stored = {path: path.stat().st_mtime_ns for path in (out / "runs").glob("*.pickle")}
    assert 1 <= len(stored) < 4 and f"interrupted: {len(stored)} of 4 runs are stored in {out / 'runs'}" in err
    again = subprocess.run(args, env=env, capture_output=True, text=True, timeout=600)
    assert again.returncode == 0, again.stderr
    assert f"4 of 4 runs done ({len(stored)} stored before), 0 left" in again.stderr  # progress lines: no terminal
    assert {path: path.stat().st_mtime_ns for path in stored} == stored  # read back, not computed again
    assert len(list((out / "runs").glob("*.pickle"))) == 4 and (out / "report.md").exists()


@pytest.mark.slow
def test_reproduce_without_a_terminal_writes_progress_lines_and_reads_its_stored_runs_back(tmp_path):
    from test_experiments import tiny

    path = tiny().with_overrides(runs=2, cases=("noise-free",)).to_toml(tmp_path / "tiny.toml")
    args = ["reproduce", "--scenario", str(path), "--out", str(tmp_path / "out")]
    first = runner.invoke(app, args)
    assert first.exit_code == 0 and "tiny: 1 of 2 runs done, 1 left, about " in first.output
    assert "tiny: 2 of 2 runs done, 0 left" in first.output
    files = sorted((tmp_path / "out" / "runs").glob("*.pickle"))
    assert len(files) == 2
    files[0].write_bytes(b"damaged")
    again = runner.invoke(app, args)
    assert again.exit_code == 0 and again.output.count(" runs done") == 1
    assert "tiny: 2 of 2 runs done (1 stored before), 0 left" in again.output  # the damaged one computed again


def test_version_prints_the_installed_package_metadata():
    from importlib.metadata import version

    import uiest

    result = runner.invoke(app, ["--version"])
    assert result.exit_code == 0, result.output
    assert result.output == f"uiest {version('uiest')}\n"
    assert uiest.__version__ == version("uiest")


def test_estimate_help_names_the_units_of_its_options():
    result = runner.invoke(app, ["estimate", "--help"], terminal_width=100)
    assert result.exit_code == 0, result.output
    text = " ".join(result.output.split())
    assert "--w-variance" in text and "Variance of one step of the unknown input's random walk" in text
    assert "as a multiple of (w's scale)^2" in text and "in w's unit^2 per step" in text
    assert "lag in samples" in text and "Largest window N of a design, in samples" in text
    assert "Prior of x[0] in the states' units" in text


def test_a_given_variance_is_printed_in_the_unknown_inputs_unit():
    from uiest import System
    from uiest.estimate import variance_text

    system = System.from_callables(
        lambda x, u, w: [x[0] + w[0]], lambda x, v: [x[0] + v[0]], nx=1, nw=1, nv=1, x_bounds=(-1, 1),
        v_bounds=(-0.1, 0.1), w_names=["force"], w_units=["m/s^2"], w_scale=[0.2],
    )  # fmt: skip
    assert variance_text(system, 0.5) == "0.5 w.scale^2 = force 0.02 (m/s^2)^2 per step"


def test_a_command_prints_each_warning_text_once(capsys):
    # the same estimator or model is built many times in a command (a design's candidates, a fit's grid): a wide
    # domain's scale warning was printed 74 times by one uiest estimate
    import warnings

    from uiest.cli import _user_errors

    @_user_errors
    def command():
        for _ in range(3):
            warnings.warn("x_scale: the same words", UserWarning, stacklevel=1)
            warnings.warn("x_scale: the same words", UserWarning, stacklevel=2)  # another location
        warnings.warn("other words", UserWarning, stacklevel=1)

    command()
    command()  # a second command prints them again
    lines = capsys.readouterr().err.splitlines()
    assert lines == ["warning: x_scale: the same words", "warning: other words"] * 2
