"""Deceleration feedback in the BCU: the brake force corrected by the measured deceleration, so that the
train meets the target deceleration of each brake step whatever the pad friction does.

Paper: seed 004, Wang et al., "Accuracy Improvement of Braking Force via Deceleration Feedback Functions
Applied to Braking Systems", Sensors 23, 5975 (../shared/seeds/004_535668fc9d9d2b17.txt).  Controller:
firmware_py/decel_feedback.py (EKF, slope estimate, activation, correction φ) in the foundation BCU;
the pad friction μ_d(v, T): plant_sim (PadParams, the brake-disc bench).  Docs:
docs/studies/decel-feedback.md.
"""

from hil.scenario.registry import Study
from hil.studies.decel_feedback.scenario import LEGACY_KEYS, DecelFeedbackSpec, check

STUDY = Study(
    name="decel_feedback", section="decel_feedback", spec=DecelFeedbackSpec, package=__name__, check=check,
    legacy_keys=LEGACY_KEYS,
    title="deceleration feedback in the BCU: the line test of Figs. 19-20, closed loop against open loop",
    paper="seed 004: Wang et al., accuracy improvement of braking force via deceleration feedback",
)
