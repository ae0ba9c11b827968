"""The paper's results in words, as users read them: a name and the result's number in the paper.

The paper is Y. Guo, J. A. Moreno, S. Streif, "Strong nonlinear detectability and moving horizon
estimation for nonlinear systems with unknown inputs". Strings that users read (guarantees,
reasons, errors, CLI output, reports) name a result through the constants below (e.g.
:data:`FULL_ORDER_GUARANTEE`), never by its LaTeX label; the theory map (``docs/theory-map.md``) is the one
place that holds the labels, with each one's number, statement and the uiest names that use it.

Numbers follow the manuscript's counters: theorems, lemmas, propositions, definitions,
assumptions and remarks share one counter per section ("Theorem 3.6" is the sixth numbered
statement of Section 3; the ieeeconf class prints the section in Roman numerals, "III.6");
equations are numbered consecutively through the paper.
"""

from __future__ import annotations

__all__ = [
    "ALGEBRAIC_TWO_STAGE",
    "CITATION",
    "DECREASE_CONDITION",
    "FIE_GUARANTEE",
    "FULL_ORDER_GUARANTEE",
    "FULL_ORDER_HORIZON",
    "LINEAR_STRONG_DETECTABILITY",
    "LYAPUNOV_CHARACTERISATION",
    "PSI_RECOVERY",
    "QUASI_STATE_AFFINE_REDUCTION",
    "REDUCED_IOSS",
    "TWO_STAGE_GUARANTEE",
    "TWO_STAGE_HORIZON",
    "W_FREE_REDUCED_DYNAMICS",
]

CITATION = "Guo et al."
"""How user-facing text names the paper."""


def _ref(what: str, where: str) -> str:
    return f"{what} ({where} of {CITATION})"


# The results the code names; docs/theory-map.md gives each one's label, statement and the uiest names that use it.
LYAPUNOV_CHARACTERISATION = _ref("the Lyapunov characterisation of strong detectability", "Theorem 3.2")
"""Theorem 3.2: strong detectability through an incremental storage function (what a certificate shows)."""
FIE_GUARANTEE = _ref("the FIE guarantee", "Lemma 3.3")
"""Lemma 3.3: the full information estimator is a UISE."""
LINEAR_STRONG_DETECTABILITY = _ref("strong detectability of linear systems", "Lemma 3.5")
"""Lemma 3.5: strong detectability of linear systems (Hautus' conditions)."""
FULL_ORDER_GUARANTEE = _ref("the full-order UISE guarantee", "Theorem 3.6")
"""Theorem 3.6: the MHE-based UISE with the full-order model is a UISE."""
QUASI_STATE_AFFINE_REDUCTION = _ref("the reduction of quasi-state-affine systems", "Proposition 4.4")
"""Proposition 4.4: the reduction of quasi-state-affine systems."""
TWO_STAGE_GUARANTEE = _ref("the two-stage UISE guarantee", "Theorem 4.8")
"""Theorem 4.8: the two-stage UISE with a reduced-order model is a UISE."""
REDUCED_IOSS = _ref("exponential i-IOSS of the reduced-order model", "Assumption 4.7")
"""Assumption 4.7: exponential i-IOSS of the reduced-order model."""
DECREASE_CONDITION = _ref("the strong-detectability decrease condition", "Eq. (5b)")
"""Eq. (5b): the storage function's decrease."""
FULL_ORDER_HORIZON = _ref("the full-order UISE horizon condition", "Eq. (13)")
"""Eq. (13): the full-order UISE's horizon condition."""
PSI_RECOVERY = _ref("the recovery z_flat = psi(y, z_sharp, v)", "Eq. (17)")
"""Eq. (17): the flat coordinates are read from the output."""
W_FREE_REDUCED_DYNAMICS = _ref("reduced dynamics free of the unknown input", "Eq. (18)")
"""Eq. (18): the reduced dynamics do not depend on the unknown input."""
TWO_STAGE_HORIZON = _ref("the two-stage UISE horizon condition N > -log_mu(4 c_x)", "Eq. (31)")
"""Eq. (31): the two-stage UISE's horizon condition."""

ALGEBRAIC_TWO_STAGE = _ref("the algebraic two-stage UISE for n_sharp = 0", "Remark 4.9")
"""Remark 4.9 (after the two-stage UISE guarantee; it has no label): with ``n_sharp = 0`` the estimate is algebraic."""
