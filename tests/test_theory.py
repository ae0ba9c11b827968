"""The paper's labels: every label in uiest.theory has words and a row in docs/theory-map.md, no other module
of src/ holds one, and none reaches the strings users read (guarantees, reasons, errors, `uiest analyse` and
`uiest estimate`)."""

import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from uiest import simulate, theory
from uiest.cli import app
from uiest.detectability import certify_delta_ioss, certify_reduced_model, certify_strong_detectability
from uiest.errors import ModelError
from uiest.estimators import UISE, StandardMHE, TwoStageUISE
from uiest.models import get, linear
from uiest.reduction import reduce_quasi_state_affine

ROOT = Path(__file__).resolve().parents[1]
LABEL = re.compile(r"\b(?:theo|eq|ass|lem|prop|def|sec|rem|cor):[A-Za-z_][A-Za-z0-9_-]*")
"""A LaTeX label of the paper as it is written in the sources."""
USER_LABEL = re.compile(r"\b(theo|eq|ass|lem|prop|def|sec|rem|cor):[A-Za-z_]")
"""What must not appear in a string a user reads."""


def _theory_map_rows() -> dict[str, str]:
    """Each label of docs/theory-map.md's tables with its row (the label cell is `` `label` ``)."""
    rows = {}
    for line in (ROOT / "docs" / "theory-map.md").read_text().splitlines():
        found = re.match(r"\|\s*`([^`]+)`\s*\|", line)
        if found:
            rows[found.group(1)] = line
    return rows


def _named_results() -> dict[str, str]:
    return {name: value for name, value in vars(theory).items() if name.isupper() and name != "CITATION"}


def test_every_named_result_has_its_number_in_the_theory_map():
    rows = "\n".join(_theory_map_rows().values())
    assert len(_theory_map_rows()) >= 20
    for name, words in _named_results().items():
        number = re.search(r"\((\w+\.? [^ ]+) of Guo et al\.\)$", words)
        assert number, (name, words)
        if name != "ALGEBRAIC_TWO_STAGE":  # Remark 4.9 has no label, hence no row
            assert number.group(1) in rows, (name, words)
        assert USER_LABEL.search(words) is None


def test_no_label_in_src():
    """Docstrings, comments and strings name results by their numbers and words; the theory map holds the labels."""
    found = [f"{path.relative_to(ROOT)}:{number}: {line.strip()}"
             for path in sorted((ROOT / "src").rglob("*.py"))
             for number, line in enumerate(path.read_text().splitlines(), 1)
             if re.search(r"\b(?:theo|eq|ass|lem|prop|rem|def|cor|sec|fig|tab):[A-Za-z_]", line)]  # fmt: skip
    assert found == []


def test_the_named_results_read_as_words():
    assert theory.FULL_ORDER_GUARANTEE == "the full-order UISE guarantee (Theorem 3.6 of Guo et al.)"
    assert theory.TWO_STAGE_HORIZON.endswith("(Eq. (31) of Guo et al.)")


@pytest.fixture(scope="module")
def linear_model():
    """x+ = A x + B w, y = C x + v with matching (rank C B = rank B = 1) and its zero 0.5."""
    A, B, C = np.array([[0.6, 0.2], [0.0, 0.5]]), [[1.0], [0.0]], [[1.0, 0.0]]
    return linear.linear_system(A, B, C, x_bounds=(-10, 10), v_bounds=(-0.01, 0.01), w_range=(-0.5, 0.5))


def _guarantee_strings(estimator) -> list[str]:
    g = estimator.guarantee
    return [g.theorem, g.reason, str(g)]


def test_guarantees_reasons_and_errors_name_results_in_words(linear_model):
    strong = certify_strong_detectability(linear_model)
    reduced = reduce_quasi_state_affine(linear_model)
    reduced_cert = certify_reduced_model(reduced)
    estimators = {
        "uise": UISE(linear_model, certificate=strong),
        "uise, short": UISE(linear_model, certificate=strong, N=1),
        "standard mhe": StandardMHE(linear_model, certificate=certify_delta_ioss(linear_model), N=10),
        "two-stage": TwoStageUISE(reduced, certificate=reduced_cert),
        "two-stage, short": TwoStageUISE(reduced, certificate=reduced_cert, N=1),
    }
    assert estimators["uise"].guaranteed and estimators["two-stage"].guaranteed
    assert not estimators["uise, short"].guaranteed and not estimators["two-stage, short"].guaranteed
    texts = {name: _guarantee_strings(est) for name, est in estimators.items()}
    assert "too short for the full-order UISE horizon condition (Eq. (13)" in texts["uise, short"][1]
    assert "too short for the two-stage UISE horizon condition" in texts["two-stage, short"][1]
    with pytest.raises(ModelError) as refused:  # no matching: the unknown input skips the output
        reduce_quasi_state_affine(linear.linear_system(np.diag([0.5, 0.5]), [[0.0], [1.0]], [[1.0, 0.0]]))
    texts["reduction refused"] = [str(refused.value)]
    for name, strings in texts.items():
        for text in strings:
            assert USER_LABEL.search(text) is None, (name, text)


@pytest.mark.slow
def test_the_cli_analyse_and_estimate_print_no_label(tmp_path):
    runner = CliRunner()
    analysed = runner.invoke(app, ["analyse", "closed-form"], terminal_width=300)
    assert analysed.exit_code == 0, analysed.output
    entry = get("closed-form")
    setup = entry.simulation()
    truth = simulate(entry.build(), setup.x0, 30, u=setup.u, w=setup.w, v=setup.noise, seed=3)
    data = tmp_path / "data.csv"
    truth.to_pandas().to_csv(data)
    env = {**os.environ, "COLUMNS": "200", "PYTHONPATH": str(ROOT / "src")}
    estimated = subprocess.run([sys.executable, "-m", "uiest", "estimate", "closed-form", "--data", str(data), "--out",
                                str(tmp_path / "out"), "--estimator", "uise"],
                               capture_output=True, text=True, env=env, check=True)  # fmt: skip
    assert "holds, bound x1" in estimated.stdout  # the table with the guarantee is in what was read
    for output in (analysed.output, estimated.stdout + estimated.stderr):
        assert USER_LABEL.search(output) is None, output
