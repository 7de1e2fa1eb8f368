"""The DBC part of the wheel-slip governor (seed 001): the signals it adds to each BECU's frames.

Part of dbc/generator/train_brake.py (run that script to write the DBC).  The governor adds no frame of
its own: its state rides in BECUn_STATUS (GovernorActive) and BECUn_DIAG (the governed reference, the
torque margin, feasibility), so a trace alone shows what it did.
"""

from __future__ import annotations

from hil.can.dbcschema import Extra, Msg, Sig


def messages() -> list[Msg]:
    return []


def signals() -> list[Extra]:
    return [
        Extra("BECU{i}_STATUS", after="WspActive", signals=[
            Sig("GovernorActive", 13, 1, maximum=1, comment="1 = reference governor limits the demand"),
        ]),
        Extra("BECU{i}_DIAG", first=True, signals=[
            Sig("GovernedDecel", 0, 16, scale=0.001, maximum=65.535, unit="m/s^2",
                comment="deceleration reference r the governor lets through (= the demand when off)"),
            Sig("GovernorMargin", 16, 16, scale=2.0, minimum=-65536.0, maximum=65534.0, unit="N.m",
                signed=True, comment="torque ceiling minus the largest predicted brake torque under r"),
            Sig("GovernorFeasible", 32, 1, maximum=1,
                comment="0 = not even r = 0 is admissible: the state left the governor's set"),
        ]),
    ]
