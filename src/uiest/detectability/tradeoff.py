"""What a faster rate costs: a certificate certified again at several bounds on cond(P).

A storage that contracts the states an output sees only through a weak coupling needs a large
condition number, so the smallest certifiable rate falls as the bound ``max_condition`` on cond(P)
grows; the weights grow with it (the estimator trusts its outputs and noise model more against its
prior, and its noise gain rises), and the minimal horizon ``~ log(cond(P)) / log(1 / mu)`` may fall
or rise. :meth:`uiest.detectability.Certificate.tradeoff` returns a :class:`Tradeoff`, one
:class:`TradeoffRow` per bound, each from a certificate made at that bound with the certify
function's default rate.
"""

from __future__ import annotations

import numbers
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from uiest.box import FloatArray
from uiest.errors import OptionError

__all__ = ["DEFAULT_LEVELS", "Tradeoff", "TradeoffRow", "check_condition", "tabulate"]

DEFAULT_LEVELS = (1e6, 1e8, 1e10, 1e12)
"""Bounds on cond(P) tabulated by default."""


@dataclass(frozen=True, kw_only=True)
class TradeoffRow:
    """One bound on cond(P) and what the certificate made with it gives.

    Attributes
    ----------
    max_condition : float
        The bound on cond(P) (scaled coordinates).
    certified : bool
        Whether the certificate made with that bound holds.
    status : str
        The certificate's status ("certified", "infeasible", ...).
    mu_min, mu : float
        The smallest rate found and the certificate's rate (its default: above mu_min).
    condition : float
        cond(P) of the certificate (scaled coordinates; NaN when not certified).
    horizon : int or None
        The certificate's ``min_horizon()`` at mu (None when not certified).
    noise_gain : ndarray (n,)
        The certificate's per-step noise gain per state, in the state's units (NaN when not certified).
    output_gain : float
        The weight on the scaled output increment over ``lambda_min(P)`` (scaled): how much more the
        estimator's cost trusts an output than its prior.

    """

    max_condition: float
    certified: bool
    status: str
    mu_min: float
    mu: float
    condition: float
    horizon: int | None
    noise_gain: FloatArray
    output_gain: float


@dataclass(frozen=True, kw_only=True)
class Tradeoff:
    """Rate, horizon and noise gain of a certificate at several bounds on cond(P).

    Attributes
    ----------
    kind : str
        The certificate's kind ("strong_detectability", "reduced_eioss", "delta_ioss").
    states : tuple of str
        Labels of the certificate's states, with their units where known (the noise gain's columns).
    rows : tuple of TradeoffRow
        One per bound, in the order given.

    """

    kind: str
    states: tuple[str, ...]
    rows: tuple[TradeoffRow, ...]

    def to_pandas(self) -> Any:
        """Return one row per bound as a pandas DataFrame.

        Columns: max_condition, status, mu_min, mu, condition, horizon, output_gain, and one
        ``noise_gain <state>`` per state.
        """
        import pandas as pd

        records = []
        for row in self.rows:
            record: dict[str, object] = {
                "max_condition": row.max_condition,
                "status": row.status,
                "mu_min": row.mu_min,
                "mu": row.mu,
                "condition": row.condition,
                "horizon": row.horizon,
                "output_gain": row.output_gain,
            }
            record.update({f"noise_gain {name}": float(g) for name, g in zip(self.states, row.noise_gain, strict=True)})
            records.append(record)
        return pd.DataFrame.from_records(records)

    def __str__(self) -> str:
        head = ("max cond(P)", "status", "mu_min", "mu", "cond(P)", "min N", "output gain", "largest noise gain")
        lines = [head]
        for row in self.rows:
            ok = row.certified
            gains = np.asarray(row.noise_gain, dtype=float)
            worst = int(np.nanargmax(gains)) if ok and np.any(np.isfinite(gains)) else None
            gain = f"{gains[worst]:.3g} ({self.states[worst]})" if worst is not None else "-"
            lines.append((
                f"{row.max_condition:.0e}", row.status, _number(row.mu_min, ".6g"),
                _number(row.mu, ".6g") if ok else "-", _number(row.condition, ".3g") if ok else "-",
                str(row.horizon) if ok else "-",
                _number(row.output_gain, ".3g") if ok else "-", gain,
            ))  # fmt: skip
        widths = [max(len(line[i]) for line in lines) for i in range(len(head))]
        text = ["  ".join(cell.rjust(width) for cell, width in zip(line, widths, strict=True)) for line in lines]
        return f"{self.kind}: rate against the bound on cond(P)\n" + "\n".join(text)


def _number(value: float, spec: str) -> str:
    return format(value, spec) if np.isfinite(value) else "-"


def check_condition(value: object, name: str = "max_condition") -> float:
    """``value`` as a bound on cond(P): a finite number > 1; OptionError naming ``name`` otherwise."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or not 1.0 < float(value) < np.inf:
        raise OptionError(f"{name}: expected a finite number > 1, got {value!r}")
    return float(value)


def check_levels(levels: Sequence[float]) -> tuple[float, ...]:
    """``levels`` as bounds on cond(P): a non-empty sequence of finite numbers > 1; OptionError otherwise."""
    if isinstance(levels, str | bytes) or not isinstance(levels, Sequence) or not levels:
        raise OptionError(f"levels: expected a non-empty sequence of finite numbers > 1, got {levels!r}")
    return tuple(check_condition(level, "levels") for level in levels)


def tabulate(
    kind: str,
    states: tuple[str, ...],
    certify: Callable[[float], Any],
    levels: Sequence[float],
) -> Tradeoff:
    """:class:`Tradeoff` of the certificates ``certify(max_condition)`` at each level (see :func:`check_levels`)."""
    rows = []
    for level in check_levels(levels):
        cert = certify(level)
        ok = bool(cert.certified)
        nan = np.full(len(states), np.nan)
        rows.append(TradeoffRow(
            max_condition=level, certified=ok, status=str(cert.status), mu_min=float(cert.rate_min),
            mu=float(cert.rate),
            condition=float(cert.condition) if ok else float("nan"), horizon=cert.min_horizon() if ok else None,
            noise_gain=np.asarray(cert.noise_gain, dtype=float) if ok else nan,
            output_gain=float(cert.output_gain) if ok else float("nan"),
        ))  # fmt: skip
    return Tradeoff(kind=kind, states=states, rows=tuple(rows))
