"""The frames of the anti-collision study (seed 002): the ACD's brake request and the radio link.

Part of dbc/generator/train_brake.py (run that script to write the DBC).
Identifiers: 0x020 (safety: the ACD's request), 0x180-0x182 (radio), 0x183 (the GPS model's truth feed),
0x184 (its status).
"""

from __future__ import annotations

from hil.can.dbcschema import Extra, Msg, Sig, becus, e2e, secoc  # noqa: F401


def messages() -> list[Msg]:
    return [
        Msg(0x020, "ACD_BRAKE_REQ", "ACD", ["BCU"], 100,
            "Anti-collision device brake request to the BCU (authenticated: a forged request brakes the "
            "train, a forged NONE hides one).",
            e2e("the ACD request") + [
                Sig("Request", 12, 2, maximum=3, comment="requested braking",
                    choices={0: "NONE", 1: "SERVICE", 2: "EMERGENCY"}),
                # 10 bits so that the SecOC trailer fits: 0.01 m/s² steps up to 10.23 m/s²
                Sig("RequestedDecel", 14, 10, scale=0.01, maximum=10.23, unit="m/s^2",
                    comment="deceleration the ACD asks for (positive = braking)"),
            ] + secoc("the ACD request"), secoc_data_id=0x020),
        Msg(0x184, "ACD_STATUS", "ACD", ["DESK"], 100,
            "Anti-collision device state for the desk and the log (no node acts on it).",
            [
                Sig("DistanceToObstacle", 0, 24, scale=0.01, maximum=167772.15, unit="m",
                    comment="distance to the leader's last wagon or to the red signal"),
            ]),
        Msg(0x180, "RADIO_LEADER_POS", "PLANT", ["ACD"], 1000,
            "Radio link: position of the leading train (relayed by the control centre).",
            [
                Sig("Latitude", 0, 32, scale=1e-7, minimum=-90.0, maximum=90.0, unit="deg", signed=True,
                    comment="WGS-84 latitude of the leader's last wagon"),
                Sig("Longitude", 32, 32, scale=1e-7, minimum=-180.0, maximum=180.0, unit="deg", signed=True,
                    comment="WGS-84 longitude of the leader's last wagon"),
            ]),
        Msg(0x181, "RADIO_LEADER_INFO", "PLANT", ["ACD"], 1000,
            "Radio link: leading train state.",
            [
                Sig("LeaderId", 0, 8, maximum=255, comment="identifier of the leading train"),
                Sig("RouteSection", 8, 16, maximum=65535, comment="route section the leader occupies"),
                Sig("Speed", 24, 16, scale=0.01, maximum=655.35, unit="m/s", comment="leader speed"),
                Sig("TrainLength", 40, 16, scale=0.1, maximum=6553.5, unit="m", comment="leader length"),
                Sig("AgeOfReport", 56, 8, scale=0.1, maximum=25.5, unit="s",
                    comment="age of the leader's report when relayed"),
            ]),
        Msg(0x182, "RADIO_SIGNAL", "PLANT", ["ACD", "BCU"], 1000,
            "Radio link: aspect of the next signal.",
            [
                Sig("SignalId", 0, 16, maximum=65535, comment="identifier of the next signal"),
                Sig("Aspect", 16, 2, maximum=3, comment="signal aspect",
                    choices={0: "UNKNOWN", 1: "RED", 2: "YELLOW", 3: "GREEN"}),
                Sig("SignalPos", 24, 24, scale=0.01, maximum=167772.15, unit="m",
                    comment="track position of the signal"),
                Sig("AgeOfAspect", 48, 8, scale=0.1, maximum=25.5, unit="s",
                    comment="age of the aspect when sent: time since the radio last delivered it"),
            ]),
        Msg(0x183, "ACD_GNSS_TRUTH", "PLANT", ["ACD"], 100,
            "Simulation only (no such frame on a train): the true position of the own train's GPS antenna "
            "(front of car 1), the feed of the GPS receiver model in the ACD node, like a GNSS "
            "simulator's feed from the vehicle model.",
            [
                Sig("TrackPos", 0, 32, scale=0.001, maximum=4294967.295, unit="m",
                    comment="true track position of the antenna (length along the track polyline)"),
                Sig("Speed", 32, 16, scale=0.01, maximum=655.35, unit="m/s", comment="true speed"),
            ]),
    ]


def signals() -> list[Extra]:
    """This study adds no signal to the foundation's frames."""
    return []
