"""The paper's claims checked against a study's measurements: verdicts as data, words from the numbers.

Each claim compares per-run values that belong together: the ratio of two estimators' focus-state
RMSE on the same run (same truth, same noise), the growth of one estimator's error over a run, the
ratio of two estimators' mean time per sample on the same run. A claim *holds* when the runs agree
that the effect has the claimed sign, *does not hold* when they agree on the other sign, and shows
*no measurable difference* when the runs' spread straddles no effect or the effect is smaller than
:data:`MIN_EFFECT` (:data:`MIN_TIME_EFFECT` for times; :func:`decide`). The sentence a reader sees
is derived from the numbers (:meth:`Claim.text`): "4.3x smaller", "22 % smaller", "41 % growth".
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from enum import StrEnum
from typing import TYPE_CHECKING

import numpy as np

from uiest.box import FloatArray
from uiest.experiments.metrics import state_names
from uiest.experiments.runner import StudyResult
from uiest.health import FAILURES

if TYPE_CHECKING:
    import pandas as pd

__all__ = [
    "FILTER_KINDS",
    "MIN_EFFECT",
    "MOSTLY_FAILED",
    "Claim",
    "ClaimVerdict",
    "Effect",
    "decide",
    "headline",
    "paper_claims",
    "per_run",
    "relative",
]

MIN_EFFECT = 0.01
"""A relative effect on accuracy below this (1 %) is no measurable difference, however consistent the runs."""

MIN_TIME_EFFECT = 0.1
"""The same for time per sample (10 %): each estimator's runs are separate tasks, timed (CPU of the thread) at
different moments on a machine whose load others change, which moves even CPU times (caches, frequency)."""

SPREAD_FACTOR = 2.0
"""With three or more runs the effect is decided by its mean log ratio +- this many standard errors."""

FILTER_KINDS = ("ekf", "ukf")
"""Baselines outside the paper: not part of its claims."""


class ClaimVerdict(StrEnum):
    """What the measurements say of a claim."""

    HOLDS = "holds"
    NO_DIFFERENCE = "no measurable difference"
    DOES_NOT_HOLD = "does not hold"


@dataclass(frozen=True, kw_only=True)
class Effect:
    """Per-run ratios of a claimed quantity (claimed: below 1) and what they decide.

    Attributes
    ----------
    ratios : ndarray (runs,)
        The per-run ratios (finite, positive).
    center : float
        Their geometric mean.
    low, high : float
        The interval the verdict was decided on: geometric mean +- SPREAD_FACTOR standard errors
        of the log ratios with three or more runs, else the smallest and largest ratio.
    verdict : ClaimVerdict

    """

    ratios: FloatArray
    center: float
    low: float
    high: float
    verdict: ClaimVerdict


def decide(
    ratios: Sequence[float] | FloatArray, *, claimed_below: bool = True, min_effect: float = MIN_EFFECT
) -> Effect:
    """The verdict on "the ratio is below 1" (``claimed_below``, else "above 1") from per-run ratios.

    See the module docstring; ``min_effect`` is the smallest relative effect that can decide. Raises
    ValueError when no ratio is finite and positive (the caller reports the claim as not measured).
    """
    values = np.asarray(ratios, dtype=float)
    values = values[np.isfinite(values) & (values > 0)]
    if not values.size:
        raise ValueError("no finite positive ratio to decide on")
    logs = np.log(values)
    center = float(np.exp(logs.mean()))
    if values.size >= 3:
        half = SPREAD_FACTOR * float(logs.std(ddof=1)) / np.sqrt(values.size)
        low, high = float(np.exp(logs.mean() - half)), float(np.exp(logs.mean() + half))
    else:
        low, high = float(values.min()), float(values.max())
    if abs(center - 1.0) < min_effect or low <= 1.0 <= high:
        verdict = ClaimVerdict.NO_DIFFERENCE
    else:
        verdict = ClaimVerdict.HOLDS if (high < 1.0) == claimed_below else ClaimVerdict.DOES_NOT_HOLD
    return Effect(ratios=values, center=center, low=low, high=high, verdict=verdict)


def relative(ratio: float, below: str, above: str) -> str:
    """``ratio`` in words: "4.3x smaller", "22 % smaller", "0.4 % larger" (``below``/``above`` 1)."""
    if ratio <= 0.5:
        return f"{1.0 / ratio:.3g}x {below}"
    if ratio >= 2.0:
        return f"{ratio:.3g}x {above}"
    change = 100.0 * (ratio - 1.0)
    return f"{abs(change):.2g} % {below if change < 0 else above}"


@dataclass(frozen=True, kw_only=True)
class Claim:
    """One claim of the paper on one case, and what the measurements say.

    Attributes
    ----------
    case : str
    statement : str
        The claim, e.g. "the UISE has a smaller x error than the standard MHE".
    quantity : str
        What the per-run ratio is ("RMSE ratio (UISE / standard MHE)", ...).
    below, above : str
        Words for a ratio below and above 1 ("smaller"/"larger", "decreases"/"grows").
    effect : Effect or None
        None when no run measured it (``detail`` says why).
    detail : str
        The values behind the ratio (e.g. both mean RMSEs).

    """

    case: str
    statement: str
    quantity: str
    below: str
    above: str
    effect: Effect | None
    detail: str = ""

    @property
    def verdict(self) -> ClaimVerdict | None:
        """The effect's verdict (None: not measured)."""
        return None if self.effect is None else self.effect.verdict

    def text(self) -> str:
        """The claim, its verdict and the numbers it rests on."""
        if self.effect is None:
            return f"{self.case}: {self.statement}: not measured ({self.detail})"
        e = self.effect
        runs = len(e.ratios)
        span = f"; {runs} runs, interval {e.low:.3g} .. {e.high:.3g}" if runs > 1 else "; 1 run, no spread measured"
        detail = f"; {self.detail}" if self.detail else ""
        return (f"{self.case}: {self.statement}: {e.verdict} ({self.quantity} {e.center:.3g}: "
                f"{relative(e.center, self.below, self.above)}{span}{detail})")  # fmt: skip


MOSTLY_FAILED = 0.5
"""A run whose estimator failed (:data:`uiest.health.FAILURES`) in more than this share of its settled steps measures
nothing about it: the claims leave it out (a claim on no run is "not measured")."""


def per_run(study: StudyResult, focus: str) -> dict[str, pd.DataFrame]:
    """Per-run tables, index (case, run), one column per estimator: focus RMSE, error growth, time per sample.

    RMSE after ``settle``; growth: mean ``|error|`` over the last quarter of the run over that of the
    quarter after ``settle``; time: the mean CPU time per sample (s, whole steps). NaN for a run whose estimator
    failed in more than :data:`MOSTLY_FAILED` of its settled steps.
    """
    scenario, frame = study.scenario, study.steps
    quarter = max(1, (scenario.steps - scenario.settle) // 4)
    err = (frame[focus] - frame[f"{focus}_hat"]).abs()
    keys = ["case", "run", "estimator"]
    settled = frame["k"] >= scenario.settle
    early = settled & (frame["k"] < scenario.settle + quarter)
    late = frame["k"] > scenario.steps - quarter

    def table(values: pd.Series, rows: pd.Series) -> pd.DataFrame:
        return values[rows].groupby([frame.loc[rows, key] for key in keys]).mean().unstack("estimator")

    failed = frame["outcome"].isin([outcome.value for outcome in FAILURES]).astype(float)
    measured = table(failed, settled) <= MOSTLY_FAILED
    return {
        "rmse": np.sqrt(table(err**2, settled)).where(measured),
        "growth": (table(err, late) / table(err, early)).where(measured),
        "seconds": table(frame["cpu_time"], frame["k"] >= 0).where(measured),
        "measured": measured,
    }


def _left_out(measured: pd.DataFrame, case: str, names: Sequence[str]) -> str:
    """``"; 2 runs left out (...)"`` where some of the case's runs failed for one of ``names``, else ``""``."""
    if case not in measured.index.get_level_values(0):
        return ""
    columns = [name for name in names if name in measured.columns]
    count = int((~measured.loc[case, columns].all(axis=1)).sum())
    return f"; {count} run{'s' * (count != 1)} left out: an estimator failed in most of its steps" if count else ""


def _column(table: pd.DataFrame, case: str, name: str) -> pd.Series:
    import pandas as pd

    if name not in table.columns or case not in table.index.get_level_values(0):
        return pd.Series(dtype=float)
    return table.loc[case, name].dropna()


def _ratios(table: pd.DataFrame, case: str, ours: str, theirs: str) -> FloatArray:
    """Per-run ``ours / theirs`` over the runs that have both."""
    import pandas as pd

    joined = pd.concat([_column(table, case, ours).rename("a"), _column(table, case, theirs).rename("b")],
                       axis=1).dropna()  # fmt: skip
    with np.errstate(divide="ignore", invalid="ignore"):
        return (joined["a"] / joined["b"]).to_numpy(dtype=float)


def _claim(case: str, statement: str, quantity: str, ratios: FloatArray, words: tuple[str, str], detail: str,
           claimed_below: bool = True, min_effect: float = MIN_EFFECT) -> Claim:  # fmt: skip
    try:
        effect = decide(ratios, claimed_below=claimed_below, min_effect=min_effect)
    except ValueError:
        effect, detail = None, "no run measured it"
    below, above = words
    return Claim(case=case, statement=statement, quantity=quantity, below=below, above=above, effect=effect,
                 detail=detail)  # fmt: skip


def paper_claims(study: StudyResult) -> list[Claim]:
    """The paper's claims that apply to the study's estimators, per case.

    - each explicit-weight paper estimator (UISE, two-stage UISE, FIE) has a smaller focus-state
      RMSE than the standard MHE (per-run ratio);
    - the standard MHE's focus-state error grows over the run (per-run late/early ratio);
    - the two-stage UISE takes less time per sample than each other paper estimator (per-run ratio
      of the mean CPU time of whole steps on the same record).
    """
    scenario = study.scenario
    if study.steps.empty:
        return []
    focus = state_names(study)[scenario.focus_state]
    names = [s.name for s in scenario.estimators if s.weights == "explicit" and s.kind not in FILTER_KINDS]
    tables = per_run(study, focus)
    rmse, growth, seconds, measured = tables["rmse"], tables["growth"], tables["seconds"], tables["measured"]
    claims = []
    for case in scenario.cases:
        if "standard MHE" in names:
            mhe = _column(rmse, case, "standard MHE")
            for name in names:
                if name == "standard MHE":
                    continue
                ours = _column(rmse, case, name)
                both = ours.index.intersection(mhe.index)  # the runs both measured
                detail = f"mean RMSE {ours[both].mean():.3g} vs {mhe[both].mean():.3g}" if len(both) else ""
                detail += _left_out(measured, case, (name, "standard MHE"))
                claims.append(_claim(case, f"the {name} has a smaller {focus} error than the standard MHE",
                                     f"RMSE ratio {name} / standard MHE", _ratios(rmse, case, name, "standard MHE"),
                                     ("smaller", "larger"), detail.removeprefix("; ")))  # fmt: skip
            left_out = _left_out(measured, case, ("standard MHE",)).removeprefix("; ")
            claims.append(_claim(case, f"the standard MHE's {focus} error grows over the run",
                                 "late/early mean |error|", _column(growth, case, "standard MHE").to_numpy(),
                                 ("decrease", "growth"), left_out, claimed_below=False))  # fmt: skip
        if "two-stage UISE" in names:
            for other in (n for n in names if n != "two-stage UISE"):
                claims.append(_claim(case, f"the two-stage UISE takes less time per sample than the {other}",
                                     f"time per sample ratio two-stage UISE / {other}",
                                     _ratios(seconds, case, "two-stage UISE", other), ("less", "more"),
                                     "paired by run" + _left_out(measured, case, ("two-stage UISE", other)),
                                     min_effect=MIN_TIME_EFFECT))  # fmt: skip
    return claims


def headline(claims: Sequence[Claim]) -> list[str]:
    """Markdown lines: each claim and its verdict, the verdict first."""
    if not claims:
        return ["**No claim of the paper applies to this scenario.**"]
    lines = ["**The paper's claims, checked here:**", ""]
    for claim in claims:
        verdict = "not measured" if claim.verdict is None else str(claim.verdict)
        lines.append(f"- **{verdict}**: {claim.case}: {claim.statement}")
    return lines
