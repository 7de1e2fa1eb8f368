"""plant_sim: the physical world of railhil and its sensors. Pure numerics: no I/O, no clock.

Each equation is one scalar function on Python floats (`*_scalar`), which the plant's step calls per car
(numpy's per-call overhead dominates at n ≤ 8 cars: see `plant_sim.plant`); the array functions over
cars wrap these (`elementwise`) for tests and the plant's 10 ms truth.

    params    frozen parameter dataclasses, the rail-condition table RAIL_CONDITIONS
    adhesion  μ(θ, σ, v) and its peak, seed 000 §2.1
    track     rail condition θ(x), gradient and curvature along the track
    brake     EP/WSP valves, cylinder pressure, pressure → torque hysteresis, seed 001
    dynamics  couplers, resistances, car and wheel dynamics, seeds 001 and 003
    sensors   noisy, quantised, seeded readings of the true state
    plant     Plant: the fixed-step integrator around all of it
    elementwise  the array face of the scalar functions
"""

from plant_sim.errors import PlantConfigError
from plant_sim.params import (
    RAIL_CONDITIONS,
    AdhesionParams,
    BrakeParams,
    PlantParams,
    SensorParams,
    TrainParams,
    theta_from_peak,
)
from plant_sim.plant import Plant
from plant_sim.sensors import Sensors
from plant_sim.track import Track

__all__ = [
    "RAIL_CONDITIONS",
    "AdhesionParams",
    "BrakeParams",
    "Plant",
    "PlantConfigError",
    "PlantParams",
    "SensorParams",
    "Sensors",
    "TrainParams",
    "Track",
    "theta_from_peak",
]
