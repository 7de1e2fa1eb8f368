"""The building blocks of the DBC generator (dbc/generator/train_brake.py) and of the studies' DBC parts
(hil/studies/<name>/frames.py): messages, signals, and signals a study adds to a foundation message."""

from __future__ import annotations

from dataclasses import dataclass, field

MAX_CARS = 8


@dataclass
class Sig:
    name: str
    start: int
    length: int
    scale: float = 1.0
    offset: float = 0.0
    minimum: float = 0.0
    maximum: float = 0.0
    unit: str = ""
    signed: bool = False
    comment: str = ""
    choices: dict[int, str] = field(default_factory=dict)


@dataclass
class Msg:
    frame_id: int
    name: str
    sender: str
    receivers: list[str]
    cycle_ms: int
    comment: str
    signals: list[Sig]
    dlc: int = 8
    secoc_data_id: int = 0     # > 0: authenticated (SecOC profile 1) with this data id
    # the optional function the frame belongs to (DBC attribute RailhilFunction): sent only in runs that
    # have it; "" = the train's base functions, on the bus in every run
    function: str = ""


def e2e(comment_what: str) -> list[Sig]:
    return [
        Sig("CHECKSUM", 0, 8, maximum=255,
            comment=f"E2E profile 1 CRC-8 (SAE J1850) over data id and {comment_what} "
                    "(filled by the sender)"),
        Sig("COUNTER", 8, 4, maximum=15, comment="E2E profile 1 alive counter 0..14, +1 every transmission"),
    ]


def secoc(what: str) -> list[Sig]:
    """SecOC profile 1 trailer (hil/can/secoc.py): bytes 0-3 are the authentic part, E2E-protected."""
    return [
        Sig("SecOCFreshness", 32, 8, maximum=255,
            comment=f"8 LSB of the freshness counter of {what} (filled by the sender)"),
        Sig("SecOCMAC", 40, 24, maximum=16777215,
            comment=f"24 MSB of the AES-128 CMAC over data id, bytes 0-3 and full freshness of {what}"),
    ]


def becus(n_cars: int = MAX_CARS) -> list[str]:
    return [f"BECU{i}" for i in range(1, n_cars + 1)]


@dataclass
class Extra:
    """Signals a study adds to a message of the foundation's train (`message`; "{i}" stands for the car
    of a per-car message, which gets them on every car): after the signal `after`, at the start with
    `first`, else at the end."""

    message: str
    signals: list[Sig]
    after: str | None = None
    first: bool = False
