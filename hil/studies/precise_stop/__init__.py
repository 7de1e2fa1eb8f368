"""Precise stopping at a target point: the BCU brakes the train along a braking curve to the stop point
the desk (the ATO) gives, correcting its braking with the paper's adaptive search ("with united attempt
and work steps", with or without the differentiation unit, setting the driver's brake valve every PLC
scan) or a PI on the curve; balises re-anchor its odometer.

Paper: seed 002, adaptive train braking on a PLC and an embedded anti-collision device
(../shared/seeds/002_52bf1e74f6d1e01e.txt), §VII.  Controller: firmware_py/stopping.py in the foundation
BCU.  Docs: docs/studies/precise-stop.md.
"""

from hil.scenario.registry import Study
from hil.studies.precise_stop.scenario import LEGACY_KEYS, PreciseStopSpec, check

STUDY = Study(
    name="precise_stop", section="precise_stop", spec=PreciseStopSpec, package=__name__, check=check,
    legacy_keys=LEGACY_KEYS,
    title="precise stopping at a target point: seeded randomized stops per method, the stop error",
    paper="seed 002: adaptive train braking on a PLC (§VII, adaptive search and differentiation unit)",
)
