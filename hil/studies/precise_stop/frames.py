"""The DBC part of precise stopping (seed 002): BCU_STOP, where the BCU believes the train is against
its target and braking curve, and the stopping state in BCU_STATUS.

Part of dbc/generator/train_brake.py (run that script to write the DBC).  The target stop point itself
comes from the desk (DESK_TARGET, a foundation frame: the desk sends it in every run) and the balises
from the plant (PLANT_BTM, the track's).
"""

from __future__ import annotations

from hil.can.dbcschema import Extra, Msg, Sig


def messages() -> list[Msg]:
    return [
        Msg(0x161, "BCU_STOP", "BCU", ["DESK"], 100,
            "Precise stopping (seed 002): where the BCU believes the train is against its target and curve. "
            "Sent only when the scenario's BCU does precise stopping.",
            [
                Sig("DistanceToGo", 0, 24, scale=0.01, minimum=-83886.08, maximum=83886.07, unit="m",
                    signed=True, comment="target stop point minus the odometer's position of car 1's front"),
                Sig("RefSpeed", 24, 16, scale=0.01, maximum=655.35, unit="m/s",
                    comment="the braking curve's speed at this point (0 when not following)"),
                Sig("StopCommand", 40, 12, scale=0.001, maximum=4.095, unit="m/s^2",
                    comment="deceleration the stopping controller commands (before the jerk limit)"),
                Sig("BalisesSeen", 52, 4, maximum=15,
                    comment="balise passages the odometer has re-anchored on, modulo 16"),
                Sig("SearchQ", 56, 8, scale=0.5, maximum=127.5, unit="m",
                    comment="adaptive search: last work function Q = |S - S_th| (saturates; 0 for pi)"),
            ]),
    ]


def signals() -> list[Extra]:
    return [
        Extra("BCU_STATUS", signals=[
            Sig("StopState", 59, 2, maximum=3, comment="precise stopping (seed 002): state of the "
                "braking-curve follower", choices={0: "OFF", 1: "ARMED", 2: "FOLLOWING", 3: "STOPPED"}),
        ]),
    ]
