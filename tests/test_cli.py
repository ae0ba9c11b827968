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
    assert all(c["falsification"]["worst_ratio"] <= 1.0 + 1e-6 for c in data["certificates"])
    assert "search: max ratio" in result.output
    bad = runner.invoke(app, ["certify", "closed-form", "--structure", "diagonal", "--out", str(out)])
    assert bad.exit_code == 2 and "structure" in bad.output


def test_reproduce_runs_a_scenario_file(tmp_path):
    from test_experiments import tiny

    path = tiny().with_overrides(runs=1, cases=("noise-free",)).to_toml(tmp_path / "tiny.toml")
    result = runner.invoke(app, ["reproduce", "--scenario", str(path), "--out", str(tmp_path / "out")])
    assert result.exit_code == 0, result.output
    assert (tmp_path / "out" / "report.md").exists() and "UISE (measured)" in result.output
    bad = runner.invoke(app, ["reproduce", "no-such-model", "--out", str(tmp_path)])
    assert bad.exit_code == 2 and "unknown name" in bad.output
    none = runner.invoke(app, ["reproduce", "closed-form", "--out", str(tmp_path)])
    assert none.exit_code == 2 and "has no study()" in none.output


def test_reproduce_runs_the_study_of_a_model_file(tmp_path):
    from pathlib import Path

    reactor = Path(__file__).resolve().parents[1] / "examples" / "reactor.py"
    args = ["reproduce", str(reactor), "--runs", "1", "--steps", "60", "--solver", "gn", "--out", str(tmp_path)]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    report = (tmp_path / "report.md").read_text()
    assert report.startswith("# reactor:") and "UISE (certified)" in report and "EKF (tuned)" in report


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
    again = runner.invoke(app, args)
    assert again.exit_code == 0 and "2 of 2 tasks stored" in again.output


def test_bench_runs_only_the_chosen_estimator_and_window_length(tmp_path):
    import json

    out = tmp_path / "bench.json"
    result = runner.invoke(app, ["bench", "-N", "3", "--estimator", "standard MHE", "--json", str(out)])
    assert result.exit_code == 0, result.output
    records = json.loads(out.read_text())
    assert {(r["estimator"], r["N"]) for r in records} == {("standard MHE", 3)}
    assert {"ipopt", "gn", "rti"} <= {r["solver"] for r in records}


@pytest.mark.parametrize("args", [["--estimator", "EKF"], ["-N", "0"]], ids=["estimator", "horizon"])
def test_bench_rejects_unknown_estimators_and_window_lengths_before_running(args):
    result = runner.invoke(app, ["bench", *args])
    assert result.exit_code == 2 and "expected" in result.output
    assert "cpu ms" not in result.output  # no table was started


def test_bench_quick_writes_one_record_per_estimator_and_backend(tmp_path):
    import json

    out = tmp_path / "bench.json"
    result = runner.invoke(app, ["bench", "--quick", "--json", str(out)])
    assert result.exit_code == 0, result.output
    records = json.loads(out.read_text())
    keys = {"estimator", "solver", "N", "median_ms", "p95_ms", "max_ms", "iterations", "max_dev_vs_ipopt",
            "max_cost_excess_vs_ipopt", "closed_loop_dev_vs_ipopt", "speedup_vs_ipopt", "median_dev_vs_ipopt",
            "windows_compared", "windows_dev_above_1e-6", "windows_cost_above_1e-8", "median_cpu_ms", "p95_cpu_ms",
            "max_cpu_ms", "cpu_ratio_vs_ipopt", "median_solve_ms", "samples", "fallbacks", "load"}  # fmt: skip
    from uiest.experiments.solver_bench import _dompc_available

    # 3 estimators x 3 backends, plus the do-mpc peer of the standard MHE where do-mpc is installed
    assert len(records) == 9 + _dompc_available() and all(keys <= set(r) for r in records)
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
