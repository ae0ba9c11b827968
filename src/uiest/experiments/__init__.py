"""Studies: scenarios (TOML), a runner over runs and estimators, metrics and reports."""

from uiest.experiments.metrics import accuracy, timing
from uiest.experiments.paper_study import crop_growth_study
from uiest.experiments.report import write_report
from uiest.experiments.runner import StudyResult, run_study
from uiest.experiments.scenario import EstimatorSpec, Scenario
from uiest.experiments.study_model import StudyModel

__all__ = [
    "EstimatorSpec",
    "Scenario",
    "StudyModel",
    "StudyResult",
    "accuracy",
    "crop_growth_study",
    "run_study",
    "timing",
    "write_report",
]
