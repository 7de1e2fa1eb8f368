"""The anti-collision device: the own position from GPS (NMEA over a serial line), the leading train and
the signal aspect over the radio link through the control centre, the braking-distance check of the
12-step algorithm, braking and release, and position prediction when radio data is late or lost.

Paper: seed 002, adaptive train braking on a PLC and an embedded anti-collision device
(../shared/seeds/002_52bf1e74f6d1e01e.txt), §IV-§V, §IX-§X.  Controller: firmware_py/acd.py; the control
centre: hil.links.control_centre; GPS: plant_sim.gps and hil.links.nmea.  Docs:
docs/studies/anticollision.md.
"""

from hil.scenario.registry import Study
from hil.studies.anticollision.scenario import AcdSpec

STUDY = Study(
    name="anticollision", section="acd", spec=AcdSpec, package=__name__,
    title="anti-collision device: randomized two-train runs with and without prediction, judged on truth",
    paper="seed 002: an embedded anti-collision device (12-step algorithm, GPS, radio, control centre)",
)
