"""The DBC part of the deceleration feedback (seed 004): its state, the correction φ and the slope
estimate in BCU_STATUS, every 100 ms (the grid of the friction-coefficient set).

Part of dbc/generator/train_brake.py (run that script to write the DBC).
"""

from __future__ import annotations

from hil.can.dbcschema import Extra, Msg, Sig, becus, e2e, secoc

FB_STATES = {0: "OFF", 1: "MONITOR", 2: "ENGAGED", 3: "HELD"}
FB_STATE_COMMENT = ("deceleration feedback (seed 004 sec. 5): OFF no service braking, emergency or not "
                    "fitted; MONITOR watching actual/target; ENGAGED correcting; HELD released (WSP or band "
                    "not met), correction kept")


def messages() -> list[Msg]:
    """The correction φ the BECUs apply, with the state that allows it: authenticated, since a forged φ
    changes every car's cylinder pressure (a BECU ignores φ unless FbState is ENGAGED or HELD)."""
    return [
        Msg(0x029, "BCU_BRAKE_CORR", "BCU", becus(), 100,
            "Deceleration feedback's pressure correction for every car (seed 004 eq. 34).",
            e2e("the pressure correction") + [
                Sig("FbState", 12, 2, maximum=3, comment=FB_STATE_COMMENT, choices=FB_STATES),
                # offset 1: raw 0 is phi = 1 (no correction)
                Sig("FrictionPhi", 14, 10, scale=0.002, offset=1.0, minimum=0.0, maximum=2.022, signed=True,
                    comment="pressure correction phi (seed 004 eq. 34, = mu_d/mu_d0): each BECU applies "
                            "P_c = P_c0/phi above the preload; 1 = no correction"),
            ] + secoc("the pressure correction"), secoc_data_id=0x029),
    ]


def signals() -> list[Extra]:
    return [
        Extra("BCU_STATUS", signals=[
            Sig("FbState", 6, 2, maximum=3, comment=FB_STATE_COMMENT, choices=FB_STATES),
            Sig("SlopeEst", 50, 9, scale=0.00025, minimum=-0.064, maximum=0.06375, signed=True,
                comment="track slope tan(theta) under the train (+ uphill) estimated from the front and "
                        "rear accelerometers and the speed; 0.001 = 1 permille"),
        ]),
    ]
