"""Study scenarios: which model, initial states, priors, noise, length, runs, seeds and estimators.

A :class:`Scenario` is a frozen dataclass that round-trips through TOML
(:meth:`Scenario.to_toml`, :meth:`Scenario.from_toml`), so a study is a file a user can edit
and re-run (``uiest reproduce --scenario FILE.toml``).
"""

from __future__ import annotations

import math
import os
import tomllib
from collections.abc import Iterable
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Any

import tomli_w

from uiest.atomic import write_bytes
from uiest.checks import MAX_SAMPLES, check_int
from uiest.errors import OptionError
from uiest.paths import plain_name, writable_file

__all__ = ["EstimatorSpec", "Scenario", "model_beside", "read_toml"]

ESTIMATOR_KINDS = ("uise", "two-stage", "standard-mhe", "smooth-mhe", "fie", "ekf", "ukf")
CASES = ("noise-free", "noisy")
WEIGHT_SOURCES = ("explicit", "certificate")


@dataclass(frozen=True)
class EstimatorSpec:
    """One estimator of a study.

    Attributes
    ----------
    name : str
        Label in tables and figures.
    kind : str
        One of ``ESTIMATOR_KINDS``.
    N : int
        Horizon (ignored by the FIE). 0 with certificate weights: the certificate's
        ``min_horizon()``, the shortest horizon its theorem allows. The defaults of ``N``, ``mu`` and the weights
        are the paper's crop study's: give your model's own.
    mu : float
        Discount of the weights (eta for the standard and the smooth-input MHE). With certificate weights, the rate
        the certificate is designed at when it certifies there (``mu >= mu_min``), else the
        certificate's default rate (the report says which).
    output_weight, prior_weight, noise_weight, disturbance_weight : float
        Diagonal weights per scaled unit of explicit weights (see ``UISEWeights.from_scales`` and
        ``MHEWeights.from_scales``).
    weights : {"explicit", "certificate"}
        "certificate": weights from the model's certificate (strong detectability for the UISE
        and FIE, the reduced model's e-IOSS for the two-stage UISE, delta-IOSS for the standard
        MHE and, of the augmented model, for the smooth-input MHE), computed once per study; the
        estimator then states whether its theorem applies.
    w_variance : float
        EKF and UKF: the random walk's step variance in units of ``w.scale^2``; the smooth-input MHE:
        its increments' variance, in the same units; 0 (default): the EKF's or UKF's, tuned on a
        separate simulation of the model's default setup (seed 12345).

    """

    name: str
    kind: str
    N: int = 30
    mu: float = 0.48
    output_weight: float = 1e6
    prior_weight: float = 1.0
    noise_weight: float = 1.0
    disturbance_weight: float = 1.0
    weights: str = "explicit"
    w_variance: float = 0.0

    def __post_init__(self) -> None:
        if self.weights not in WEIGHT_SOURCES:
            raise OptionError(f"estimators.weights: expected one of {WEIGHT_SOURCES}, got {self.weights!r}")
        if self.kind not in ESTIMATOR_KINDS:
            raise OptionError(f"estimators.kind: expected one of {ESTIMATOR_KINDS}, got {self.kind!r}")
        least = 0 if self.weights == "certificate" else 1
        if isinstance(self.N, bool) or not isinstance(self.N, int) or least > self.N:
            raise OptionError(f"estimators.N: expected an integer >= {least}, got {self.N!r}")
        if not isinstance(self.name, str) or not self.name:
            raise OptionError(f"estimators.name: expected a non-empty string, got {self.name!r}")
        if not _number(self.mu) or not 0.0 < self.mu < 1.0:
            raise OptionError(f"estimators.mu: expected a number in (0, 1), got {self.mu!r}")
        for label in ("output_weight", "prior_weight", "noise_weight", "disturbance_weight", "w_variance"):
            value = getattr(self, label)
            if not _number(value) or not (math.isfinite(value) and value >= 0.0):
                raise OptionError(f"estimators.{label}: expected a finite number >= 0, got {value!r}")
        for label in ("mu", "output_weight", "prior_weight", "noise_weight", "disturbance_weight", "w_variance"):
            object.__setattr__(self, label, float(getattr(self, label)))  # 1000000 and 1e6 are one spec


def _number(value: object) -> bool:
    """A real number (int or float), not a bool or a string."""
    return isinstance(value, int | float) and not isinstance(value, bool)


def _numbers(value: object, name: str, *, allow_nan: bool = False) -> tuple[float, ...]:
    """A tuple of real numbers (finite unless ``allow_nan`` lets NaN through), else OptionError naming ``name``."""
    try:
        if not isinstance(value, Iterable):
            raise TypeError
        items = tuple(value)
    except TypeError:
        raise OptionError(f"{name}: expected a list of numbers, got {value!r}") from None
    out = []
    for item in items:
        if isinstance(item, str) and allow_nan and item.lower() == "nan":
            item = math.nan
        if not _number(item) or not (math.isfinite(item) or (allow_nan and math.isnan(item))):
            raise OptionError(f"{name}: expected {'numbers or nan' if allow_nan else 'finite numbers'}, got {value!r}")
        out.append(float(item))
    return tuple(out)


def _index_pairs(value: object) -> tuple[tuple[int, int], ...]:
    """``prior_from_output`` as (state, output) pairs of integers, else OptionError."""
    try:
        if not isinstance(value, Iterable):
            raise TypeError
        pairs = [tuple(pair) if isinstance(pair, Iterable) else () for pair in value]
    except TypeError:
        pairs = [()]
    checked = tuple((i, j) for i, j in (p for p in pairs if len(p) == 2) if type(i) is int and type(j) is int)
    if len(checked) != len(pairs):
        raise OptionError(f"prior_from_output: expected [state, output] integer index pairs, got {value!r}")
    return checked


@dataclass(frozen=True)
class Scenario:
    """A Monte Carlo study of estimators on a registered model.

    Attributes
    ----------
    name : str
        Name of the study (used in titles and as the default output folder ``out/<name>``): a plain name,
        without path separators, ``.`` or ``..``.
    model : str
        Registered model (``uiest.models.names()``) or the path of a model file (``.py``, see
        :func:`uiest.models.load`; in a TOML file, relative to that file's folder); its default inputs,
        unknown-input law and noise model are used. A model file is Python code that runs with your
        rights (like a ``setup.py``) wherever the study runs: in this process and in every worker.
    steps : int
        Length K of each run.
    runs : int
        Monte Carlo runs per case; run r draws x0 uniformly from ``[x0_lower, x0_upper]`` (run 0
        uses ``x0``) and noise with seed ``seed + r``.
    seed : int
        Base seed.
    cases : tuple of str
        Subset of ``("noise-free", "noisy")``.
    x0, x0_lower, x0_upper : tuple of float
        Nominal initial state and the box of the random ones (empty: the model's default x0 for
        every run).
    prior : tuple of float
        Prior of the initial state for every estimator; NaN entries are filled from the first
        measurement through ``prior_from_output``.
    prior_from_output : tuple of (state, output) index pairs
        ``x_hat_0[state] = y_0[output]`` (the paper: ``x_hat^c_0 = y^c_0``).
    settle : int
        Steps after which accuracy metrics are computed.
    focus_state : int
        The state shown in Figure 1 and named in the report (the paper: x^{d,1}).
    noise_scale : float
        Factor on the model's noise in the noisy case.
    w_gain : float
        Factor on the model's unknown input (``w = w_gain * law(k, x)``).
    initial_error : float
        NaN: the estimators' prior is ``prior``. Otherwise the prior is the true x0 plus
        ``initial_error * x.scale`` with random signs (seeded by the run), then
        ``prior_from_output`` applies.
    estimators : tuple of EstimatorSpec

    """

    name: str
    model: str
    steps: int = 300
    runs: int = 20
    seed: int = 0
    cases: tuple[str, ...] = CASES
    x0: tuple[float, ...] = ()
    x0_lower: tuple[float, ...] = ()
    x0_upper: tuple[float, ...] = ()
    prior: tuple[float, ...] = ()
    prior_from_output: tuple[tuple[int, int], ...] = ()
    settle: int = 30
    focus_state: int = 0
    noise_scale: float = 1.0
    w_gain: float = 1.0
    initial_error: float = math.nan
    estimators: tuple[EstimatorSpec, ...] = field(default_factory=tuple)

    def __post_init__(self) -> None:
        for label in ("name", "model"):
            if not isinstance(getattr(self, label), str) or not getattr(self, label):
                raise OptionError(f"{label}: expected a non-empty string, got {getattr(self, label)!r}")
        plain_name(self.name, "name")  # it names the study's output folder (uiest reproduce: out/<name>)
        for label in ("steps", "runs"):  # at most MAX_SAMPLES: a run's samples, a study's runs are stepped in Python
            object.__setattr__(self, label, check_int(getattr(self, label), label, low=1, high=MAX_SAMPLES))
        cases = (self.cases,) if isinstance(self.cases, str) else self.cases
        if not isinstance(cases, list | tuple):
            raise OptionError(f"cases: expected a list of {CASES}, got {self.cases!r}")
        object.__setattr__(self, "cases", tuple(cases))
        if not self.cases or any(case not in CASES for case in self.cases) or len(set(self.cases)) != len(self.cases):
            raise OptionError(f"cases: expected a non-empty subset of {CASES} without repeats, got {self.cases!r}")
        if not self.estimators:
            raise OptionError("estimators: expected at least one estimator")
        if not isinstance(self.estimators, list | tuple) or not all(
            isinstance(spec, EstimatorSpec) for spec in self.estimators
        ):
            raise OptionError(f"estimators: expected a list of EstimatorSpec, got {self.estimators!r:.200}")
        object.__setattr__(self, "estimators", tuple(self.estimators))
        names = [spec.name for spec in self.estimators]
        if len(set(names)) != len(names):
            raise OptionError(f"estimators: names must be unique, got {names}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise OptionError(f"seed: expected an integer >= 0, got {self.seed!r}")
        object.__setattr__(self, "prior_from_output", _index_pairs(self.prior_from_output))
        for label in ("x0", "x0_lower", "x0_upper", "prior"):
            object.__setattr__(self, label, _numbers(getattr(self, label), label, allow_nan=label == "prior"))
        for label in ("noise_scale", "w_gain", "initial_error"):
            (value,) = _numbers([getattr(self, label)], label, allow_nan=label == "initial_error")
            object.__setattr__(self, label, value)
        if len(self.x0_lower) != len(self.x0_upper):
            raise OptionError("x0_lower, x0_upper: expected the same length")
        if any(lo > hi for lo, hi in zip(self.x0_lower, self.x0_upper, strict=True)):
            raise OptionError(f"x0_lower, x0_upper: expected x0_lower <= x0_upper, got {self.x0_lower} and "
                              f"{self.x0_upper}")  # fmt: skip
        if isinstance(self.focus_state, bool) or not isinstance(self.focus_state, int) or self.focus_state < 0:
            raise OptionError(f"focus_state: expected a state index >= 0, got {self.focus_state!r}")
        if isinstance(self.settle, bool) or not isinstance(self.settle, int) or not 0 <= self.settle < self.steps:
            raise OptionError(f"settle: expected 0 <= settle < steps = {self.steps}, got {self.settle}")
        if not (self.noise_scale >= 0.0 and math.isfinite(self.noise_scale)):
            raise OptionError(f"noise_scale: expected a finite number >= 0, got {self.noise_scale!r}")
        if not math.isfinite(self.w_gain):
            raise OptionError(f"w_gain: expected a finite number, got {self.w_gain!r}")

    def check_model(self, nx: int, ny: int, x_bounds: Any = None) -> None:
        """Raise OptionError unless the sizes in this scenario fit a model with ``nx`` states and ``ny`` outputs.

        With ``x_bounds`` (the model's X, a Box) the initial states x0 and the box [x0_lower, x0_upper] must lie in X.
        """
        for label in ("x0", "x0_lower", "x0_upper", "prior"):
            value = getattr(self, label)
            if value and len(value) != nx:
                raise OptionError(f"{label}: expected {nx} values (the model's states), got {len(value)}")
            if value and label != "prior" and x_bounds is not None and not x_bounds.contains(value):
                raise OptionError(f"{label}: expected a point in X = {x_bounds}, got {list(value)}")
        if not 0 <= self.focus_state < nx:
            raise OptionError(f"focus_state: expected a state index in [0, {nx}), got {self.focus_state}")
        for state, output in self.prior_from_output:
            if not (0 <= state < nx and 0 <= output < ny):
                raise OptionError(
                    f"prior_from_output: expected (state in [0, {nx}), output in [0, {ny})) pairs, "
                    f"got ({state}, {output})"
                )

    def with_overrides(self, **changes: Any) -> Scenario:
        """A copy with fields replaced (None values are ignored); unknown names raise OptionError."""
        known = {f.name for f in fields(self)}
        unknown = set(changes) - known
        if unknown:
            raise OptionError(f"unknown scenario fields: {sorted(unknown)}")
        return replace(self, **{k: v for k, v in changes.items() if v is not None})

    def to_dict(self) -> dict[str, Any]:
        """Plain data (TOML has no null or NaN: NaN priors are written as the string "nan")."""
        data = asdict(self)
        data["prior"] = ["nan" if math.isnan(v) else v for v in self.prior]
        data["initial_error"] = "nan" if math.isnan(self.initial_error) else self.initial_error
        data["prior_from_output"] = [list(pair) for pair in self.prior_from_output]
        return data

    def to_toml(self, path: Path | str, *, relative_to: Path | str | None = None) -> Path:
        """Write the scenario as TOML, whole or not at all (OptionError or StorageError naming ``path``).

        A model file's path is written relative to ``relative_to`` (default ``path``'s folder, from which
        :meth:`from_toml` reads it; another folder where the file will be moved there, as a staged report is).
        """
        path = writable_file(Path(path), "path")
        data = self.to_dict()
        if is_model_file(self.model):
            folder = path.parent if relative_to is None else Path(relative_to)
            data["model"] = os.path.relpath(os.path.abspath(self.model), os.path.abspath(folder))
        return write_bytes(path, tomli_w.dumps(data).encode())

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Scenario:
        """Build from plain data (as read from TOML); unknown keys raise OptionError."""
        if not isinstance(data, dict):
            raise OptionError(f"scenario: expected a table, got {data!r}")
        known = {f.name for f in fields(cls)}
        unknown = set(data) - known
        if unknown:
            raise OptionError(f"scenario: unknown keys {sorted(unknown)}")
        spec_fields = {f.name for f in fields(EstimatorSpec)}
        raw_specs = data.get("estimators", [])
        if not isinstance(raw_specs, list) or not all(isinstance(raw, dict) for raw in raw_specs):
            raise OptionError(f"estimators: expected a list of tables ([[scenario.estimators]]), got {raw_specs!r}")
        estimators = []
        for raw in raw_specs:
            bad = set(raw) - spec_fields
            if bad:
                raise OptionError(f"estimators: unknown keys {sorted(bad)}")
            missing = {"name", "kind"} - set(raw)
            if missing:
                raise OptionError(f"estimators: each needs {sorted(missing)}")
            estimators.append(EstimatorSpec(**raw))
        missing = {"name", "model"} - set(data)
        if missing:
            raise OptionError(f"scenario: missing keys {sorted(missing)} (an empty or partial scenario table)")
        values = dict(data)
        values["estimators"] = tuple(estimators)
        return cls(**values)

    @classmethod
    def from_toml(cls, path: Path) -> Scenario:
        """Read a scenario written by :meth:`to_toml` (or by hand); a relative model file path is taken from its folder.

        A model file is Python code: loading the scenario's model runs it, with your rights (like a
        ``setup.py``), in this process and in every worker. Run scenarios whose model files you trust.
        """
        data = read_toml(path, "scenario")
        if isinstance(data.get("scenario"), dict):  # unknown at the top level: the table a sweep file nests it in
            unknown = sorted(set(data) - {f.name for f in fields(cls)})
            raise OptionError(
                f"scenario: unknown keys {unknown}: {path} looks like a sweep file (a [scenario] table); run it with "
                "`uiest sweep`, or move the [scenario] table's keys to the top level"
            )
        return cls.from_dict(model_beside(data, Path(path)))


def is_model_file(model: object) -> bool:
    """Whether a scenario's ``model`` names a model file (``.py``) rather than a registered model."""
    return isinstance(model, str) and model.endswith(".py")


def model_beside(data: Any, path: Path) -> Any:
    """``data`` (a scenario table read from ``path``) with a relative model file path taken from ``path``'s folder."""
    if isinstance(data, dict) and is_model_file(data.get("model")) and not Path(data["model"]).is_absolute():
        data = {**data, "model": str(Path(path).parent / data["model"])}
    return data


def read_toml(path: Path, what: str) -> dict[str, Any]:
    """The table of a TOML file, or OptionError naming ``what`` and why it cannot be read."""
    try:
        return tomllib.loads(Path(path).read_text())
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise OptionError(f"{what}: cannot read {path}: {exc}") from exc
