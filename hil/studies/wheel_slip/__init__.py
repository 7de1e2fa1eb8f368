"""The wheel-slip governor: a reference governor that keeps each car's slip speed within s̄ by limiting
the deceleration reference of the BECU's PI, so that the wheel-slide protection never has to vent.

Paper: seed 001, C. Danielson, S. Di Cairano, "A Reference Governor for Wheel-Slip Prevention in
Railway Vehicles with Pneumatic Brakes" (../shared/seeds/001_5c39e1b23503103a.txt).  Controller:
firmware_py/governor.py, a reference stage of the foundation BECU (firmware_py/becu.py); the plant's
slip-speed adhesion curve and pneumatic brake: plant_sim.  Docs: docs/studies/wheel-slip.md.
"""

from hil.scenario.registry import Study
from hil.studies.wheel_slip.scenario import LEGACY_KEYS, WheelSlipSpec, check

STUDY = Study(
    name="wheel_slip", section="wheel_slip", spec=WheelSlipSpec, package=__name__, check=check,
    legacy_keys=LEGACY_KEYS,
    title="reference governor against wheel slip: Figs. 8-9, with and without the governor",
    paper="seed 001: Danielson, Di Cairano, a reference governor for wheel-slip prevention",
)
