"""Result of a certificate's sampled verification."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Verification:
    """Outcome of ``certificate.verify(...)``.

    Attributes
    ----------
    worst_ratio : float
        Largest ``LHS / RHS`` of the certificate's incremental inequality over the pairs
        (<= 1: the inequality held on every pair; NaN: nothing was tested).
    pairs_used : int
        Pairs that stayed in the domain and were tested.
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
