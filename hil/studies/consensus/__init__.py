"""Consensus braking across cars: each car's BECU brakes to a consensus on speed with its neighbours,
a potential field keeping every coupler within ±1 cm, and a sliding-mode observer compensating the
disturbances (adhesion loss, running resistance).

Paper: seed 003, "Observer-driven distributed consensus braking control for urban railway trains",
Actuators 12, 111 (../shared/seeds/003_56a2b48f7abd0f3a.txt).  Controller: firmware_py/consensus.py;
the paper's force-actuated plant: plant_sim/consensus.py.  Docs: docs/studies/consensus.md.
"""

from hil.scenario.registry import Study
from hil.studies.consensus.scenario import ConsensusSpec

STUDY = Study(
    name="consensus", section="consensus", spec=ConsensusSpec, package=__name__,
    title="consensus braking across cars: cases 1-3 with and without the observer, cycle and latency sweeps",
    paper="seed 003: observer-driven distributed consensus braking control for urban railway trains",
)
