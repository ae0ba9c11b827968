"""Sweep designs: which scenario parameters vary, over which values, as tasks with stable keys.

A :class:`Sweep` is a base :class:`~uiest.experiments.scenario.Scenario` and a design over
the parameters in ``SWEEPABLE`` (a full grid and/or random points). Every value is checked
against the parameter's type and the scenario before any run starts. Every (design point,
case, run) is one :class:`Task`; its key hashes the scenario, the point, the case, the run, the
backend and the code version, so results of other code are never taken for these.
"""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from itertools import product
from pathlib import Path
from typing import Any

import numpy as np

from uiest.checks import shown
from uiest.errors import OptionError
from uiest.experiments.provenance import code_version, keyed_scenario, model_digest
from uiest.experiments.scenario import Scenario, model_beside, read_toml
from uiest.window import DEFAULT_BACKEND
from uiest.window.backends import BACKENDS

__all__ = ["SWEEPABLE", "Sweep", "Task", "apply"]

SWEEPABLE = ("N", "mu", "output_weight", "noise_scale", "w_gain", "initial_error", "steps", "estimator", "solver")
"""Parameters a sweep may vary: N, mu, output_weight apply to every estimator; estimator keeps only
the named one; solver selects the window backend; the rest are Scenario fields."""

INTEGER = ("N", "steps")
MAX_INTEGER = {"N": 100_000, "steps": 10_000_000}
"""Sanity bounds of the integer parameters (a larger horizon or run is a typo, not a study)."""
CHOICES = ("estimator", "solver")
MAX_TASKS = 100_000
"""Most tasks (design points x cases x runs) one sweep may hold: its points are generated and checked up front."""


def _check_value(name: str, value: Any, estimators: set[str]) -> Any:
    """``value`` if it is a valid value of the swept parameter ``name``, else OptionError."""
    where = f"sweep.grid.{name}"
    if name in CHOICES:
        allowed = sorted(estimators) if name == "estimator" else list(BACKENDS)
        if value not in allowed:
            raise OptionError(f"{where}: expected one of {allowed}, got {value!r}")
        return value
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise OptionError(f"{where}: expected a number, got {value!r}")
    if name in INTEGER:
        if not isinstance(value, int) or not 1 <= value <= MAX_INTEGER[name]:
            raise OptionError(f"{where}: expected an integer in [1, {MAX_INTEGER[name]}], got {value!r}")
        return value
    value = float(value)
    valid = {
        "mu": 0.0 < value < 1.0,
        "output_weight": math.isfinite(value) and value > 0.0,
        "noise_scale": math.isfinite(value) and value >= 0.0,
        "w_gain": math.isfinite(value),
        "initial_error": math.isfinite(value) or math.isnan(value),
    }[name]
    if not valid:
        expected = {"mu": "a number in (0, 1)", "output_weight": "a finite number > 0",
                    "noise_scale": "a finite number >= 0"}.get(name, "a finite number")  # fmt: skip
        raise OptionError(f"{where}: expected {expected}, got {value!r}")
    return value


def _check_range(name: str, bounds: Any) -> tuple[float, float]:
    where = f"sweep.ranges.{name}"
    if name in CHOICES:
        raise OptionError(f"{where}: {name} takes a list of values in sweep.grid, not a range")
    try:
        low, high = bounds
    except (TypeError, ValueError):
        raise OptionError(f"{where}: expected [low, high], got {bounds!r}") from None
    for value in (low, high):
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
            raise OptionError(f"{where}: expected finite numbers [low, high], got {bounds!r}")
    if low > high:
        raise OptionError(f"{where}: expected low <= high, got [{low}, {high}]")
    for value in (low, high):
        _check_value(name, int(value) if name in INTEGER and float(value).is_integer() else value, set())
    return float(low), float(high)


@dataclass(frozen=True)
class Sweep:
    """A design over scenario parameters.

    Attributes
    ----------
    scenario : Scenario
        The base study (its runs, cases, seed and estimators).
    grid : dict
        Parameter -> non-empty list of values; the full factorial product is swept.
    random : int
        Number of additional random points, drawn (seeded by the scenario seed) uniformly from
        ``ranges`` (integers for N and steps, log-uniform for output_weight).
    ranges : dict
        Parameter -> (low, high) for the random points.

    """

    scenario: Scenario
    grid: dict[str, tuple[Any, ...]] = field(default_factory=dict)
    random: int = 0
    ranges: dict[str, tuple[float, float]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not isinstance(self.scenario, Scenario):
            raise OptionError(f"scenario: expected a Scenario, got {shown(self.scenario)}")
        for key, wanted in (("grid", "lists of values"), ("ranges", "[low, high] pairs")):
            if not isinstance(getattr(self, key), Mapping):
                raise OptionError(f"sweep.{key}: expected a mapping from parameters to {wanted}, got "
                                  f"{shown(getattr(self, key))}")  # fmt: skip
        for name in [*self.grid, *self.ranges]:
            if name not in SWEEPABLE:
                raise OptionError(f"sweep: {name!r} cannot be swept; expected one of {SWEEPABLE}")
        if isinstance(self.random, bool) or not isinstance(self.random, int) or self.random < 0:
            raise OptionError(f"sweep.random: expected an integer >= 0, got {self.random!r}")
        if bool(self.random) != bool(self.ranges):
            raise OptionError("sweep.random, sweep.ranges: random points need ranges, and ranges need random > 0")
        names = {spec.name for spec in self.scenario.estimators}
        grid = {}
        for name, values in self.grid.items():
            if isinstance(values, str) or not isinstance(values, list | tuple) or not values:
                raise OptionError(f"sweep.grid.{name}: expected a non-empty list of values, got {values!r}")
            grid[name] = tuple(_check_value(name, value, names) for value in values)
            if len(set(grid[name])) != len(grid[name]):
                raise OptionError(f"sweep.grid.{name}: expected distinct values, got {list(values)}")
        object.__setattr__(self, "grid", grid)
        object.__setattr__(self, "ranges", {name: _check_range(name, b) for name, b in self.ranges.items()})
        points = (math.prod(len(values) for values in grid.values()) if grid else int(not self.random)) + self.random
        count = points * len(self.scenario.cases) * self.scenario.runs
        if count > MAX_TASKS:
            raise OptionError(
                f"sweep: {count:_} tasks ({points:_} points x {len(self.scenario.cases)} cases x "
                f"{self.scenario.runs} runs); expected at most {MAX_TASKS:_}: split the design (random, grid)"
            )
        for point in self.points():  # every point must give a valid scenario
            try:
                apply(self.scenario, point)
            except OptionError as exc:
                raise OptionError(f"sweep point {point}: {exc}") from None

    def points(self) -> list[dict[str, Any]]:
        """The design points: the grid product, then the random points."""
        keys = list(self.grid)
        points = [dict(zip(keys, values, strict=True)) for values in product(*(self.grid[k] for k in keys))]
        if not keys:
            points = [{}] if not self.random else []
        rng = np.random.default_rng([self.scenario.seed, 101])
        for _ in range(self.random):
            point: dict[str, Any] = {}
            for name, (low, high) in self.ranges.items():
                if name in INTEGER:
                    point[name] = int(rng.integers(math.ceil(low), math.floor(high) + 1))
                elif name == "output_weight":
                    point[name] = float(10 ** rng.uniform(math.log10(low), math.log10(high)))
                else:
                    point[name] = float(rng.uniform(low, high))
            points.append(point)
        return points

    def tasks(self, solver: str = DEFAULT_BACKEND) -> list[Task]:
        """Every distinct (point, case, run) as a Task; ``solver`` unless the point sweeps it.

        Random points that coincide (integer ranges) are one task.
        """
        if solver not in BACKENDS:
            raise OptionError(f"solver: expected one of {list(BACKENDS)}, got {solver!r}")
        code, model = code_version(), model_digest(self.scenario.model)
        tasks: dict[str, Task] = {}
        for point in self.points():
            scenario = apply(self.scenario, point)
            for case in scenario.cases:
                for run in range(scenario.runs):
                    params = tuple(sorted(point.items()))
                    task = Task(
                        scenario=scenario,
                        params=params,
                        case=case,
                        run=run,
                        solver=point.get("solver", solver),
                        code=code,
                        model_sha256=model,
                    )
                    tasks.setdefault(task.key, task)
        return list(tasks.values())

    def to_dict(self) -> dict[str, Any]:
        """Plain data: ``{"scenario": ..., "sweep": {"grid", "random", "ranges"}}`` (TOML-ready)."""
        return {
            "scenario": self.scenario.to_dict(),
            "sweep": {
                "grid": {k: list(v) for k, v in self.grid.items()},
                "random": self.random,
                "ranges": {k: list(v) for k, v in self.ranges.items()},
            },
        }

    @classmethod
    def from_toml(cls, path: Path) -> Sweep:
        """Read ``[scenario]`` (as in Scenario TOML) and ``[sweep]`` (``grid``, ``random``, ``ranges``).

        A relative model file path is taken from the sweep file's folder; the model file is Python code
        that runs with your rights (like a ``setup.py``) in this process and in every worker.
        """
        data = read_toml(path, "sweep")
        unknown = set(data) - {"scenario", "sweep"}
        if unknown or "scenario" not in data:
            raise OptionError(f"sweep file: expected the tables 'scenario' and 'sweep', got {sorted(data)}")
        design = data.get("sweep", {})
        if not isinstance(design, dict):
            raise OptionError(f"sweep: expected a table, got {design!r}")
        bad = set(design) - {"grid", "random", "ranges"}
        if bad:
            raise OptionError(f"sweep: unknown keys {sorted(bad)}")
        for key in ("grid", "ranges"):
            if not isinstance(design.get(key, {}), dict):
                raise OptionError(f"sweep.{key}: expected a table of parameters, got {design[key]!r}")
        return cls(
            Scenario.from_dict(model_beside(data["scenario"], Path(path))),
            grid=dict(design.get("grid", {})),
            random=design.get("random", 0),
            ranges=dict(design.get("ranges", {})),
        )


def apply(scenario: Scenario, point: dict[str, Any]) -> Scenario:
    """The scenario with a design point's parameters applied."""
    estimators = scenario.estimators
    spec_changes = {k: point[k] for k in ("N", "mu", "output_weight") if k in point}
    if spec_changes:
        estimators = tuple(replace(spec, **spec_changes) for spec in estimators)
    if "estimator" in point:
        estimators = tuple(spec for spec in estimators if spec.name == point["estimator"])
    fields = {k: point[k] for k in ("noise_scale", "w_gain", "initial_error", "steps") if k in point}
    return replace(scenario, estimators=estimators, **fields)


@dataclass(frozen=True, kw_only=True)
class Task:
    """One (design point, case, run): plain data, rebuilt into a system and estimators by a worker."""

    scenario: Scenario
    params: tuple[tuple[str, Any], ...]
    case: str
    run: int
    solver: str
    code: str
    """The code version (:func:`~uiest.experiments.provenance.code_version`) the task is meant for."""
    model_sha256: str = ""
    """The SHA-256 of the scenario's model file (:func:`~uiest.experiments.provenance.model_digest`; "" for a name)."""

    @property
    def key(self) -> str:
        """Stable identifier: a hash of the scenario, point, case, run, backend, code and the model file's content.

        The scenario as :func:`~uiest.experiments.provenance.keyed_scenario` keys it (no run count, no file path).
        """
        identity = [keyed_scenario(self.scenario), list(self.params), self.case, self.run, self.solver,
                    self.code]  # fmt: skip
        payload = json.dumps(
            [*identity, self.model_sha256],
            sort_keys=True,
            default=str,
        )
        return hashlib.sha256(payload.encode()).hexdigest()[:20]
