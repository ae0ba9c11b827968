"""What every certificate is: a verdict, a rate, a quadratic storage, weights, a horizon, a check.

:class:`Certificate` is the base of :class:`~uiest.detectability.StrongDetectability`,
:class:`~uiest.detectability.ReducedIOSS`, :class:`~uiest.detectability.DeltaIOSS` and
:class:`~uiest.detectability.LinearStrongDetectability`. Storage matrices are computed in
scaled coordinates ``z / scale`` and given in original units by :attr:`Certificate.P`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from uiest.box import Box, FloatArray
from uiest.checks import check_samples, check_seed
from uiest.detectability.tradeoff import DEFAULT_LEVELS, Tradeoff, tabulate
from uiest.errors import CertificationError, OptionError

if TYPE_CHECKING:
    from uiest.detectability.falsify import Falsification

__all__ = [
    "DEFAULT_MAX_CONDITION",
    "STATUS_OF",
    "Certificate",
    "CertificateStatus",
    "MuCertificate",
    "StrongDetectabilityBase",
    "Verification",
    "check_rate",
    "horizon_condition",
    "quad",
    "sample_pairs",
    "state_labels",
    "strong_horizon",
    "verdict",
]


class CertificateStatus(StrEnum):
    """The statuses a certificate can end in (compare with the strings or the members).

    ``INFEASIBLE`` only when the solver solved the margin problem to optimality with a non-positive
    margin (within the stated bound on cond(P)), at a cover's vertices and at the sampled Jacobians
    themselves; ``UNDECIDED`` when that happened at the vertices only; ``NOT_PROVED`` when the LMIs
    hold but an ingredient was sampled (a sampled cover, asked for, or a domain bounded at a grid);
    ``REFUTED`` when the adversarial search found a pair that violates the inequality the LMIs claimed.
    """

    CERTIFIED = "certified"
    INFEASIBLE = "infeasible"
    SOLVER_FAILED = "solver failed"
    BELOW_RATE = "below the smallest rate"
    RECHECK_FAILED = "re-check failed"
    UNDECIDED = "undecided"
    NOT_PROVED = "holds at the samples, not proved"
    REFUTED = "refuted"


CERTIFIED, INFEASIBLE, SOLVER_FAILED, BELOW_RATE, RECHECK_FAILED, UNDECIDED, NOT_PROVED, REFUTED = CertificateStatus

STATUS_OF = {"feasible": CERTIFIED, "infeasible": INFEASIBLE, "solver failed": SOLVER_FAILED,
             "below mu_min": BELOW_RATE, "re-check failed": RECHECK_FAILED, "undecided": UNDECIDED}  # fmt: skip
"""Certificate status of each solver outcome (:mod:`uiest.detectability.lmi` and the LMI modules)."""


def verdict(
    outcome: str, reason: str, *, unproved: str = "", falsification: Falsification | None = None
) -> tuple[bool, CertificateStatus, str]:
    """``(certified, status, reason)`` of an LMI outcome once the adversarial search and the ingredients are known.

    A solved LMI is "refuted" when the search found a violating pair, "holds at the samples, not
    proved" when ``unproved`` names a sampled ingredient, else "certified".
    """
    status = CertificateStatus(STATUS_OF.get(outcome, SOLVER_FAILED))
    if status != CERTIFIED:
        return False, status, reason
    solved = reason.removeprefix("certified: ")
    if falsification is not None and falsification.refuted:
        return False, REFUTED, f"{falsification.text()}, although the LMIs hold at the cover's vertices ({solved})"
    if unproved:
        return False, NOT_PROVED, f"{NOT_PROVED}: {unproved}; the LMIs hold at the vertices: {solved}"
    return True, CERTIFIED, reason


DEFAULT_MAX_CONDITION = 1e6
"""Default bound on cond(P) (scaled coordinates) of every certificate's rate problem and design.

A larger bound can buy a faster rate (states seen only through a weak coupling need an ill-conditioned
storage), paid in the weights: the estimator's cost then weighs outputs and noise up to cond(P) times more
against its prior, its noise gain grows and its window problem spans more digits. 1e6 keeps those weights
within what the double-precision window solvers resolve and is where every known answer is reached (a
linear system's ``max |zero|^2`` needs a well-conditioned P); :meth:`Certificate.tradeoff` shows what a
larger bound buys for a given model, and ``max_condition=`` asks for it.
"""


def strong_horizon(mu: float, condition: float) -> int:
    r"""Smallest N with ``8 mu^N a2 / a1 < 1`` (Eq. (13) for ``alpha_i(r) = a_i r^2``).

    ``(2 mu^N alpha_2 o 2 alpha_1^-1)(r) = 8 mu^N (a2 / a1) r`` with ``alpha_1^-1(s) = sqrt(s / a1)``;
    ``condition = a2 / a1``.
    """
    return int(np.floor(np.log(8.0 * condition) / np.log(1.0 / mu))) + 1


def horizon_condition(mu: float, N: int) -> float:
    """The bound on cond(P) below which :func:`strong_horizon` is at most N: ``8 mu^N cond < 1``."""
    return float(mu) ** -float(N) / 8.0


@dataclass(frozen=True, kw_only=True)
class Verification:
    """Outcome of ``certificate.verify(...)``.

    Attributes
    ----------
    worst_ratio : float
        Largest ``LHS / RHS`` of the certificate's incremental inequality over the pairs
        (<= 1: the inequality held on every pair; NaN: nothing was tested).
    pairs_used : int
        Pairs tested.
    pairs_drawn : int
        Pairs drawn.
    note : str
        What the ratio measures, or why nothing was tested.

    """

    worst_ratio: float
    pairs_used: int
    pairs_drawn: int
    note: str

    @property
    def holds(self) -> bool:
        """True when pairs were tested and the worst ratio is at most 1 (+1e-9)."""
        return self.pairs_used > 0 and self.worst_ratio <= 1.0 + 1e-9


@dataclass(frozen=True, eq=False, kw_only=True)
class Certificate:
    """A certificate's verdict, rate and quadratic storage ``V = |z - z~|_P^2``.

    Attributes
    ----------
    certified : bool
        True only when the inequality is proved on the whole domain: the LMIs were solved at the
        vertices of an exact cover, the independent numpy re-check passed, and the adversarial
        search (``falsification``) found no violating pair.
    status : CertificateStatus
        One of "certified", "infeasible" (proved by the solver), "solver failed",
        "below the smallest rate" (a given rate below the one found), "re-check failed",
        "holds at the samples, not proved" (a sampled ingredient), "refuted" (a violating pair was
        found), and "undecided" (infeasible only at a cover's vertices, not at the sampled Jacobians
        themselves: "infeasible" needs both).
    reason : str
        One sentence with the numbers.
    rate, rate_min : float
        The discount of the certificate's inequality (mu or eta) and the smallest one found.
    P_scaled : ndarray (n, n)
        Storage matrix in scaled coordinates (NaN when the LMIs were not solved; the solution found
        when they were, also for a certificate "refuted" or "holds at the samples, not proved").
    scale : ndarray (n,)
        The scales of the certificate's state: ``P = P_scaled / outer(scale, scale)``.
    solve_time : float
        Seconds, from the call to the result.
    coverage : str
        How the domain was covered, in words (with the numbers).
    cover_kind : str
        The cover's kind as data: "constant", "exact by entries", "parameter box", "sampled cover", or
        "exact" (a linear system's one Jacobian).
    sound : bool
        True when every ingredient is proved over the whole domain (the vertices cover it; for the
        dissipation certificates, the output Jacobian is constant); False when one was sampled
        (``coverage`` says which; the certificate is then not ``certified``).
    margin : float
        Smallest eigenvalue margin of the re-check, relative to ``||P||``: > 0 when certified, or (strong
        detectability) negative within the direct check's rounding tolerance, which ``reason`` then names.
    falsification : Falsification or None
        The adversarial search run before the certificate was returned: its size (pairs, local
        searches) and the worst ratio found (None when the LMIs were not solved, so nothing was claimed).

    """

    certified: bool
    status: CertificateStatus
    reason: str
    rate: float
    rate_min: float
    P_scaled: FloatArray
    scale: FloatArray
    solve_time: float
    coverage: str
    sound: bool
    margin: float
    falsification: Falsification | None = field(default=None, kw_only=True)
    cover_kind: str = field(default="", kw_only=True)

    kind: ClassVar[str] = "certificate"

    def __post_init__(self) -> None:
        object.__setattr__(self, "status", CertificateStatus(self.status))

    @property
    def P(self) -> FloatArray:
        """Storage matrix in original units: ``V = |z - z~|_P^2``."""
        return self.P_scaled / np.outer(self.scale, self.scale)

    @property
    def alpha_1_scaled(self) -> float:
        """``lambda_min(P_scaled)`` (NaN when the LMIs were not solved)."""
        return _eig(self.P_scaled, 0)

    @property
    def alpha_2_scaled(self) -> float:
        """``lambda_max(P_scaled)`` (NaN when the LMIs were not solved)."""
        return _eig(self.P_scaled, -1)

    @property
    def condition(self) -> float:
        """Condition number of ``P_scaled`` (NaN when the LMIs were not solved)."""
        return self.alpha_2_scaled / self.alpha_1_scaled

    def require(self, what: str) -> None:
        """Raise :class:`CertificationError` for ``what`` unless the certificate holds."""
        if not self.certified:
            raise CertificationError(f"{what}: the certificate does not hold ({self.status}: {self.reason})")

    def min_horizon(self) -> int:
        """Smallest horizon for which the estimator's theorem applies; raises when not certified."""
        self.require("min_horizon")
        return self._horizon()

    def _horizon(self) -> int:
        raise NotImplementedError

    def verify(self, n_pairs: int = 100_000, seed: int = 0) -> Verification:
        """Test the certificate's inequality with the nonlinear model on random pairs."""
        n_pairs, seed = check_samples(n_pairs, "n_pairs"), check_seed(seed)
        if not self.certified:
            return Verification(
                worst_ratio=float("nan"), pairs_used=0, pairs_drawn=0, note=f"not certified: {self.reason}"
            )
        return self._verify(n_pairs, seed)

    def _verify(self, n_pairs: int, seed: int) -> Verification:
        raise NotImplementedError

    def to_dict(self) -> dict[str, object]:
        """Plain-data form for JSON (NaN for numbers that do not exist)."""
        ok = self.certified
        return {
            "kind": self.kind,
            "certified": ok,
            "status": self.status,
            "reason": self.reason,
            "rate": self.rate,
            "rate_min": self.rate_min,
            "P": self.P.tolist() if ok else None,
            "P_scaled": self.P_scaled.tolist() if ok else None,
            "condition_scaled": self.condition if ok else None,
            "min_horizon": self.min_horizon() if ok else None,
            "solve_time_s": self.solve_time,
            "coverage": self.coverage,
            "cover_kind": self.cover_kind,
            "sound": self.sound,
            "margin": self.margin,
            "falsification": None if self.falsification is None else self.falsification.to_dict(),
            **self._details(),
        }

    def _details(self) -> dict[str, object]:
        return {}

    def tradeoff(self, levels: Sequence[float] = DEFAULT_LEVELS) -> Tradeoff:
        """Make the certificate again with cond(P) bounded by each of ``levels`` (at its default rate).

        Each row gives the smallest rate found, the rate, cond(P), the minimal horizon, the weight on the
        outputs over ``lambda_min(P)`` and the noise gain per state (:mod:`uiest.detectability.tradeoff`):
        what a faster rate costs. The certify function is called once per level with the arguments this
        certificate was made with, except ``mu`` and ``max_condition``.

        Raises
        ------
        OptionError
            Bad ``levels``, or a certificate not made by a certify function that bounds cond(P).

        """
        recertify = getattr(self, "recertify", None)
        if recertify is None:
            raise OptionError(
                f"tradeoff: a {type(self).__name__} is not made by a certify function that bounds cond(P)"
            )
        return tabulate(self.kind, self._state_labels(), lambda level: self._like_this(recertify(max_condition=level)),
                        levels)  # fmt: skip

    def _like_this(self, certificate: Any) -> Any:
        """``certificate`` (made again at another bound on cond(P)) with this one's later changes applied."""
        return certificate

    def _state_labels(self) -> tuple[str, ...]:
        """Labels of the storage's states (with units where known)."""
        return tuple(f"z{i + 1}" for i in range(len(self.scale)))


def state_labels(names: Sequence[str], units: Sequence[str]) -> tuple[str, ...]:
    """``name [unit]`` (``name`` alone without a unit)."""
    return tuple(f"{n} [{u}]" if u else n for n, u in zip(names, units, strict=True))


@dataclass(frozen=True, eq=False, kw_only=True)
class MuCertificate(Certificate):
    """A certificate whose rate the paper calls mu (strong detectability, reduced e-IOSS)."""

    @property
    def mu(self) -> float:
        """The design discount (``rate``)."""
        return self.rate

    @property
    def mu_min(self) -> float:
        """Smallest discount found (``rate_min``)."""
        return self.rate_min


@dataclass(frozen=True, eq=False, kw_only=True)
class StrongDetectabilityBase(MuCertificate):
    """What the nonlinear and the linear strong-detectability certificates share.

    mu, the horizon of Eq. (13) and the UISE's weights ``(mu, P, R_y, R_v)``
    (subclasses hold ``R_y`` and ``R_v``).
    """

    def _horizon(self) -> int:
        """Eq. (13) in the scaled norm: :func:`strong_horizon`."""
        return strong_horizon(self.mu, self.condition)


def _eig(matrix: FloatArray, index: int) -> float:
    if not np.all(np.isfinite(matrix)):
        return float("nan")
    return float(np.linalg.eigvalsh(0.5 * (matrix + matrix.T))[index])


def check_rate(value: object, name: str) -> float | None:
    """``value`` as a rate in (0, 1), or None; OptionError naming ``name`` otherwise."""
    if value is None:
        return None
    try:
        rate = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise OptionError(f"{name}: expected a number in (0, 1) or None, got {value!r}") from None
    if not 0.0 < rate < 1.0:
        raise OptionError(f"{name}: expected a number in (0, 1) or None, got {value!r}")
    return rate


def sample_pairs(
    rng: np.random.Generator, box: Box, n_pairs: int, scale: FloatArray, directions: FloatArray | None = None
) -> tuple[FloatArray, FloatArray]:
    """Pairs ``(z, z~)`` in a bounded box, shape (n_pairs, n) each; half of them close.

    Close pairs: ``z~ = z + 10^U(-6, -1) * width * d`` with d a random unit combination of the
    columns of ``directions`` (scaled coordinates; all directions when None), clipped to the box.
    Steps below 1e-6 of the width would measure rounding, not the inequality.
    """
    z, zt = box.sample(rng, n_pairs), box.sample(rng, n_pairs)
    close = np.arange(n_pairs) < n_pairs // 2
    basis = np.eye(box.size) if directions is None else directions
    d = rng.standard_normal((int(close.sum()), basis.shape[1])) @ basis.T
    d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-300)
    width = np.where(box.width > 0, box.width, scale)
    step = 10.0 ** rng.uniform(-6.0, -1.0, (int(close.sum()), 1)) * float(np.linalg.norm(width / scale))
    zt[close] = box.clip(z[close] + step * d * scale)
    return z, zt


ADMIT_DRAWS = 50
"""Where a predicate admits only part of the box (:func:`sample_admitted_pairs`), at most this many times the
requested pairs are drawn."""


def sample_admitted_pairs(
    rng: np.random.Generator,
    box: Box,
    shared: Box,
    n_pairs: int,
    scale: FloatArray,
    admit: Callable[[FloatArray, FloatArray, FloatArray], np.ndarray],
    directions: FloatArray | None = None,
) -> tuple[FloatArray, FloatArray, FloatArray, int]:
    """Up to ``n_pairs`` pairs ``(z, z~)`` of :func:`sample_pairs` with a shared point ``s`` that ``admit`` accepts.

    Batches of ``n_pairs`` pairs (and ``s`` from ``shared``) are drawn until ``n_pairs`` are admitted or
    :data:`ADMIT_DRAWS` times ``n_pairs`` were drawn. The close pairs and the others are admitted up to half each (a
    close pair lies in a thin domain more often than two independent points), a random subset of the last batch
    needed. ``admit(z (m, n), z~ (m, n), s (m, ns))`` returns a boolean mask (m,). Returns ``z, z~`` (k, n) (the close
    pairs first), ``s`` (k, ns) with ``0 <= k <= n_pairs``, and the number of pairs drawn.
    """
    close_quota = n_pairs // 2
    kept: list[list[tuple[FloatArray, FloatArray, FloatArray]]] = [[], []]  # close pairs, the others
    wanted = [close_quota, n_pairs - close_quota]
    drawn = 0
    while any(wanted) and drawn < ADMIT_DRAWS * n_pairs:
        a, b = sample_pairs(rng, box, n_pairs, scale, directions)
        s = shared.sample(rng, n_pairs)
        drawn += n_pairs
        admitted = np.asarray(admit(a, b, s), dtype=bool)
        for part, rows in enumerate((np.arange(close_quota), np.arange(close_quota, n_pairs))):
            take = rng.permutation(rows[admitted[rows]])[: wanted[part]]
            kept[part].append((a[take], b[take], s[take]))
            wanted[part] -= len(take)
    a, b, s = (np.vstack([piece[i] for part in kept for piece in part]) for i in range(3))
    return a, b, s, drawn


def quad(d: FloatArray, W: FloatArray) -> FloatArray:
    """``d_m^T W d_m`` for each row of d (m, n)."""
    return np.einsum("mi,ij,mj->m", d, W, d)
