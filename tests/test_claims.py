"""The paper's claims checked from per-run ratios: the verdict follows the sign and size of the measurement."""

import numpy as np
import pandas as pd
import pytest
from test_experiments import tiny

from uiest.experiments import run_study
from uiest.experiments.claims import MIN_EFFECT, Claim, ClaimVerdict, decide, headline, paper_claims, per_run, relative


def test_a_verdict_needs_the_runs_to_agree_on_the_sign():
    assert decide([0.3, 0.35, 0.28, 0.4]).verdict == ClaimVerdict.HOLDS
    assert decide([1.3, 1.35, 1.28, 1.4]).verdict == ClaimVerdict.DOES_NOT_HOLD
    # 0.2 % apart on average but the runs straddle 1: no measurable difference, not "holds marginally"
    assert decide([0.95, 1.04, 0.99, 1.03, 0.98]).verdict == ClaimVerdict.NO_DIFFERENCE
    # consistent, but smaller than the least effect worth a word
    tiny_effect = 1.0 - MIN_EFFECT / 2
    assert decide([tiny_effect] * 5).verdict == ClaimVerdict.NO_DIFFERENCE
    # the claim may be that the ratio exceeds 1 (an error that grows)
    assert decide([1.3, 1.2, 1.25], claimed_below=False).verdict == ClaimVerdict.HOLDS
    assert decide([0.8, 0.82, 0.85], claimed_below=False).verdict == ClaimVerdict.DOES_NOT_HOLD
    # fewer than 3 runs: their range decides
    assert decide([0.9, 1.1]).verdict == ClaimVerdict.NO_DIFFERENCE and decide([0.5]).verdict == ClaimVerdict.HOLDS
    assert decide([0.95, 0.94, 0.96], min_effect=0.1).verdict == ClaimVerdict.NO_DIFFERENCE  # a time per sample
    with pytest.raises(ValueError, match="no finite positive ratio"):
        decide([np.nan, 0.0])


def test_words_follow_the_size_and_sign_of_the_ratio():
    assert relative(0.2, "smaller", "larger") == "5x smaller"
    assert relative(0.78, "smaller", "larger") == "22 % smaller"
    assert relative(1.004, "smaller", "larger") == "0.4 % larger"
    assert relative(3.0, "decrease", "growth") == "3x growth"
    claim = Claim(
        case="noisy",
        statement="the error grows over the run",
        quantity="late/early mean |error|",
        below="decrease",
        above="growth",
        effect=decide([0.84, 0.8, 0.82], claimed_below=False),
    )
    assert claim.verdict == ClaimVerdict.DOES_NOT_HOLD
    assert "does not hold (late/early mean |error| 0.82: 18 % decrease; 3 runs" in claim.text()
    assert headline([claim]) == ["**The paper's claims, checked here:**", "",
                                 "- **does not hold**: noisy: the error grows over the run"]  # fmt: skip
    assert (
        "not measured"
        in Claim(
            case="noisy", statement="x", quantity="q", below="a", above="b", effect=None, detail="no run measured it"
        ).text()
    )


def test_paper_claims_rest_on_per_run_ratios_of_the_study():
    scenario = tiny().with_overrides(runs=3)
    study = run_study(scenario, solver="gn")
    claims = paper_claims(study)
    statements = {(c.case, c.statement) for c in claims}
    assert ("noisy", "the UISE has a smaller x2 error than the standard MHE") in statements
    assert ("noisy", "the standard MHE's x2 error grows over the run") in statements
    tables = per_run(study, "x2")
    steps = study.steps
    for claim in claims:
        assert claim.effect is not None and len(claim.effect.ratios) == 3
        if "smaller x2 error" in claim.statement:
            expected = []
            for run in range(3):
                rmse = {}
                for name in ("UISE", "standard MHE"):
                    sel = steps[(steps.case == claim.case) & (steps.run == run) & (steps.estimator == name)]
                    sel = sel[sel.k >= scenario.settle]
                    rmse[name] = np.sqrt(((sel.x2 - sel.x2_hat) ** 2).mean())
                expected.append(rmse["UISE"] / rmse["standard MHE"])
            np.testing.assert_allclose(np.sort(claim.effect.ratios), np.sort(expected))
    assert isinstance(tables["rmse"], pd.DataFrame) and set(tables["rmse"].columns) == {"UISE", "standard MHE"}


def test_a_run_whose_estimator_mostly_failed_measures_no_claim():
    # a study where 200 of 202 steps failed said "holds: the standard MHE's error grows" from the propagated estimates
    import dataclasses

    from uiest.experiments.claims import MOSTLY_FAILED

    study = run_study(tiny().with_overrides(runs=2), solver="gn")
    steps = study.steps.copy()
    mhe = (steps.estimator == "standard MHE") & (steps.run == 0)
    steps.loc[mhe & (steps.k % 4 != 0), "outcome"] = "failed"  # 3 of 4 steps: more than MOSTLY_FAILED
    claims = paper_claims(dataclasses.replace(study, steps=steps))
    assert MOSTLY_FAILED < 0.75
    for claim in claims:
        if "standard MHE" in claim.statement:
            case_runs = 1 if claim.case in set(steps.case[mhe]) else 2
            assert claim.effect is not None and len(claim.effect.ratios) == case_runs
            assert "1 run left out: an estimator failed in most of its steps" in claim.text()  # said, not silent
