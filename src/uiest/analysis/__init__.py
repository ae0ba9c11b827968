"""Model analysis: which estimator a model admits, and why.

:func:`analyse` returns a :class:`ModelAnalysis`: the matching ranks and the samples each unknown
input needs to reach an output; the invariant zeros of the model linearised at sampled points of X
(the ones that sampling a continuous-time model created named as such) and per channel; the
near-zeros (frequencies at which an unknown input is nearly invisible, and the error floor they
impose on any estimator that allows arbitrary unknown inputs); the strong-detectability certificate
and the error bound of the UISE it designs; the delayed UISE where matching fails; and the
recommended estimator (:class:`Recommendation`) with its cause (:class:`Cause`) and a one-sentence
reason derived from the numbers. ``uiest analyse MODEL`` prints it.
"""

from uiest.analysis.analyse import DEFAULT_MAX_HORIZON, analyse
from uiest.analysis.designs import EstimatorDesign
from uiest.analysis.near_zeros import FrequencyMinimum, NearZeros
from uiest.analysis.random_walk import RandomWalkDetectability
from uiest.analysis.recommend import Cause, Recommendation
from uiest.analysis.report import ModelAnalysis
from uiest.analysis.zeros import Channel, Zero, Zeros

__all__ = [
    "DEFAULT_MAX_HORIZON",
    "Cause",
    "Channel",
    "EstimatorDesign",
    "FrequencyMinimum",
    "ModelAnalysis",
    "NearZeros",
    "RandomWalkDetectability",
    "Recommendation",
    "Zero",
    "Zeros",
    "analyse",
]
