"""The model a study runs on, resolved once: its system, default simulation, reduction, certificates, tunings.

A :class:`StudyModel` is built from a registered name, a model file or a
:class:`~uiest.models.ModelEntry` (:meth:`StudyModel.of`). Every estimator of a study is built
from it (:data:`uiest.experiments.runner.BUILDERS`): nothing is looked up by name again. The
certificates that design weights and the EKF/UKF tunings are computed on first use and kept,
failures included, so that a study computes each once (:meth:`StudyModel.prepare`) and its
workers receive them with the model's name (:meth:`StudyModel.resolved`).
"""

from __future__ import annotations

import functools
import pickle
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from uiest import models
from uiest.augmented import augmented_system
from uiest.checks import check_real
from uiest.detectability import Certificate, certify_delta_ioss, certify_reduced_model, certify_strong_detectability
from uiest.errors import CertificationError, ModelError, OptionError
from uiest.estimators.kalman import EKF, UKF
from uiest.estimators.smooth_mhe import DW_SIGMAS
from uiest.models import ModelEntry, SimulationSetup
from uiest.reduction import ReducedModel
from uiest.simulate import simulate
from uiest.system import System
from uiest.theory import LYAPUNOV_CHARACTERISATION, REDUCED_IOSS

__all__ = ["KIND_CERTIFICATE", "StudyModel", "study_model"]

KIND_CERTIFICATE = {
    "uise": LYAPUNOV_CHARACTERISATION,
    "fie": LYAPUNOV_CHARACTERISATION,
    "two-stage": REDUCED_IOSS,
    "standard-mhe": "delta-IOSS (Schiller et al. 2023)",
    "smooth-mhe": "delta-IOSS of the model with w as a state (Schiller et al. 2023)",
}
"""The certificate that designs each estimator kind's weights."""

TUNING_SEED = 12345
"""Seed of the separate simulation the EKF and UKF are tuned on (not a study run's seed)."""


@dataclass(eq=False)
class StudyModel:
    """A model resolved for a study.

    Attributes
    ----------
    name : str
        The scenario's model: a registered name or the path of a model file.
    system : System
    entry : ModelEntry
        Where the default simulation, the reduction and the Jacobian's parameters come from.
    known : dict
        Certificates ``("certificate", kind, mu)`` and tunings ``("variance", kind)`` computed
        so far, or the :class:`~uiest.errors.UiestError` their computation raised.

    """

    name: str
    system: System
    entry: ModelEntry
    known: dict[tuple[Any, ...], Any] = field(default_factory=dict, repr=False)

    @classmethod
    def of(cls, model: str | Path | ModelEntry) -> StudyModel:
        """Resolve a registered name, a model file (``.py``) or an entry; the system is built once."""
        entry = model if isinstance(model, ModelEntry) else models.load(model)
        name = entry.name if isinstance(model, ModelEntry) else str(model)
        return cls(name, entry.build(), entry)

    @property
    def setup(self) -> SimulationSetup:
        """The model's default simulation (OptionError when it has none)."""
        return self.entry.simulation()

    @functools.cached_property
    def reduction(self) -> ReducedModel:
        """The two-stage UISE's reduced model; ModelError when the model registers none."""
        if self.entry.reduction is None:
            raise ModelError(f"the two-stage UISE: the model {self.name!r} has no reduction() (T, psi)")
        return self.entry.reduction()

    def certificate(self, kind: str, mu: float, w_variance: float = 0.0) -> Certificate:
        """The certificate that designs the weights of an estimator of ``kind`` (computed once).

        Certified at ``mu`` when ``mu`` is at least the smallest rate found, else at the
        certificate's default rate. Raises :class:`CertificationError` when it does not hold.
        ``w_variance``: the smooth-input MHE's increment variance (:meth:`increment_variance`), whose
        bound is part of the model it certifies; ignored by the other kinds.
        """
        if kind not in KIND_CERTIFICATE:
            raise OptionError(f"kind: expected one of {sorted(KIND_CERTIFICATE)}, got {kind!r}")
        rate = check_real(mu, "mu", "a number in (0, 1)")
        if kind == "smooth-mhe":
            factor = self.increment_variance(w_variance)
            return self._known(("certificate", kind, rate, factor), lambda: self._certify(kind, rate, factor))
        return self._known(("certificate", kind, rate), lambda: self._certify(kind, rate))

    def increment_variance(self, w_variance: float) -> float:
        """The smooth-input MHE's increment variance in ``w.scale^2``: ``w_variance`` if > 0, else the EKF's tuned."""
        return w_variance if w_variance > 0 else self.tuned_variance("ekf")

    def tuned_variance(self, kind: str) -> float:
        """The EKF/UKF random-walk factor (in ``w.scale^2``), tuned on a default simulation (computed once).

        The simulation is the model's default setup with seed :data:`TUNING_SEED`, not a study run's.
        """
        if kind not in ("ekf", "ukf"):
            raise OptionError(f"kind: expected 'ekf' or 'ukf', got {kind!r}")
        return self._known(("variance", kind), lambda: self._tune(kind))

    def prepare(self, specs: Any) -> None:
        """Compute what the estimator specs need (certificates, tunings) now, errors kept for their runs."""
        for spec in specs:
            try:
                if spec.weights == "certificate":
                    self.certificate(spec.kind, spec.mu, spec.w_variance)
                if spec.kind in ("ekf", "ukf", "smooth-mhe") and spec.w_variance == 0:
                    self.tuned_variance("ekf" if spec.kind == "smooth-mhe" else spec.kind)
            except Exception:  # kept in `known`: each run of the estimator records it
                pass

    def resolved(self) -> dict[tuple[Any, ...], Any]:
        """What has been computed and can be pickled (for workers that load the model by name).

        A value that cannot be pickled (an exception carrying a user's object, say) is left out:
        a worker computes it again.
        """
        shipped = {}
        for key, value in self.known.items():
            try:
                pickle.dumps(value)
            except Exception:
                continue
            shipped[key] = value
        return shipped

    def _known(self, key: tuple[Any, ...], compute: Callable[[], Any]) -> Any:
        """``compute()`` once; its exception, whatever it is, is kept and raised again (without old tracebacks)."""
        if key not in self.known:
            try:
                self.known[key] = compute()
            except Exception as exc:
                self.known[key] = exc
        value = self.known[key]
        if isinstance(value, Exception):
            raise value.with_traceback(None)
        return value

    def _certify(self, kind: str, mu: float, factor: float = 0.0) -> Certificate:
        make: Callable[[float | None], Certificate]
        if kind in ("uise", "fie"):
            theta = self.entry.jacobian_parameters() if self.entry.jacobian_parameters is not None else None
            make = lambda rate: certify_strong_detectability(self.system, rate, parameters=theta)  # noqa: E731
        elif kind == "two-stage":
            make = lambda rate: certify_reduced_model(self.reduction, mu=rate)  # noqa: E731
        elif kind == "standard-mhe":
            make = lambda rate: certify_delta_ioss(self.system, rate)  # noqa: E731
        elif kind == "smooth-mhe":
            augmented = augmented_system(self.system, DW_SIGMAS * np.sqrt(factor) * self.system.w.scale)
            make = lambda rate: certify_delta_ioss(augmented, rate)  # noqa: E731
        else:
            raise OptionError(f"estimators.kind: no certificate for {kind!r}")
        default = make(None)
        if not default.certified:
            raise CertificationError(
                f"{KIND_CERTIFICATE[kind]} of {self.name!r} does not hold ({default.status}: {default.reason}); "
                "use explicit weights"
            )
        if default.rate_min <= mu < 1.0 and mu != default.rate:
            at_mu = make(mu)
            if at_mu.certified:
                return at_mu
        return default

    def _tune(self, kind: str) -> float:

        setup = self.setup
        training = simulate(self.system, setup.x0, setup.steps, u=setup.u, w=setup.w, v=setup.noise, seed=TUNING_SEED)
        tuned = (EKF if kind == "ekf" else UKF).tuned(self.system, training, x0_prior=setup.x0)
        assert tuned.tuning is not None
        return float(tuned.tuning.chosen)


_BY_NAME: dict[str, tuple[object, StudyModel]] = {}


def study_model(name: str | Path, known: dict[tuple[Any, ...], Any] | None = None) -> StudyModel:
    """The study model of a registered name or model file, kept per process (a sweep's or a study's worker).

    ``known``: certificates and tunings the parent computed (:meth:`StudyModel.resolved`). A
    name registered again, or a model file changed since (its size or modification time), gives
    a new study model.
    """
    name = str(name)
    if name.endswith(".py"):
        try:
            stat = Path(name).stat()
        except OSError:
            stat = None  # models.load names the missing file
        version: object = None if stat is None else (stat.st_mtime_ns, stat.st_size)
    else:
        version = models.get(name)
    cached = _BY_NAME.get(name)
    if cached is None or version is None or cached[0] != version:
        entry = models.load(name)
        cached = _BY_NAME[name] = (version, StudyModel(name, entry.build(), entry))
    study = cached[1]
    for key, value in (known or {}).items():
        study.known.setdefault(key, value)
    return study
