"""A study's finished runs, written as each one finishes, so that an interrupted study resumes.

:func:`~uiest.experiments.runner.run_study` with ``store=FOLDER`` writes each finished (case, run) to
``FOLDER/<key>.pickle`` at once (to a temporary name, then renamed: a run file is whole or absent) and,
on a later call, reads back the runs stored under the same keys instead of computing them. The key
hashes the scenario (all but its number of runs: run r is the same run in a study of 2 or 20 runs), the
case, the run, the window backend, the code version (:func:`~uiest.experiments.provenance.code_version`)
and the SHA-256 of the model file's bytes (:func:`~uiest.experiments.provenance.model_digest`): an edited
model file, other code or another backend is computed again, never read from the store. A file that
cannot be read, or holds another run, is moved to ``FOLDER/corrupt/`` and its run computed again.

Run files are Python pickles (they hold the estimators' results as objects): reading one runs code, as
loading a model file does. Resume only from output folders you trust (your own).
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import pickle
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from uiest import models
from uiest.atomic import write_bytes
from uiest.errors import OptionError
from uiest.experiments import provenance
from uiest.experiments.scenario import Scenario
from uiest.paths import writable_folder

__all__ = ["StudyStore"]

SUFFIX = ".pickle"


@dataclass(frozen=True)
class StudyStore:
    """Where the finished runs of one study (its scenario and backend) are kept.

    Attributes
    ----------
    folder : Path
        The run files' folder (``uiest reproduce``: ``OUT/runs``).
    scenario : Scenario
        The study; its model must be a built-in name or a model file (whose bytes key the runs).
    solver : str
        The window backend every estimator uses.

    """

    folder: Path
    scenario: Scenario
    solver: str

    def __post_init__(self) -> None:
        object.__setattr__(self, "folder", Path(self.folder))
        if not models.loadable_elsewhere(self.scenario.model):
            raise OptionError(
                f"store: runs are stored only for a built-in model or a model file (their code keys the stored "
                f"runs); {self.scenario.model!r} was registered at run time"
            )

    @functools.cached_property
    def identity(self) -> list[Any]:
        """What every run's key covers besides (case, run): the keyed scenario, backend, code, model file bytes.

        The scenario as :func:`~uiest.experiments.provenance.keyed_scenario` keys it (no run count, no file path).
        """
        data = provenance.keyed_scenario(self.scenario)
        return [data, self.solver, provenance.code_version(), provenance.model_digest(self.scenario.model)]

    def key(self, case: str, run: int) -> str:
        """The run's key (20 hex digits): scenario but its run count, case, run, backend, code, model file bytes."""
        payload = json.dumps([*self.identity, case, run], sort_keys=True, default=str)
        return hashlib.sha256(payload.encode()).hexdigest()[:20]

    def path(self, case: str, run: int) -> Path:
        """The run's file."""
        return self.folder / f"{self.key(case, run)}{SUFFIX}"

    def prepare(self) -> None:
        """Create the folder and check it is writable (OptionError naming ``store`` otherwise)."""
        writable_folder(self.folder, "store")

    def stored(self) -> list[tuple[str, int]]:
        """The study's (case, run) pairs that have a run file (not read: :meth:`load` checks it)."""
        return [
            (case, run)
            for case in self.scenario.cases
            for run in range(self.scenario.runs)
            if self.path(case, run).is_file()
        ]

    def load(self, case: str, run: int, expected: type | None = None) -> Any | None:
        """The stored outcome of (case, run), or None (no file, or a damaged one, which is set aside).

        ``expected``: the outcome's type; a file holding anything else is damaged too.
        """
        path = self.path(case, run)
        if not path.is_file():
            return None
        try:
            with path.open("rb") as file:
                record = pickle.load(file)  # the user's own output folder (module docstring)
            if not isinstance(record, dict) or record.get("key") != path.stem:
                raise ValueError("the file holds another run")
            if expected is not None and not isinstance(record["outcome"], expected):
                raise TypeError(f"the file holds a {type(record['outcome']).__name__}")
        except Exception as exc:  # any damage: set it aside, the run is computed again
            aside = self.folder / "corrupt"
            aside.mkdir(exist_ok=True)
            target = aside / f"{path.stem}.{time.time_ns()}{SUFFIX}"
            os.replace(path, target)
            warnings.warn(f"runs: the stored run file {path.name} could not be read ({type(exc).__name__}); set aside "
                          f"as {target} and computed again", UserWarning, stacklevel=2)  # fmt: skip
            return None
        return record["outcome"]

    def save(self, case: str, run: int, outcome: Any) -> Path:
        """Write ``outcome`` as the run file of (case, run), whole or not at all (StorageError naming it)."""
        path = self.path(case, run)
        data = pickle.dumps({"key": path.stem, "outcome": outcome}, protocol=pickle.HIGHEST_PROTOCOL)
        return write_bytes(path, data)
