"""The frames of the slip-reference-with-preview study (seed 000, Picasso, Caporale, Colaneri).

Part of dbc/generator/train_brake.py (run that script to write the DBC).
Identifiers: 0x070-0x07F (the paper-mode loop: each BECU's slip reference to the plant) and 0x109-0x119
(0x108 is PLANT_CAR8_SENSORS; the plant's train-state and per-car adhesion frames, and each BECU's σ̄°
broadcast with its position).

σ̄° is the speed-normalised optimal slip of seed 000 eq. (2), σ̄°(x) = σ°(x, v) · k2(v): a property of
the rail at x alone, so a car behind can re-scale it to the speed it will have there.
"""

from __future__ import annotations

from hil.can.dbcschema import MAX_CARS, Extra, Msg, Sig, becus, e2e  # noqa: F401

SLIP_SCALE = 1e-5          # slip ratio resolution [-]: 16 bits cover 0 .. 0.65535
METHODS = {0: "LF", 1: "BD", 2: "DP", 3: "IDEAL"}
SOURCES = {0: "ORACLE", 1: "ESTIMATE"}


def messages() -> list[Msg]:
    msgs: list[Msg] = []
    for i in range(1, MAX_CARS + 1):
        msgs.append(Msg(
            0x070 + i - 1, f"BECU{i}_SLIP_REF", f"BECU{i}", ["PLANT"], 10,
            f"Seed 000 paper mode: car {i}'s slip reference Sigma_i (eq. 4) to the plant's closed-loop slip "
            "model, with the reference generator's state.",
            [
                Sig("SlipRef", 0, 16, scale=SLIP_SCALE, maximum=0.65535,
                    comment="slip reference Sigma_i of eq. (4) (relative slip, beta scaling included)"),
                Sig("PreviewDist", 16, 16, scale=0.01, maximum=655.35, unit="m",
                    comment="delta_i* of eq. (9): how far behind car 1 the previewed sigma° is read "
                            "(0 for Lf, Bd, ideal and car 1)"),
                Sig("PredSpeed", 32, 16, scale=0.001, maximum=65.535, unit="m/s",
                    comment="speed predicted for when this car reaches the previewed point (eq. 10 / "
                            "Remark 2); the measured speed for Lf, Bd"),
                Sig("Method", 48, 2, maximum=3, comment="reference generator", choices=METHODS),
                Sig("Source", 50, 1, maximum=1, comment="where sigma° comes from", choices=SOURCES),
                Sig("PreviewMiss", 51, 1, maximum=1,
                    comment="1: no preview data at the previewed point yet, own sigma° used instead",
                    choices={0: "OK", 1: "MISS"}),
            ]))
    msgs.append(Msg(
        0x109, "PLANT_TRAIN", "PLANT", becus(), 10,
        "Seed 000 paper mode: the train's common speed, acceleration and the position of car 1 (rigid "
        "train, eq. 3).",
        [
            Sig("Speed", 0, 16, scale=0.001, maximum=65.535, unit="m/s", comment="train speed v"),
            Sig("Accel", 16, 16, scale=0.0005, minimum=-16.384, maximum=16.3835, unit="m/s^2", signed=True,
                comment="train acceleration dv/dt (negative when braking)"),
            Sig("HeadPos", 32, 32, scale=0.001, minimum=-2147483.648, maximum=2147483.647, unit="m",
                signed=True, comment="track position x_1 of car 1 (the braking device of the first car)"),
        ]))
    for i in range(1, MAX_CARS + 1):
        msgs.append(Msg(
            0x10A + i - 1, f"PLANT_CAR{i}_ADH", "PLANT", [f"BECU{i}"], 10,
            f"Seed 000: car {i}'s wheel-rail measurements: its slip, the adhesion it uses (from brake "
            "force) and the oracle's true sigma-bar° under the car.",
            [
                Sig("Slip", 0, 16, scale=SLIP_SCALE, maximum=0.65535,
                    comment="measured relative slip sigma_i"),
                Sig("AdhesionUsed", 16, 16, scale=SLIP_SCALE, maximum=0.65535,
                    comment="adhesion coefficient mu the car's wheels use now (braking force / weight)"),
                Sig("SigmaOptBarTrue", 32, 16, scale=SLIP_SCALE, maximum=0.65535,
                    comment="oracle: true sigma-bar°(x_i) = sigma°(x_i, v) k2(v) of eq. (2) under the car"),
            ]))
    for i in range(1, MAX_CARS + 1):
        msgs.append(Msg(
            0x112 + i - 1, f"BECU{i}_PREVIEW", f"BECU{i}", [b for b in becus() if b != f"BECU{i}"], 10,
            f"Seed 000 preview data: car {i}'s sigma-bar° (oracle or its own estimate) and the track "
            "position it belongs to, for the cars behind.",
            [
                Sig("SigmaOptBar", 0, 16, scale=SLIP_SCALE, maximum=0.65535,
                    comment="sigma-bar° = sigma° k2(v) of eq. (2) at Position (speed-normalised)"),
                Sig("Position", 16, 32, scale=0.001, minimum=-2147483.648, maximum=2147483.647, unit="m",
                    signed=True, comment="track position where SigmaOptBar was measured (this car's)"),
                Sig("Source", 48, 1, maximum=1, comment="oracle or estimate", choices=SOURCES),
                Sig("Valid", 49, 1, maximum=1, comment="0 until the car has a value",
                    choices={0: "INVALID", 1: "VALID"}),
            ]))
    return msgs


def signals() -> list[Extra]:
    """Each BECU's own estimate of σ° with the position it was measured at (BECUn_EST): what the cars
    behind read as preview when σ° is estimated."""
    return [
        Extra("BECU{i}_EST", signals=[
            Sig("OptSlipEst", 16, 10, scale=0.0005, maximum=0.5115,
                comment="estimated optimal slip ratio sigma^o here (seed 000 eq. 2); 0 = no estimate"),
            Sig("OptSlipPos", 26, 18, scale=0.1, maximum=26214.3, unit="m",
                comment="track position at which OptSlipEst was measured"),
        ]),
    ]
