"""The driver's brake valve as seed 002's PLC sets it (§VII): three positions, the demanded deceleration
integrated from them.

The PLC of seed 002 does not command a deceleration: it sets "the baselines of control elements (a
driver's stop-device)" of the brake system — II brake release, IV lap with feeding, V service brake.
On a driver's brake valve (e.g. the Kran 394/395 of the paper's freight trains) position V vents the
equalizing reservoir at the service rate and the brakes apply more the longer it is held; IV (lap with
feeding) holds the brake pipe pressure reached, compensating leaks; II recharges the pipe and the brakes
release.  `BrakeValve` models that on the brake demand itself: in V the demanded deceleration rises at the
service rate, in II it falls at the release rate, in IV it is held, always within [0, max].

The BCU integrates the position it receives with this class (the bench's PLC sends only the position),
and the stopping controller's adaptive searches feed their own positions through it (firmware_py/stopping),
so both turn the same positions into the same demand.  Pure: time is passed in.  Units: SI, decelerations
positive when braking.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum

from firmware_py.limits import clip


class ValvePosition(IntEnum):
    """Positions of the driver's brake valve the PLC uses (seed 002 §VII), numbered as on the valve."""

    RELEASE = 2      # II: brake release (running position)
    LAP = 4          # IV: lap with feeding: the brake reached is held
    SERVICE = 5      # V: service brake: the brake applies at the service rate


@dataclass(frozen=True)
class BrakeValveParams:
    service_rate_mps3: float = 0.3    # V: rise of the demanded deceleration [m/s³] (chosen: full service,
    #                                   1.0 m/s², in about 3.3 s, as a driver's valve with EP control
    #                                   applies the bench's EP brakes; an all-pneumatic freight train, the
    #                                   paper's, takes about twice as long: its equalizing reservoir falls
    #                                   about 0.1 MPa in 4–5 s in V and full service is about 0.15 MPa)
    release_rate_mps3: float = 0.3    # II: fall of the demanded deceleration [m/s³] (chosen: graduated
    #                                   release as fast as the application)
    max_decel_mps2: float = 1.0       # the demand's ceiling: full service (BcuParams step 7) [m/s²]


class BrakeValve:
    """`step(dt_s, position) -> demanded deceleration [m/s²]`: the demand after dt_s in `position`.

    `position` is a number, as the PLC's CAN signal decodes (5.0 is SERVICE); one that is not one of
    `ValvePosition` is taken as LAP (the demand is held, nothing new is applied or released); a non-finite
    or negative dt_s changes nothing."""

    def __init__(self, p: BrakeValveParams, demand_mps2: float = 0.0) -> None:
        self.p = p
        self.demand = clip(demand_mps2, 0.0, p.max_decel_mps2)

    def step(self, dt_s: float, position: float) -> float:
        p = self.p
        if not (math.isfinite(dt_s) and dt_s > 0.0):
            return self.demand
        if position == ValvePosition.SERVICE:
            self.demand = clip(self.demand + p.service_rate_mps3 * dt_s, 0.0, p.max_decel_mps2)
        elif position == ValvePosition.RELEASE:
            self.demand = clip(self.demand - p.release_rate_mps3 * dt_s, 0.0, p.max_decel_mps2)
        return self.demand
