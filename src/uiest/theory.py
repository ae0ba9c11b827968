"""The paper's results in words: what each LaTeX label of the paper is called where users read it.

The paper is Y. Guo, J. A. Moreno, S. Streif, "Strong nonlinear detectability and moving horizon
estimation for nonlinear systems with unknown inputs". Strings that users read (guarantees,
reasons, errors, CLI output, reports) name a result through the constants below (e.g.
:data:`FULL_ORDER_GUARANTEE`) or :data:`PAPER` (:func:`cite`), never by its label; this module is the one
place in the sources that holds the labels, and the theory map (``docs/theory-map.md``) gives each label's
statement and the uiest names that use it.

Numbers follow the manuscript's counters: theorems, lemmas, propositions, definitions,
assumptions and remarks share one counter per section ("Theorem 3.6" is the sixth numbered
statement of Section 3; the ieeeconf class prints the section in Roman numerals, "III.6");
equations are numbered consecutively through the paper.
"""

from __future__ import annotations

from types import MappingProxyType

from uiest.errors import OptionError

__all__ = ["ALGEBRAIC_TWO_STAGE", "PAPER", "cite"]

CITATION = "Guo et al."
"""How user-facing text names the paper."""


def _ref(what: str, where: str) -> str:
    return f"{what} ({where} of {CITATION})"


PAPER = MappingProxyType({
    # sections
    "sec:UISE_red": _ref("reduced-order models", "Section 4"),
    # theorems, lemmas, propositions
    "theo:Lyapunov": _ref("the Lyapunov characterisation of strong detectability", "Theorem 3.2"),
    "lem:FIE": _ref("the FIE guarantee", "Lemma 3.3"),
    "lem:UIO_LTI": _ref("strong detectability of linear systems", "Lemma 3.5"),
    "theo:MHE_full": _ref("the full-order UISE guarantee", "Theorem 3.6"),
    "prop:special_case": _ref("the reduction of quasi-state-affine systems", "Proposition 4.4"),
    "theo:stab": _ref("the two-stage UISE guarantee", "Theorem 4.8"),
    # assumptions
    "ass": _ref("the reduction assumption", "Assumption 4.2"),
    "ass:e-ioss": _ref("exponential i-IOSS of the reduced-order model", "Assumption 4.7"),
    # equations
    "eq:Lyapunov_2": _ref("the strong-detectability decrease condition", "Eq. (5b)"),
    "eq:op_FIE": _ref("the FIE problem", "Eq. (6)"),
    "eq:cost_FIE_full": _ref("the FIE cost", "Eq. (7)"),
    "eq:cost_MHE_full": _ref("the full-order UISE cost", "Eq. (11)"),
    "eq:prior_rule": _ref("the full-order UISE prior rule", "Eq. (12)"),
    "eq:MHE_full_horizon": _ref("the full-order UISE horizon condition", "Eq. (13)"),
    "eq:ass_1": _ref("the recovery z_flat = psi(y, z_sharp, v)", "Eq. (17)"),
    "eq:ass_2": _ref("reduced dynamics free of the unknown input", "Eq. (18)"),
    "eq:sys_spec": _ref("the quasi-state-affine form", "Eq. (19)"),
    "eq:sys_red": _ref("the reduced-order model", "Eq. (21)"),
    "eq:fullest": _ref("the full-state map x = T^-1(psi(y, z_sharp, v), z_sharp)", "Eq. (26)"),
    "eq:p-eioss_quadratic": _ref("the exponential i-IOSS inequality", "Eq. (27)"),
    "eq:cost_MHE": _ref("the two-stage UISE cost", "Eq. (28)"),
    "eq:prior": _ref("the two-stage UISE prior rule", "Eq. (29)"),
    "eq:op_MHE": _ref("the two-stage UISE's MHE problem", "Eq. (30)"),
    "eq:N_cond": _ref("the two-stage UISE horizon condition N > -log_mu(4 c_x)", "Eq. (31)"),
    "eq:rges_proof_4": _ref("the two-stage bound on z_sharp", "Eq. (33)"),
    "eq:fullest_new": _ref("the projected full-state map", "Eq. (35)"),
})  # fmt: skip
"""Each paper label that uiest refers to, mapped to the words users read."""

# The results the code names, as constants: the labels stay in this module (and the theory map) only.
LYAPUNOV_CHARACTERISATION = PAPER["theo:Lyapunov"]
"""Theorem 3.2: strong detectability through an incremental storage function (what a certificate shows)."""
FIE_GUARANTEE = PAPER["lem:FIE"]
"""Lemma 3.3: the full information estimator is a UISE."""
LINEAR_STRONG_DETECTABILITY = PAPER["lem:UIO_LTI"]
"""Lemma 3.5: strong detectability of linear systems (Hautus' conditions)."""
FULL_ORDER_GUARANTEE = PAPER["theo:MHE_full"]
"""Theorem 3.6: the MHE-based UISE with the full-order model is a UISE."""
QUASI_STATE_AFFINE_REDUCTION = PAPER["prop:special_case"]
"""Proposition 4.4: the reduction of quasi-state-affine systems."""
TWO_STAGE_GUARANTEE = PAPER["theo:stab"]
"""Theorem 4.8: the two-stage UISE with a reduced-order model is a UISE."""
REDUCED_IOSS = PAPER["ass:e-ioss"]
"""Assumption 4.7: exponential i-IOSS of the reduced-order model."""
DECREASE_CONDITION = PAPER["eq:Lyapunov_2"]
"""Eq. (5b): the storage function's decrease."""
FULL_ORDER_HORIZON = PAPER["eq:MHE_full_horizon"]
"""Eq. (13): the full-order UISE's horizon condition."""
PSI_RECOVERY = PAPER["eq:ass_1"]
"""Eq. (17): the flat coordinates are read from the output."""
W_FREE_REDUCED_DYNAMICS = PAPER["eq:ass_2"]
"""Eq. (18): the reduced dynamics do not depend on the unknown input."""
TWO_STAGE_HORIZON = PAPER["eq:N_cond"]
"""Eq. (31): the two-stage UISE's horizon condition."""

ALGEBRAIC_TWO_STAGE = _ref("the algebraic two-stage UISE for n_sharp = 0", "Remark 4.9")
"""Remark 4.9 (after the two-stage UISE guarantee; it has no label): with ``n_sharp = 0`` the estimate is algebraic."""


def cite(label: str) -> str:
    """The words for a paper label, e.g. ``cite("theo:MHE_full")``.

    Parameters
    ----------
    label : str
        A key of :data:`PAPER` (a LaTeX label of the paper).

    Returns
    -------
    str
        What users read, e.g. ``"the full-order UISE guarantee (Theorem 3.6 of Guo et al.)"``.

    Raises
    ------
    OptionError
        When ``label`` is not a key of :data:`PAPER`.

    """
    try:
        return PAPER[label]
    except KeyError:
        raise OptionError(f"label: expected one of the paper labels in uiest.theory.PAPER, got {label!r}") from None
