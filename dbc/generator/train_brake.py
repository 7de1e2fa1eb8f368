"""Writes dbc/train_brake.dbc, the CAN schema of the whole train (1 to 8 cars).

The DBC file is what every tool reads and what railhil checks against; this script only saves us from
typing eight copies of the per-car frames by hand (opendbc keeps generators the same way, in
opendbc/dbc/generator/).  After editing, run

    .venv/bin/python dbc/generator/train_brake.py

and commit both files; tests/can/test_dbc.py fails when they disagree.

Conventions
- Units are SI; scaled integers.  Every signal has a comment.
- Safety frames (emergency, demands, pressure commands) have the lowest identifiers and carry
  `CHECKSUM` (byte 0) and `COUNTER` (low nibble of byte 1): the AUTOSAR E2E profile 1 layout.  The
  message attributes `E2EProfile` ("P01") and `E2EDataID` (the frame id: unique on this bus, data id
  mode BOTH) tell the node runtime to protect and check them (hil/can/e2e.py).
- Every frame whose signals reach an actuator or a target is authenticated (tests/safety/test_protection.py
  derives which from the node bindings): the brake demand, the pressure commands, the emergency frame
  (whose EmergencyActive = 0 releases), the desk's command and target, the cars' status, the ACD's
  request and the BCU's pressure correction; SecOC profile 1: bytes 0-3 are the E2E-protected
  authentic part, `SecOCFreshness` (byte 4) and `SecOCMAC` (bytes 5-7) the trailer; attribute
  `SecOCDataID` names the data id (hil/can/secoc.py).
- Names: message `<SENDER>_<WHAT>`, per-car messages `<SENDER><n>_<WHAT>` / `PLANT_CAR<n>_<WHAT>`,
  signals CamelCase with no car index, so a binding can substitute the index.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from hil.can.dbcschema import MAX_CARS, Extra, Msg, Sig, becus, e2e, secoc  # noqa: F401
from hil.scenario.registry import studies

BITRATE_BPS = 500_000
OUT = Path(__file__).resolve().parents[1] / "train_brake.dbc"


WSP_CHOICES = {0: "FILL", 1: "HOLD", 2: "VENT"}
BCU_MODES = {0: "RELEASED", 1: "SERVICE", 2: "EMERGENCY"}


def messages() -> list[Msg]:
    msgs: list[Msg] = [
        Msg(0x010, "BCU_EMERGENCY", "BCU", becus() + ["PLANT"], 20,
            "Emergency-brake loop: EmergencyActive=1 commands full braking on every car.",
            e2e("the emergency frame") + [
                Sig("EmergencyActive", 12, 1, maximum=1, comment="1 = emergency braking commanded",
                    choices={0: "INACTIVE", 1: "ACTIVE"}),
                Sig("Source", 13, 2, maximum=3, comment="who demanded the emergency brake",
                    choices={0: "NONE", 1: "DESK", 2: "ACD", 3: "BCU"}),
            ] + secoc("the emergency frame"), secoc_data_id=0x010),
        Msg(0x018, "DESK_CMD", "DESK", ["BCU"], 100,
            "Driver desk / ATO brake commands (authenticated: a forged release is dropped).",
            e2e("the desk command") + [
                Sig("BrakeStep", 12, 3, maximum=7,
                    comment="service brake step 0 (released) .. 7 (full service)"),
                Sig("EmergencyReq", 15, 1, maximum=1, comment="1 = driver emergency brake request"),
                # seed 002 §VII: the PLC sets the driver's brake valve; the BCU integrates the position into
                # a brake demand at the valve's service / release rate (firmware_py/brake_valve.py)
                Sig("BrakeValve", 16, 3, maximum=7,
                    comment="driver's brake valve position set by a PLC on the desk: 0 not used (the brake "
                            "step alone), 2 = II release, 4 = IV lap with feeding, 5 = V service brake",
                    choices={0: "NONE", 2: "RELEASE", 4: "LAP", 5: "SERVICE"}),
            ] + secoc("the desk command"), secoc_data_id=0x018),
        Msg(0x019, "DESK_TARGET", "DESK", ["BCU"], 100,
            "Driver desk / ATO target stop point (precise stopping; authenticated: a forged target "
            "would move where the train stops).",
            e2e("the target stop point") + [
                Sig("TargetStopValid", 12, 1, maximum=1,
                    comment="1 = TargetStopPos holds a target stop point"),
                # 19 bits so that the SecOC trailer fits: 2 cm steps, against the ±30 cm platform-door goal of
                # the precise-stop study (docs/studies/precise-stop.md; seed 002 itself reports ±2-7 m)
                Sig("TargetStopPos", 13, 19, scale=0.02, maximum=10485.74, unit="m",
                    comment="target stop point of the leading car's front, track position"),
            ] + secoc("the target stop point"), secoc_data_id=0x019),
        Msg(0x028, "BCU_DEMAND", "BCU", becus(), 10,
            "Train brake demand distributed to every car.",
            e2e("the demand") + [
                Sig("Mode", 12, 2, maximum=3, comment="BCU brake mode", choices=BCU_MODES),
                Sig("BrakeStep", 16, 3, maximum=7, comment="active service brake step"),
                Sig("TargetDecel", 19, 13, scale=0.001, maximum=8.191, unit="m/s^2",
                    comment="target deceleration for every car (positive = braking)"),
            ] + secoc("the demand"), secoc_data_id=0x028),
    ]
    for i in range(1, MAX_CARS + 1):
        msgs.append(Msg(
            0x030 + i, f"BECU{i}_PRESS_CMD", f"BECU{i}", ["PLANT"], 10,
            f"Car {i}: brake-cylinder valve commands from BECU{i} to the pneumatic brake.",
            e2e("the pressure command") + [
                Sig("WspValve", 12, 2, maximum=2, comment="wheel-slide protection dump valve",
                    choices=WSP_CHOICES),
                # 9 bits each so that the SecOC trailer fits: 0.4 % of the valve's flow is the step of an
                # 8-bit PWM valve driver, 1 kPa is finer than a 0.5 %-of-10-bar pressure transducer
                Sig("ValveCmd", 14, 9, scale=0.004, minimum=-1.0, maximum=1.0, signed=True,
                    comment="EP valve opening: +1 full fill from the reservoir, -1 full vent"),
                Sig("CylPressureSet", 23, 9, scale=1000.0, maximum=511000.0, unit="Pa",
                    comment="brake-cylinder pressure set-point (gauge)"),
            ] + secoc("the pressure command"), secoc_data_id=0x030 + i))
    for i in range(1, MAX_CARS + 1):
        msgs.append(Msg(
            0x100 + i, f"PLANT_CAR{i}_SENSORS", "PLANT", [f"BECU{i}", "BCU"], 10,
            f"Car {i}: wheel-speed sensor, brake-cylinder pressure transducer and accelerometer.",
            [
                Sig("AxleSpeed", 0, 16, scale=0.005, maximum=327.675, unit="rad/s",
                    comment="axle angular speed from the wheel-speed sensor"),
                Sig("CylPressure", 16, 16, scale=10.0, maximum=655350.0, unit="Pa",
                    comment="brake-cylinder pressure (gauge) from the transducer"),
                Sig("AccelLong", 32, 16, scale=0.001, minimum=-32.768, maximum=32.767, unit="m/s^2",
                    signed=True, comment="longitudinal accelerometer (+ forward), includes g*sin(gradient)"),
                Sig("SensorCounter", 48, 8, maximum=255, comment="sample counter, +1 per frame"),
            ]))
    for i in range(1, MAX_CARS + 1):
        msgs.append(Msg(
            0x040 + i, f"BECU{i}_STATUS", f"BECU{i}", ["BCU"] + [b for b in becus() if b != f"BECU{i}"], 50,
            f"Car {i}: BECU{i} reference speed and mode flags (authenticated: the BCU's standstill, "
            f"odometer and deceleration feedback act on them).",
            e2e("the car's status") + [
                Sig("WspActive", 12, 1, maximum=1,
                    comment="1 = wheel-slide protection is venting or holding"),
                Sig("IntegratorSat", 14, 1, maximum=1, comment="1 = a PI integrator is saturated or frozen"),
                Sig("InputMissing", 15, 1, maximum=1, comment="1 = an input signal is missing or non-finite"),
                Sig("SpeedEst", 16, 16, scale=0.01, maximum=655.35, unit="m/s",
                    comment="reference (ground) speed estimate"),
            ] + secoc("the car's status"), secoc_data_id=0x040 + i))
    for i in range(1, MAX_CARS + 1):
        msgs.append(Msg(
            0x170 + i, f"BECU{i}_EST", f"BECU{i}", ["BCU"] + [b for b in becus() if b != f"BECU{i}"], 100,
            f"Car {i}: BECU{i} slip estimates (the log; the preview of seed 000 reads its optimal slip).",
            [
                Sig("SlipSpeedEst", 0, 16, scale=0.001, minimum=-32.768, maximum=32.767, unit="m/s",
                    signed=True, comment="slip speed estimate s = v - r*omega (seed 001 eq. 2)"),
            ]))
    for i in range(1, MAX_CARS + 1):
        msgs.append(Msg(
            0x150 + i, f"BECU{i}_DIAG", f"BECU{i}", ["BCU"], 50,
            f"Car {i}: BECU{i} diagnostics: reference governor (seed 001 eq. 9) and sensor monitoring.",
            [
                Sig("SpeedSensorFault", 33, 1, maximum=1,
                    comment="1 = wheel-speed sensor stuck or implausible: excluded, WSP inhibited"),
                Sig("AccelSensorFault", 34, 1, maximum=1,
                    comment="1 = accelerometer biased or implausible: excluded, the axle speed is used"),
                Sig("CylSensorFault", 35, 1, maximum=1,
                    comment="1 = brake-cylinder pressure transducer frozen while the valve moves the "
                            "pressure: the pressure loop runs open, on the set-point"),
                Sig("AccelBiasEst", 40, 12, scale=0.002, minimum=-4.096, maximum=4.094, unit="m/s^2",
                    signed=True, comment="accelerometer reading minus the axle's acceleration, filtered"),
            ]))
    msgs += [
        Msg(0x160, "BCU_STATUS", "BCU", ["DESK"], 100,
            "BCU state for the desk and the log.",
            [
                Sig("Mode", 0, 2, maximum=3, comment="BCU brake mode", choices=BCU_MODES),
                Sig("BrakeStep", 2, 3, maximum=7, comment="brake step in force"),
                Sig("Degraded", 5, 1, maximum=1,
                    comment="1 = degraded: a car silent for 3 of its status cycles, or implausible"),
                Sig("CarsSilent", 8, 8, maximum=255,
                    comment="bit i-1 set = no status from car i for 3 of its cycles (150 ms)"),
                Sig("TrainSpeedEst", 16, 16, scale=0.01, maximum=655.35, unit="m/s",
                    comment="train speed estimate (max of the plausible cars' estimates)"),
                Sig("CarsImplausible", 32, 8, maximum=255,
                    comment="bit i-1 set = car i's speed estimate disagrees with the train's: excluded"),
            ]),
        Msg(0x120, "PLANT_BTM", "PLANT", ["BCU"], 20,
            "Balise transmission module of car 1: the last fixed balise its antenna (the train's front) "
            "passed. Sent only when the track has balises ([track] balises).",
            [
                Sig("BalisePos", 0, 24, scale=0.01, minimum=-83886.08, maximum=83886.07, unit="m",
                    signed=True, comment="track position of the last balise passed"),
                Sig("PassageAge", 24, 16, scale=0.0001, maximum=6.5535, unit="s",
                    comment="time since the antenna passed it, at transmission (saturates)"),
                Sig("BaliseCount", 40, 8, maximum=255, comment="balises passed since start, modulo 256"),
                Sig("BaliseValid", 48, 1, maximum=1, comment="1 once a balise has been passed",
                    choices={0: "NONE", 1: "VALID"}),
            ], function="balises"),
    ]
    # each study's DBC part (hil/studies/<name>/frames.py): its own frames, marked with its name
    # (RailhilFunction), and the signals it adds to the foundation's frames, in registry order
    by_name = {m.name: m for m in msgs}
    for study in studies():
        part = study.part("frames")
        msgs += [dataclasses.replace(m, function=m.function or study.name) for m in part.messages()]
        for extra in part.signals():
            names = ([extra.message.format(i=i) for i in range(1, MAX_CARS + 1)] if "{i}" in extra.message
                     else [extra.message])
            for name in names:
                add_signals(by_name[name], extra)
    return sorted(msgs, key=lambda m: m.frame_id)


def add_signals(msg: Msg, extra: Extra) -> None:
    """Put a study's signals into a foundation message where `extra` says."""
    names = [s.name for s in msg.signals]
    if extra.first:
        at = 0
    elif extra.after is not None:
        at = names.index(extra.after) + 1
    else:
        at = len(names)
    msg.signals[at:at] = [dataclasses.replace(s) for s in extra.signals]


def _num(x: float) -> str:
    return repr(float(x)).rstrip("0").rstrip(".") if "e" not in repr(float(x)) else repr(float(x))


def render() -> str:
    msgs = messages()
    nodes = ["PLANT", "BCU"] + becus() + ["ACD", "DESK"]
    out = [
        'VERSION "railhil train_brake 1"',
        "",
        "NS_ :",
        "\tBA_DEF_",
        "\tBA_",
        "\tBA_DEF_DEF_",
        "\tCM_",
        "\tVAL_",
        "",
        "BS_:",
        "",
        "BU_: " + " ".join(nodes),
        "",
    ]
    for m in msgs:
        out.append(f"BO_ {m.frame_id} {m.name}: {m.dlc} {m.sender}")
        for s in m.signals:
            sign = "-" if s.signed else "+"
            out.append(
                f" SG_ {s.name} : {s.start}|{s.length}@1{sign} ({_num(s.scale)},{_num(s.offset)}) "
                f'[{_num(s.minimum)}|{_num(s.maximum)}] "{s.unit}" {",".join(m.receivers)}'
            )
        out.append("")
    out.append('CM_ "Train brake CAN of railhil: PLANT, BCU, BECU1..BECU8, ACD, DESK. SI units.";')
    for m in msgs:
        out.append(f'CM_ BO_ {m.frame_id} "{m.comment}";')
        for s in m.signals:
            out.append(f'CM_ SG_ {m.frame_id} {s.name} "{s.comment}";')
    out += [
        'BA_DEF_ BO_ "GenMsgCycleTime" INT 0 65535;',
        'BA_DEF_ BO_ "GenMsgSendType" ENUM "Cyclic","NoMsgSendType";',
        'BA_DEF_ BO_ "E2EProfile" ENUM "NONE","P01","P02";',
        'BA_DEF_ BO_ "E2EDataID" INT 0 65535;',
        'BA_DEF_ BO_ "SecOCDataID" INT 0 65535;',
        'BA_DEF_ BO_ "RailhilFunction" STRING ;',
        'BA_DEF_ "Baudrate" INT 10000 1000000;',
        'BA_DEF_ "BusType" STRING ;',
        'BA_DEF_DEF_ "GenMsgCycleTime" 0;',
        'BA_DEF_DEF_ "GenMsgSendType" "NoMsgSendType";',
        'BA_DEF_DEF_ "E2EProfile" "NONE";',
        'BA_DEF_DEF_ "E2EDataID" 0;',
        'BA_DEF_DEF_ "SecOCDataID" 0;',
        'BA_DEF_DEF_ "RailhilFunction" "";',
        'BA_DEF_DEF_ "Baudrate" 500000;',
        'BA_DEF_DEF_ "BusType" "CAN";',
        f'BA_ "Baudrate" {BITRATE_BPS};',
        'BA_ "BusType" "CAN";',
    ]
    for m in msgs:
        out.append(f'BA_ "GenMsgCycleTime" BO_ {m.frame_id} {m.cycle_ms};')
        out.append(f'BA_ "GenMsgSendType" BO_ {m.frame_id} 0;')
        if any(s.name == "CHECKSUM" for s in m.signals):
            out.append(f'BA_ "E2EProfile" BO_ {m.frame_id} 1;')
            out.append(f'BA_ "E2EDataID" BO_ {m.frame_id} {m.frame_id};')
        if m.secoc_data_id:
            out.append(f'BA_ "SecOCDataID" BO_ {m.frame_id} {m.secoc_data_id};')
        if m.function:
            out.append(f'BA_ "RailhilFunction" BO_ {m.frame_id} "{m.function}";')
    for m in msgs:
        for s in m.signals:
            if s.choices:
                vals = " ".join(f'{k} "{v}"' for k, v in sorted(s.choices.items()))
                out.append(f"VAL_ {m.frame_id} {s.name} {vals} ;")
    return "\n".join(out) + "\n"


if __name__ == "__main__":
    OUT.write_text(render())
    print(f"wrote {OUT}")
