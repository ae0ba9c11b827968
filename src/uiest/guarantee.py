"""What an estimator's theorem guarantees, in the user's units: :class:`Guarantee`.

A guarantee is data: whether the theorem's assumptions are met (``applies``), and if so the
error bound it gives per state (in the state's units, for the model's noise bound V), after how
many steps it holds, and how it compares with X's width. :attr:`Guarantee.verdict` classifies
it and :attr:`Guarantee.text` is derived from the numbers for display::

    holds, bound x1 0.0031 kg/m^2, x2 0.002 kg/m^2 after 12 steps (informative)
    holds but vacuous: bound 31015 cm > X's width 24 cm for h1
    none: N=2 < min_horizon()=18, too short for the full-order UISE horizon condition (Eq. (13) of Guo et al.)

The numbers come from :mod:`uiest.estimators.bounds` (each estimator's theorem);
:class:`~uiest.results.EstimationResult` holds the guarantee of the estimator that produced it.
"""

from __future__ import annotations

import dataclasses
import enum
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from uiest.box import FloatArray
from uiest.errors import OptionError

__all__ = ["Guarantee", "Verdict"]


class Verdict(enum.Enum):
    """What a guarantee says, derived from its numbers (:attr:`Guarantee.verdict`)."""

    NONE = "none"
    """The theorem's assumptions are not met: no claim."""
    INFORMATIVE = "informative"
    """It holds, and every state's bound is below X's width."""
    VACUOUS = "vacuous"
    """It holds, but some state's bound is at least X's width: it says nothing there."""
    PARTIAL = "partial"
    """It holds, some states have a bound below X's width and the others no finite bound."""
    NO_BOUND = "no bound"
    """It holds (the error converges under convergent noise), but no state has a finite bound for V."""


@dataclass(frozen=True, eq=False, kw_only=True)
class Guarantee:
    """An estimator's guarantee: the theorem, whether it applies, and its error bound per state.

    Attributes
    ----------
    theorem : str
        A user-facing name in words (:mod:`uiest.theory`), e.g.
        ``"the full-order UISE guarantee (Theorem 3.6 of Guo et al.)"``.
    applies : bool
        The theorem's assumptions are met (a certified certificate gave the weights, the horizon
        is long enough, matching holds, ...).
    reason : str
        Why it does not apply (empty when it applies).
    x_width : ndarray (nx,)
        X's width per state (inf where X is unbounded).
    names, units : tuple of str (nx each)
        The states' names and units.
    error_bound : ndarray (nx,) or None
        ``|x_hat[k] - x[k]|`` per state, in the state's units, for every noise within V (and
        whatever else :attr:`assumes` states), at every ``k >= settling_steps``. NaN where the
        theorem bounds that state by nothing (:attr:`bound_note` says why), inf where its bound is
        infinite (V unbounded). None when the theorem does not apply.
    settling_steps : int or None
        The bound holds from this step on, starting from an initial error as large as X allows
        (each state's error up to X's width); None when X is unbounded or the noise-free bound is 0
        (then it holds only in the limit).
    assumes : str
        What the bound assumes besides the theorem's assumptions.
    condition : str
        A hypothesis the bound rests on that the user must know to read it (the standard MHE's: the
        unknown input in its known range); the text says "holds while <condition>".
    bound_note : str
        Why some states have no finite bound (empty when all have one).
    horizon : int or None
        The window length (transitions) the estimator uses, for which the bound is computed (None: no
        fixed window).
    requested_horizon : int or None
        The window length asked for; larger than :attr:`horizon` when the window was capped at the
        information horizon (:attr:`capped`). None for a window that grows from time 0 (the FIE).
    grows : bool
        The window grows from time 0 (the FIE); with :attr:`horizon` set, it stops growing there, at the
        information horizon, and slides from then on (:attr:`capped`).
    information_horizon : int or None
        The longest window whose every cost term counts in double precision
        (:mod:`uiest.estimators.horizon`; None: no such limit, or no window).
    suspended : (int, int) or None
        A run's guarantee only (:meth:`for_run`): the first and last steps whose data or solve broke what the
        bound assumes (an output missing, a window not solved, or from :attr:`settling_steps` on an estimate the
        data put beyond a side of X); None when none did.
    suspended_steps : int
        How many steps between them did (0 without :attr:`suspended`).
    resumes : int or None
        With :attr:`suspended`: the step from which the bound holds again (a window of measured outputs after
        the last, then :attr:`settling_steps` from an error as large as X allows; an observer without a window:
        the settling steps after the last). None without settling steps, and for a window that grows from time 0
        without a horizon (the FIE's keeps the missing outputs).
    run_steps : int or None
        A run's guarantee only: the run's steps ``K + 1`` (the text says where the bound applies to none of them).
        The flags (:attr:`applies`, :attr:`verdict`, :attr:`informative`) stay the estimator's in a run's
        guarantee: the text says what the run did to it.

    """

    theorem: str
    applies: bool
    x_width: FloatArray
    names: tuple[str, ...]
    units: tuple[str, ...]
    reason: str = ""
    error_bound: FloatArray | None = None
    settling_steps: int | None = None
    assumes: str = ""
    bound_note: str = ""
    condition: str = ""
    horizon: int | None = None
    requested_horizon: int | None = None
    information_horizon: int | None = None
    grows: bool = False
    suspended: tuple[int, int] | None = None
    suspended_steps: int = 0
    resumes: int | None = None
    run_steps: int | None = None

    def __post_init__(self) -> None:
        width = np.array(self.x_width, dtype=float, ndmin=1)
        width.setflags(write=False)
        object.__setattr__(self, "x_width", width)
        object.__setattr__(self, "names", tuple(self.names))
        object.__setattr__(self, "units", tuple(self.units))
        if self.error_bound is not None:
            bound = np.array(self.error_bound, dtype=float, ndmin=1)
            if bound.shape != width.shape:
                raise OptionError(f"error_bound: expected shape {width.shape} (one bound per state), got {bound.shape}")
            bound.setflags(write=False)
            object.__setattr__(self, "error_bound", bound)

    @classmethod
    def none(cls, theorem: str, reason: str, x_width: FloatArray, names: tuple[str, ...],
             units: tuple[str, ...]) -> Guarantee:  # fmt: skip
        """A theorem that does not apply, and why."""
        return cls(theorem=theorem, applies=False, reason=reason, x_width=x_width, names=names, units=units)

    def for_run(self, broken: np.ndarray, outside: Sequence[bool] | np.ndarray | None = None) -> Guarantee:
        """The guarantee as a run of ``K + 1`` steps met it (:attr:`suspended`, :attr:`resumes`).

        ``broken`` (K+1,) bool marks the steps whose data or solve broke what the bound assumes; ``outside`` (K+1,)
        bool the estimates the data put beyond a side of X (the true state may have left X), which count from
        :attr:`settling_steps` on (before, an estimate far from a wrong prior's start is the transient the bound
        allows). The guarantee itself where none did or it does not apply.
        """
        if not self.applies:
            return self
        if outside is not None and self.settling_steps is not None:
            late = np.asarray(outside, dtype=bool).copy()
            late[: self.settling_steps] = False
            broken = np.asarray(broken, dtype=bool) | late
        steps = np.flatnonzero(broken)
        if not steps.size:
            return dataclasses.replace(self, run_steps=len(broken))
        first, last = int(steps[0]), int(steps[-1])
        resumes = None
        if self.settling_steps is not None and not (self.grows and self.horizon is None):
            resumes = last + (self.horizon or 0) + 1 + self.settling_steps
        return dataclasses.replace(self, suspended=(first, last), suspended_steps=int(steps.size), resumes=resumes,
                                   run_steps=len(broken))  # fmt: skip

    def for_study(self) -> Guarantee:
        """A run's guarantee without what one run did to it (:attr:`suspended`): the same for every run of a study."""
        return dataclasses.replace(self, suspended=None, suspended_steps=0, resumes=None)

    @property
    def capped(self) -> bool:
        """The window used is shorter than the one asked for (capped at the information horizon).

        A growing window (:attr:`grows`) is capped when it has a :attr:`horizon`: it stops growing there.
        """
        if self.horizon is None:
            return False
        return self.grows or (self.requested_horizon is not None and self.horizon < self.requested_horizon)

    # ------------------------------------------------------------------ flags per state
    @property
    def bounded_states(self) -> np.ndarray:
        """(nx,) bool: the theorem bounds the state by a finite number."""
        if not self.applies or self.error_bound is None:
            return np.zeros(self.x_width.shape, dtype=bool)
        return np.isfinite(self.error_bound)

    @property
    def informative_states(self) -> np.ndarray:
        """(nx,) bool: a finite bound below X's width."""
        bounded = self.bounded_states
        out = np.zeros(bounded.shape, dtype=bool)
        if bounded.any():
            assert self.error_bound is not None
            out[bounded] = self.error_bound[bounded] < self.x_width[bounded]
        return out

    @property
    def vacuous_states(self) -> np.ndarray:
        """(nx,) bool: a finite bound at least X's width (it says nothing X does not)."""
        return self.bounded_states & ~self.informative_states

    @property
    def informative(self) -> bool:
        """The theorem applies and every state's bound is below X's width."""
        return self.applies and bool(np.all(self.informative_states))

    @property
    def verdict(self) -> Verdict:
        """:class:`Verdict` from the flags."""
        if not self.applies:
            return Verdict.NONE
        if self.vacuous_states.any():
            return Verdict.VACUOUS
        if self.informative:
            return Verdict.INFORMATIVE
        return Verdict.PARTIAL if self.informative_states.any() else Verdict.NO_BOUND

    # ------------------------------------------------------------------ text
    @property
    def text(self) -> str:
        """One line derived from the numbers (module docstring), the window's cap and where a run suspended it."""
        text = self._verdict_text()
        if self.capped and self.grows:
            text += (
                f". The window grows from time 0 to N={self.horizon} and slides from there: it is capped at its "
                "information horizon (older cost terms would fall below double precision)"
            )
        elif self.capped:
            text += (
                f". The window runs N={self.horizon}, not the N={self.requested_horizon} asked for: it is capped at "
                "its information horizon (older cost terms would fall below double precision)"
            )
        end = None if self.run_steps is None else self.run_steps - 1  # the run's last step
        if self.suspended is not None:
            first, last = self.suspended
            if first == last:
                steps = f"k = {first}"
            elif self.suspended_steps == last - first + 1:
                steps = f"k = {first}..{last}"
            else:
                steps = f"{self.suspended_steps} steps from k = {first} to {last}"
            text += (f". Suspended in this run: an output was missing, a window not solved or the data put the "
                     f"estimate beyond X's side at {steps}, and the bound assumes every output measured, every window "
                     "solved and the state in X")  # fmt: skip
            if self.resumes is not None:
                beyond = end is not None and self.resumes > end
                text += f"; it applies again from k = {self.resumes}" + (f", after the run's end (k = {end})" * beyond)
            elif self.grows and self.horizon is None and self.settling_steps is not None:
                text += "; it does not apply again (the growing window keeps the steps that broke it)"
        elif end is not None and self.settling_steps is not None and self.settling_steps > end:
            text += f". The run ends at k = {end}, before the bound applies"
        return text

    def _verdict_text(self) -> str:
        verdict = self.verdict
        if verdict is Verdict.NONE:
            return f"none: {self.reason}"
        holds = f"holds while {self.condition}" if self.condition else "holds"
        if verdict is Verdict.NO_BOUND:
            return f"{holds}, no finite bound: {self.bound_note}"
        informative, vacuous = self.informative_states, self.vacuous_states
        missing = ~self.bounded_states
        after = self._after()
        if verdict is Verdict.INFORMATIVE:
            return f"{holds}, bound {self._bounds(informative)} {after} (informative)"
        if verdict is Verdict.PARTIAL:
            text = f"{holds}, bound {self._bounds(informative)} {after} (informative there)"
        else:
            assert self.error_bound is not None
            wide = ", ".join(
                f"{_amount(self.error_bound[i], self.units[i])} > X's width {_amount(self.x_width[i], self.units[i])} "
                f"for {self.names[i]}"
                for i in np.flatnonzero(vacuous)
            )
            text = f"{holds} but vacuous: bound {wide}"
            if informative.any():
                text += f"; informative for {self._bounds(informative)} {after}"
        if missing.any():
            text += f"; no bound for {', '.join(self.names[i] for i in np.flatnonzero(missing))}: {self.bound_note}"
        return text

    def _bounds(self, states: np.ndarray) -> str:
        assert self.error_bound is not None
        chosen = np.flatnonzero(states)
        if len(self.names) == 1:
            return _amount(self.error_bound[0], self.units[0])
        return ", ".join(f"{self.names[i]} {_amount(self.error_bound[i], self.units[i])}" for i in chosen)

    def _after(self) -> str:
        if self.settling_steps is None:
            return "once the initial error has decayed"
        return "at every step" if self.settling_steps == 0 else f"after {self.settling_steps} steps"

    def __str__(self) -> str:
        return self.text

    def __repr__(self) -> str:
        return f"Guarantee({self.theorem}: {self.text})"

    def to_dict(self) -> dict[str, object]:
        """Plain data for JSON (bounds as lists; NaN and inf kept as floats)."""
        return {
            "theorem": self.theorem,
            "applies": self.applies,
            "verdict": self.verdict.value,
            "informative": self.informative,
            "reason": self.reason,
            "error_bound": None if self.error_bound is None else [float(b) for b in self.error_bound],
            "x_width": [float(w) for w in self.x_width],
            "units": list(self.units),
            "settling_steps": self.settling_steps,
            "assumes": self.assumes,
            "bound_note": self.bound_note,
            "horizon": self.horizon,
            "requested_horizon": self.requested_horizon,
            "information_horizon": self.information_horizon,
            "grows": self.grows,
            "capped": self.capped,
            "suspended": None if self.suspended is None else list(self.suspended),
            "suspended_steps": self.suspended_steps,
            "resumes": self.resumes,
            "run_steps": self.run_steps,
            "text": self.text,
        }


def _amount(value: float, unit: str) -> str:
    """``value`` with 3 significant digits (whole numbers up to 1e6 in full) and its unit ("" and "-": none)."""
    magnitude = abs(value)
    number = f"{value:.0f}" if 1e3 <= magnitude < 1e6 else f"{value:.3g}"
    return f"{number} {unit}" if unit not in ("", "-") else number
