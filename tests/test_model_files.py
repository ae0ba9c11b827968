"""Loading a model file: it never replaces another model, and nothing it raises ends the program untyped."""

import pytest
from typer.testing import CliRunner

from uiest import models
from uiest.cli import app
from uiest.errors import ModelError
from uiest.experiments.study_model import study_model

runner = CliRunner()
ONE_STATE = (
    "import numpy as np\nfrom uiest.models import linear\n"
    "system = linear.linear_system(np.array([[0.5]]), [[1.0]], [[1.0]], x_bounds=(-1, 1), v_bounds=(-0.1, 0.1))\n"
)


@pytest.fixture
def registry():
    """The registry as it was before the test, restored after it."""
    saved, files = dict(models._REGISTRY), dict(models._FILES)
    yield
    models._REGISTRY.clear()
    models._REGISTRY.update(saved)
    models._FILES.clear()
    models._FILES.update(files)


@pytest.mark.parametrize("built_in", sorted(models.BUILT_IN))
def test_a_file_named_like_a_built_in_is_registered_under_its_path(tmp_path, registry, built_in):
    path = tmp_path / f"{built_in}.py"
    path.write_text(ONE_STATE)
    nx = models.get(built_in).build().nx
    entry = models.load(path)
    assert entry.name == str(path) and entry.build().nx == 1
    assert models.get(built_in).build().nx == nx > 1  # the built-in is still the built-in ...
    assert study_model(built_in).system.nx == nx  # ... for a study naming it, later in the same process
    assert models.load(path).name == str(path)  # loading the file again replaces only its own entry


def test_a_file_keeps_its_short_name_and_never_replaces_another_file_or_registration(tmp_path, registry):
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    first, second = tmp_path / "a" / "plant.py", tmp_path / "b" / "plant.py"
    first.write_text(ONE_STATE)
    second.write_text(ONE_STATE.replace("0.5", "0.25"))
    assert models.load(first).name == "plant" and models.load(first).name == "plant"
    assert models.load(second).name == str(second) and models.get("plant").summary == f"model file {first}"
    models.register("own", lambda: models.get("closed-form").build())
    own = tmp_path / "own.py"
    own.write_text(ONE_STATE)
    assert models.load(own).name == str(own) and models.get("own").build().nx == 2


@pytest.mark.parametrize(
    "body, raised",
    [
        ("import sys\nsys.exit()\n", "SystemExit"),
        ("import sys\nsys.exit(0)\n", "SystemExit"),
        ("raise SystemExit(3)\n", "SystemExit"),
        ("class Stop(BaseException):\n    pass\nraise Stop('no')\n", "Stop"),
    ],
    ids=["exit", "exit-0", "exit-3", "base-exception"],
)
def test_a_model_file_that_exits_at_import_is_a_typed_error_naming_it(tmp_path, registry, body, raised):
    path = tmp_path / "quits.py"
    path.write_text(body)
    with pytest.raises(ModelError, match=f"model: importing {path} raised {raised}"):
        models.load(path)
    out = tmp_path / "out"
    result = runner.invoke(app, ["simulate", str(path), "--out", str(out)])
    assert result.exit_code == 2, result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: model: importing {path} raised {raised}")


def test_a_model_files_build_that_exits_is_a_typed_error_and_an_interrupt_passes(tmp_path, registry):
    path = tmp_path / "quits_later.py"
    path.write_text("import sys\ndef build():\n    sys.exit('bye')\n")
    with pytest.raises(ModelError, match=f"model: build\\(\\) in {path} raised SystemExit: bye"):
        models.load(path).build()
    interrupted = tmp_path / "interrupted.py"
    interrupted.write_text("raise KeyboardInterrupt\n")
    with pytest.raises(KeyboardInterrupt):  # Ctrl-C during an import stops the program, as everywhere
        models.load(interrupted)
