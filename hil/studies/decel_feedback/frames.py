"""The DBC part of the deceleration feedback (seed 004): its state, the correction φ and the slope
estimate in BCU_STATUS, every 100 ms (the grid of the friction-coefficient set).

Part of dbc/generator/train_brake.py (run that script to write the DBC).
"""

from __future__ import annotations

from hil.can.dbcschema import Extra, Msg, Sig


def messages() -> list[Msg]:
    return []


def signals() -> list[Extra]:
    return [
        Extra("BCU_STATUS", signals=[
            Sig("FbState", 6, 2, maximum=3,
                comment="deceleration feedback (seed 004 sec. 5): OFF no service braking, emergency or "
                        "not fitted; MONITOR watching actual/target; ENGAGED correcting; HELD released "
                        "(WSP or band not met), correction kept",
                choices={0: "OFF", 1: "MONITOR", 2: "ENGAGED", 3: "HELD"}),
            # offset 1: raw 0 is phi = 1 (no correction), the value of a BCU without the function
            Sig("FrictionPhi", 40, 10, scale=0.002, offset=1.0, minimum=0.0, maximum=2.022, signed=True,
                comment="pressure correction phi (seed 004 eq. 34, = mu_d/mu_d0): each BECU applies "
                        "P_c = P_c0/phi above the preload; 1 = no correction"),
            Sig("SlopeEst", 50, 9, scale=0.00025, minimum=-0.064, maximum=0.06375, signed=True,
                comment="track slope tan(theta) under the train (+ uphill) estimated from the front and "
                        "rear accelerometers and the speed; 0.001 = 1 permille"),
        ]),
    ]
